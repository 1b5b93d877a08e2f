"""The PPO-tuned GNN in the PyBullet + Zenoh runtime against tuned local consensus and the BC model.

For each start seed, writes a scenario (N robots on a cycle, uniform in
``swarm.core.initial_poses.box_for(N)`` 0.4 m apart, v_max 0.5 m/s, lockstep, 20 Hz) per controller and
runs it with ``python -m swarm.cli run`` exactly as a user would (one sim_server process and N robot_agent
processes over Zenoh), on the PyBullet engine and, for reference, on the kinematic engine. Reads
each run's ``metrics.json`` and ``trajectory.jsonl``: convergence time at the scenario's threshold
(PyBullet: robots have bodies and jam, so its threshold is that of a gathered group; kinematic:
0.2 m) and the first time ``max_pairwise`` falls under each of ``--levels`` metres. Writes
``docs/results/rl/ppo/runtime.json`` and ``.md``.

    python bench/ppo_runtime.py [--seeds 7 8] [--count 20] [--gain 8] [--engines pybullet kinematic]

Without ``--gain``, local consensus runs with the gain tuned for the graph and N in
``docs/results/rl/ppo/tuned_lc.json`` (``python bench/tune_consensus_gain.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from _output import add_output_arguments, output_dir, progress

from swarm.core import metrics
from swarm.core.initial_poses import box_for
from swarm.scenarios.results import read_trajectory

ROOT = Path(__file__).resolve().parent.parent
OUT_DIR = ROOT / "docs" / "results" / "rl" / "ppo"


def scenario(
    count: int, seed: int, topology: str, controller: dict, duration_s: float, threshold_m: float
) -> dict:
    low, high = box_for(count)
    return {
        "name": f"ppo-runtime-{topology}{count}-{seed}-{controller['name']}",
        "robots": {
            "count": count,
            "init": {"random": {"seed": seed, "x": [low, high], "y": [low, high], "min_separation": 0.4}},
        },
        "topology": {"kind": topology},
        "robot": {"v_max": 0.5},
        "controller": {key: value for key, value in controller.items() if key != "name"},
        "sim": {"mode": "lockstep", "control_period": 0.05, "duration": duration_s},
        "success": {"metric": "max_pairwise", "threshold": {"kinematic": 0.2, "pybullet": threshold_m}},
    }


def first_below(times_s: np.ndarray, values: np.ndarray, level_m: float) -> float | None:
    below = np.nonzero(values <= level_m)[0]
    return float(times_s[below[0]]) if len(below) else None


def run_one(data: dict, engine: str, work: Path, levels: list[float]) -> dict:
    path = work / f"{data['name']}-{engine}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    out = work / f"{data['name']}-{engine}"
    started = time.perf_counter()
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "swarm.cli",
            "run",
            str(path),
            "--engine",
            engine,
            "--out",
            str(out),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    wall_s = time.perf_counter() - started
    if result.returncode == 2:
        raise RuntimeError(f"swarm run failed on {path}: {result.stderr.strip()[-2000:]}")
    outcome = json.loads((out / "metrics.json").read_text())
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    values = metrics.max_pairwise(poses[..., :2])
    return {
        "engine": engine,
        "converged": outcome["converged"],
        "threshold_m": outcome["threshold"],
        "convergence_time_s": outcome["convergence_time_s"],
        "lower_bound_s": outcome["lower_bound_s"],
        "final_metric_m": outcome["final_metric"],
        "initial_metric_m": outcome["initial_metric"],
        "first_below_s": {f"{level:g}": first_below(times_s, values, level) for level in levels},
        "wall_s": round(wall_s, 1),
    }


def write(rows: list[dict], args: argparse.Namespace, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = {key: value for key, value in vars(args).items() if key != "out"}
    (out_dir / "runtime.json").write_text(json.dumps({"settings": settings, "runs": rows}, indent=2) + "\n")

    def fmt(value: float | None) -> str:
        return "-" if value is None else f"{value:.2f}"

    levels = [f"{level:g}" for level in args.levels]
    lines = [
        f"# PPO-tuned GNN in the distributed runtime: {args.topology} of {args.count} robots",
        "",
        f"Command: `python bench/ppo_runtime.py --seeds {' '.join(map(str, args.seeds))} "
        f"--count {args.count} --gain {args.gain:g} --engines {' '.join(args.engines)} "
        f"--duration {args.duration:g} --threshold {args.threshold:g} "
        f"--levels {' '.join(f'{level:g}' for level in args.levels)}`. "
        "`swarm run` (lockstep, 20 Hz, v_max 0.5 m/s): on `pybullet` one sim_server process and one "
        "robot_agent process per robot over Zenoh, robots with bodies (threshold "
        f"{args.threshold:g} m: they jam before their points meet); on `kinematic` the same scenario "
        "in-process, no bodies (threshold 0.2 m). t(d): first time max_pairwise <= d metres.",
        "",
        "| engine | seed | controller | converged | t conv (s) | LB (s) | "
        + " | ".join(f"t({d})" for d in levels)
        + " |",
        "|---|---|---|---|---|---|" + "---|" * len(levels),
    ]
    for row in rows:
        lines.append(
            f"| {row['engine']} | {row['seed']} | {row['controller']} | {row['converged']} "
            f"| {fmt(row['convergence_time_s'])} | {fmt(row['lower_bound_s'])} | "
            + " | ".join(fmt(row["first_below_s"][d]) for d in levels)
            + " |"
        )
    lines += [
        "",
        "Summary per engine (a start that never met the threshold within the run counts as a failure):",
        "",
    ]
    for engine in args.engines:
        names = ("ppo", "bc", "local_consensus_tuned")
        runs = {
            name: [r for r in rows if r["engine"] == engine and r["controller"] == name] for name in names
        }
        counts = ", ".join(
            f"{name} {sum(r['converged'] for r in runs[name])}/{len(runs[name])}" for name in names
        )
        lines.append(f"- {engine}: converged {counts}.")
        for other in ("local_consensus_tuned", "bc"):
            ratios = []
            for seed in args.seeds:
                pick = {r["controller"]: r for r in rows if r["engine"] == engine and r["seed"] == seed}
                if "ppo" not in pick or other not in pick:
                    continue
                ppo, ref = pick["ppo"]["convergence_time_s"], pick[other]["convergence_time_s"]
                if ppo is not None and ref is not None:
                    ratios.append(ppo / ref)
            if ratios:
                lines.append(
                    f"  PPO / {other} on the {len(ratios)} starts where both converged: mean "
                    f"{np.mean(ratios):.3f} (min {np.min(ratios):.3f}, max {np.max(ratios):.3f})."
                )
    (out_dir / "runtime.md").write_text("\n".join(lines) + "\n")


TUNED = Path(__file__).resolve().parent.parent / "docs" / "results" / "rl" / "ppo" / "tuned_lc.json"


def tuned_gain(path: Path, topology: str, count: int) -> float:
    """The tuned K of local consensus for ``topology`` at ``count`` robots (tune_consensus_gain.py)."""
    cells = json.loads(path.read_text())["cells"]
    for cell in cells:
        if cell["topology"] == topology and cell["robots"] == count:
            return float(cell["tuned_gain_per_s"])
    raise SystemExit(f"{path}: no tuned gain for {topology} N={count}: run bench/tune_consensus_gain.py")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", default="models/gnn_ppo.npz")
    parser.add_argument("--bc", default="models/gnn_graph_filter.npz")
    parser.add_argument("--topology", default="cycle")
    parser.add_argument("--count", type=int, default=20)
    parser.add_argument(
        "--gain",
        type=float,
        help="gain of local consensus (default: the tuned one for --topology and --count in "
        "docs/results/rl/ppo/tuned_lc.json, from bench/tune_consensus_gain.py)",
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[7, 8])
    parser.add_argument("--engines", nargs="+", default=["pybullet", "kinematic"])
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument("--threshold", type=float, default=1.6, help="PyBullet threshold (m)")
    parser.add_argument("--levels", nargs="+", type=float, default=[4.0, 3.0, 2.0, 1.6])
    add_output_arguments(parser, committed=OUT_DIR)
    args = parser.parse_args()
    out_dir = output_dir(args, committed=OUT_DIR)
    if args.gain is None:
        args.gain = tuned_gain(TUNED, args.topology, args.count)
    controllers = [
        {"name": "ppo", "kind": "gnn", "model": str((ROOT / args.model).resolve())},
        {"name": "bc", "kind": "gnn", "model": str((ROOT / args.bc).resolve())},
        {"name": "local_consensus_tuned", "kind": "local_consensus", "gain": args.gain},
    ]
    rows = []
    runs = [(e, s, c) for e in args.engines for s in args.seeds for c in controllers]
    with tempfile.TemporaryDirectory(prefix="ppo-runtime-") as work:
        for engine, seed, controller in progress(runs, args, desc="ppo_runtime", unit="run"):
            data = scenario(args.count, seed, args.topology, controller, args.duration, args.threshold)
            row = {"seed": seed, "controller": controller["name"]}
            row.update(run_one(data, engine, Path(work), args.levels))
            rows.append(row)
            print(json.dumps(row), flush=True)
            write(rows, args, out_dir)


if __name__ == "__main__":
    main()
