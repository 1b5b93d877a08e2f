"""Reliability benchmark: consensus under link faults in the distributed runtime (``engine: pybullet``).

For every connected graph kind (complete, cycle, line, star, random-connected), swarm size N (6, 20) and
controller (the shipped GNN, local consensus) it runs the same start four times with
``python -m swarm.cli run``, real processes and real Zenoh, as a user would:

- ``none``: no fault (the reference);
- ``drop``: links dropped for the whole run while the graph stays connected: up to a fifth of the
  edges (at least one), each removed both ways when the graph stays connected without it; a tree
  (line, star) has no such edge, so one edge is dropped one way (its second robot stops hearing the
  first, chosen so that it still hears another neighbour; information still flows the other way, so
  consensus remains possible);
- ``loss 0.2`` and ``loss 0.5``: every message lost with that probability (``packet_loss`` on every
  link, ``faults_seed`` 0).

It reads each run's ``metrics.json`` (converged?, final metric, the messages the agents counted as
dropped and lost by the faults) and its trajectory: the convergence time of the max pairwise distance
to two thresholds (``THRESHOLDS_M``), and the slowdown, the convergence time over the fault-free
run's. Robots have bodies (docs/design.md, "Metrics"): the loose threshold is a chain of N touching robots
plus 0.1 m (1.3 m for 6 robots, as in scenarios/thesis; 4.66 m for 20), what local consensus on
sparse graphs jams into; the tight one (0.8 m, 2.0 m) is one compact cluster, which jams may never
reach. The scenario's ``success`` is the loose threshold.

Resumable: every finished cell is saved at once in ``bench/results/faults.json``; a new invocation
skips the cells already there (``--force`` runs them again), so the N = 20 cells can run in the
background, over several sittings. ``bench/results/faults.md`` is rewritten from the JSON each time
(``--report`` only rewrites it).

Run: ``python bench/bench_faults.py`` (everything), or e.g. ``--sizes 6 --controllers local_consensus``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.core import graphs
from swarm.core.initial_poses import box_for
from swarm.core.metrics import convergence_time, max_pairwise
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).resolve().parent / "results"
JSON_PATH, MD_PATH = RESULTS / "faults.json", RESULTS / "faults.md"

KINDS = ("complete", "cycle", "line", "star", "random")
SIZES = (6, 20)
CONTROLLERS = ("gnn", "local_consensus")
CONDITIONS = ("none", "drop", "loss 0.2", "loss 0.5")
THRESHOLDS_M = {6: (1.3, 0.8), 20: (4.66, 2.0)}
"""(loose, tight) thresholds in PyBullet, where robots have bodies (bumper radius 0.12 m). Loose: a
chain of N touching robots plus 0.1 m, ``(N - 1) * 0.24 + 0.1``, what local consensus on sparse graphs
jams into (1.3 m for 6 as in scenarios/thesis). Tight: one compact cluster. Measured fault-free at
N = 20 (seed 1): the GNN on the star gathers to 1.23-1.43 m; local consensus on the line jams at
2.7 m after 10 s, then the chain spreads again (4.6 m at 75 s, 5.9 m at 120 s), hence also the
duration."""
DURATION_S = {6: 40.0, 20: 60.0}
"""Simulated seconds per run."""
RANDOM_P = {6: 0.5, 20: 0.2}
"""Edge probability of the random connected graph (mean degree about 2.5 and 3.8)."""
SEED = 1


def topology(kind: str, count: int) -> dict:
    if kind == "random":
        return {"kind": "random", "p": RANDOM_P[count], "seed": 3, "connected": True}
    return {"kind": kind}


def dropped_links(adjacency: np.ndarray) -> list[dict]:
    """The ``drop`` condition's faults (see the module docstring), from tick 0 for the whole run."""
    edges = [(int(i), int(j)) for i, j in zip(*np.nonzero(np.triu(adjacency)), strict=True)]
    wanted = max(1, round(0.2 * len(edges)))
    rng = np.random.default_rng(SEED)
    remaining, faults = adjacency.copy(), []
    for index in rng.permutation(len(edges)):
        i, j = edges[index]
        trial = remaining.copy()
        trial[i, j] = trial[j, i] = 0
        if graphs.is_connected(trial):
            remaining = trial
            faults.append({"at": 0.0, "kind": "drop_link", "link": [i, j]})
            if len(faults) == wanted:
                break
    if not faults:  # a tree: one edge one way, heard no more by an end that still hears someone else
        i, j = edges[int(rng.integers(len(edges)))]
        sender, receiver = (i, j) if adjacency[j].sum() >= 2 else (j, i)
        faults.append({"at": 0.0, "kind": "drop_link", "link": [sender, receiver], "direction": "one"})
    return faults


def scenario_data(kind: str, count: int, controller: str, condition: str) -> dict:
    low, high = box_for(count)
    data = {
        "name": f"bench-faults-{kind}-{count}-{controller}-{condition.replace(' ', '')}",
        "robots": {
            "count": count,
            "init": {"random": {"seed": SEED, "x": [low, high], "y": [low, high], "min_separation": 0.4}},
        },
        "topology": topology(kind, count),
        "robot": {"v_max": 0.5},
        "controller": {"kind": controller},
        "sim": {
            "engine": "pybullet",
            "mode": "lockstep",
            "control_period": 0.05,
            "duration": DURATION_S[count],
        },
        "faults_seed": 0,
        "success": {"metric": "max_pairwise", "threshold": THRESHOLDS_M[count][0]},
    }
    if condition == "drop":
        data["faults"] = dropped_links(parse_scenario(data).adjacency())
    elif condition.startswith("loss"):
        data["faults"] = [{"kind": "packet_loss", "p": float(condition.split()[1])}]
    parse_scenario(data)  # a bad cell fails here, before anything starts
    return data


def cell_id(kind: str, count: int, controller: str, condition: str) -> str:
    return f"{kind}/{count}/{controller}/{condition}"


def run_cell(kind: str, count: int, controller: str, condition: str, work: Path) -> dict:
    data = scenario_data(kind, count, controller, condition)
    path, out = work / "scenario.json", work / "out"
    shutil.rmtree(out, ignore_errors=True)
    path.write_text(json.dumps(data))  # JSON is YAML
    load = os.getloadavg()[0]
    started = time.perf_counter()
    process = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(out), "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    wall_s = time.perf_counter() - started
    if process.returncode not in (0, 1):
        raise RuntimeError(f"{cell_id(kind, count, controller, condition)}: {process.stderr.strip()}")
    metrics = json.loads((out / "metrics.json").read_text())
    faults = metrics.get("faults", {})
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    values = max_pairwise(poses[..., :2])
    times = {}
    for threshold in THRESHOLDS_M[count]:
        time_s = convergence_time(times_s, values, threshold)
        times[str(threshold)] = None if np.isnan(time_s) else round(float(time_s), 3)
    return {
        "kind": kind,
        "robots": count,
        "controller": controller,
        "condition": condition,
        "faults": data.get("faults", []),
        "threshold_m": metrics["threshold"],
        "duration_s": metrics["duration_s"],
        "converged": metrics["converged"],
        "convergence_time_s": metrics["convergence_time_s"],
        "convergence_time_s_by_threshold": times,
        "final_metric_m": round(metrics["final_metric"], 4),
        "min_metric_m": round(float(values.min()), 4),
        "lower_bound_s": metrics["lower_bound_s"],
        "messages": faults.get("messages"),
        "ticks_missed": metrics["runtime"]["ticks_missed"],
        "wall_s": round(wall_s, 2),
        "load_avg_1min_before": round(load, 2),
    }


def load_results(json_path: Path) -> dict:
    if json_path.is_file():
        return json.loads(json_path.read_text())
    return {"cells": {}}


def save_results(results: dict, out_dir: Path) -> None:
    results["machine"] = {"platform": platform.platform(), "cpus": os.cpu_count()}
    results["settings"] = {
        "thresholds_m": THRESHOLDS_M,
        "duration_s": DURATION_S,
        "random_p": RANDOM_P,
        "init_seed": SEED,
        "faults_seed": 0,
        "control_period_s": 0.05,
        "mode": "lockstep",
    }
    results["cells"] = dict(sorted(results["cells"].items()))
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path = out_dir / JSON_PATH.name
    temporary = json_path.with_suffix(".json.tmp")
    temporary.write_text(json.dumps(results, indent=1) + "\n")
    os.replace(temporary, json_path)
    (out_dir / MD_PATH.name).write_text(report(results))


def _time(cell: dict | None, threshold: float) -> str:
    if cell is None:
        return "not run"
    time_s = cell["convergence_time_s_by_threshold"][str(threshold)]
    return f"{time_s:.2f} s" if time_s is not None else f"no ({cell['final_metric_m']:.2f} m)"


def _table(cells: dict, tight: bool) -> list[str]:
    lines = [
        "| graph | N | controller | none | drop | slowdown | loss 0.2 | slowdown | loss 0.5 | slowdown |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for count in SIZES:
        threshold = THRESHOLDS_M[count][int(tight)]
        for kind in KINDS:
            for controller in CONTROLLERS:
                row = [cells.get(cell_id(kind, count, controller, c)) for c in CONDITIONS]
                if not any(row):
                    continue
                times = [
                    None if cell is None else cell["convergence_time_s_by_threshold"][str(threshold)]
                    for cell in row
                ]
                entries = [_time(row[0], threshold)]
                for cell, time_s in zip(row[1:], times[1:], strict=True):
                    entries.append(_time(cell, threshold))
                    entries.append(f"{time_s / times[0]:.2f}x" if time_s and times[0] else "-")
                lines.append(
                    f"| {kind} | {count} ({threshold} m) | {controller} | " + " | ".join(entries) + " |"
                )
    return lines


def report(results: dict) -> str:
    cells = results["cells"]
    lines = [
        "`python bench/bench_faults.py`: consensus in the PyBullet runtime (lockstep, 20 Hz, real agent"
        " processes over Zenoh) under link faults, one start per cell (seed 1, robots in a box that grows"
        " with N). Entries: convergence time of the max pairwise distance to the threshold (or `no` and"
        " the final distance), and the slowdown against the fault-free run of the same cell. `drop`: up"
        " to a fifth of the edges dropped both ways for the whole run, the graph kept connected (a tree:"
        " one edge one way); `loss p`: every message lost with probability p.",
        "",
        "Loose threshold (a chain of N touching robots plus 0.1 m: 1.3 m for 6 robots, 4.66 m for 20;"
        " the scenarios' `success`):",
        "",
        *_table(cells, tight=False),
        "",
        "Tight threshold (one compact cluster: 0.8 m for 6 robots, 2.0 m for 20); jams may never reach it:",
        "",
        *_table(cells, tight=True),
    ]
    total = len(SIZES) * len(KINDS) * len(CONTROLLERS) * len(CONDITIONS)
    faulty = [cell for cell in cells.values() if cell["condition"] != "none"]
    lines += [
        "",
        f"{len(cells)} of {total} cells ran; faulty cells that met the loose threshold:"
        f" {sum(cell['converged'] for cell in faulty)} of {len(faulty)}. Per-cell details (faults,"
        " message counts, minimum and final distance, wall time, load) in `bench/results/faults.json`.",
        *NOTES,
    ]
    return "\n".join(lines) + "\n"


NOTES = [
    "",
    "Notes (measured):",
    "",
    "- Trees (line, star), `drop`: the one-way drop is chosen so that its receiver still hears another"
    " neighbour. An earlier run dropped the hub-to-leaf direction on the star, leaving leaf 15 deaf: it"
    " held still as it must, but in PyBullet the hub, jammed among 18 leaves that pushed it, drifted"
    " away from it (local consensus, N = 20, not gathered in 60 s; the kinematic engine converged):"
    " a robot that hears nobody cannot be reached by bodies that jam.",
    "- Below the loose threshold bodies dominate: robots jam, and jams form and break differently"
    " in every run. A faulty run can then be faster (cycle of 6, local consensus, to 0.8 m: 30.05 s"
    " fault-free, 7.10 s with 20% loss: the fault-free jam held 0.77-0.80 m for a long time) or never"
    " get there (local consensus on the line of 20: a chain that gathered to 2.5 m and spread again"
    " to 4.2 m fault-free, 1.41 m with 20% loss). Read the tight table's slowdowns with that in mind;"
    " the loose one compares the gathering itself.",
    "- No cell missed a tick (`ticks_missed` 0): every run is the deterministic lockstep run, and the"
    " loose-threshold times of a second full run of the benchmark were the same to the tick.",
]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), choices=SIZES)
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    parser.add_argument("--controllers", nargs="+", default=list(CONTROLLERS), choices=CONTROLLERS)
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=CONDITIONS)
    parser.add_argument("--force", action="store_true", help="run cells that are already in faults.json")
    parser.add_argument("--report", action="store_true", help="only rewrite faults.md from faults.json")
    add_output_arguments(parser)
    args = parser.parse_args()
    out_dir = output_dir(args)
    results = load_results(out_dir / JSON_PATH.name)
    if args.report:
        save_results(results, out_dir)
        return 0
    cells = [
        (kind, count, controller, condition)
        for count in args.sizes
        for kind in args.kinds
        for controller in args.controllers
        for condition in args.conditions
        if args.force or cell_id(kind, count, controller, condition) not in results["cells"]
    ]
    with tempfile.TemporaryDirectory(prefix="bench-faults-") as work:
        for kind, count, controller, condition in progress(cells, args, desc="bench_faults", unit="cell"):
            key = cell_id(kind, count, controller, condition)
            cell = run_cell(kind, count, controller, condition, Path(work))
            results["cells"][key] = cell
            save_results(results, out_dir)
            times = cell["convergence_time_s_by_threshold"]
            print(f"{key}: {times} (wall {cell['wall_s']:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
