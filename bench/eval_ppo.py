"""PPO-tuned GNN against local consensus with a tuned gain, under the speed limit.

For each graph at N robots, from the same random starts as ``swarm sweep`` (the first ``--starts``
of its 1000 per cell, seed 0), kinematic engine, v_max 0.5 m/s, control period 0.05 s, convergence
= max_pairwise <= 0.2 m held 5 s: the PPO model, the BC model it started from, local consensus
with the gain K tuned for that graph and N (``bench/tune_consensus_gain.py``, read from
``tuned_lc.json``; tuned here if missing), local consensus with K = 1 and the centralized expert
(K = 1, complete graph, everyone's current position). Per controller: success rate, median and p90
time, the ratio of its median to tuned local consensus's median, the median over starts of the
per-start time ratio to tuned local consensus, and the median per-start ratio to the lower bound
of docs/design.md. Targets: on sparse graphs the PPO median at most 0.8x tuned local
consensus with no loss of success rate; on the complete graph within 1.1x the lower bound.
Writes ``docs/results/rl/ppo/ppo_vs_tuned_lc.json`` and ``.md``.

    python bench/eval_ppo.py models/gnn_ppo.npz [--bc models/gnn_graph_filter.npz] [--starts 1000]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.core import metrics
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import cell_starts, converge_batch
from swarm.sim.controllers import Centralized, LocalConsensus
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import load_policy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from tune_consensus_gain import DEFAULT_GAINS, OUT_DIR, sweep_config, tune

SPARSE = ("cycle", "line", "random", "star")


def tuned_gains(path: Path) -> dict[tuple[str, int], float]:
    if not path.is_file():
        return {}
    cells = json.loads(path.read_text())["cells"]
    return {(c["topology"], c["robots"]): c["tuned_gain_per_s"] for c in cells if c["tuned_gain_per_s"]}


def evaluate(args: argparse.Namespace) -> list[dict]:
    robot = RobotParams(v_max_mps=0.5)
    config = sweep_config(args.starts, 0.2, 0.5, 0.05)
    gains = tuned_gains(Path(args.tuned))
    rows = []
    cells = [(topology, count) for topology in args.topologies for count in args.sizes]
    for topology, count in progress(cells, args, desc="eval_ppo", unit="cell"):
        if (topology, count) not in gains:
            found = tune([topology], [count], DEFAULT_GAINS, min(args.starts, 200))[0]
            gains[(topology, count)] = found["tuned_gain_per_s"]
        gain = gains[(topology, count)]
        controllers = {
            "ppo": lambda n: load_policy(args.model, robot, n),
            "bc": lambda n: load_policy(args.bc, robot, n),
            f"local_consensus_tuned_K{gain:g}": lambda n, g=gain: LocalConsensus(robot, g),
            "local_consensus_K1": lambda n: LocalConsensus(robot, 1.0),
            "centralized": lambda n: Centralized(robot, 1.0),
        }
        poses, adjacency, _ = cell_starts(config, topology, count)
        lower = np.array([metrics.lower_bound_s(p[:, :2], 0.2, robot.v_max_mps) for p in poses])
        times = {}
        for name, factory in controllers.items():
            started = time.perf_counter()
            sim = KinematicSim(robot, factory(count), 0.05, poses, adjacency)
            times[name] = converge_batch(sim, 0.2, args.max_duration, 5.0)
            print(f"{topology} N={count} {name}: {time.perf_counter() - started:.1f} s", flush=True)
        reference = times[f"local_consensus_tuned_K{gain:g}"]
        for name, values in times.items():
            ok = ~np.isnan(values)
            both = ok & ~np.isnan(reference)
            median = float(np.median(values[ok])) if ok.any() else None
            rows.append(
                {
                    "topology": topology,
                    "robots": count,
                    "controller": name,
                    "tuned_gain_per_s": gain,
                    "starts": len(values),
                    "success_rate": float(ok.mean()),
                    "median_time_s": median,
                    "p90_time_s": float(np.percentile(values[ok], 90)) if ok.any() else None,
                    "median_lower_bound_s": float(np.median(lower)),
                    "ratio_of_medians_to_tuned_lc": None
                    if median is None
                    else median / float(np.median(reference[~np.isnan(reference)])),
                    "median_ratio_to_tuned_lc": float(np.median(values[both] / reference[both]))
                    if both.any()
                    else None,
                    "median_ratio_to_lower_bound": float(np.median(values[ok] / lower[ok]))
                    if ok.any()
                    else None,
                }
            )
    return rows


def verdicts(rows: list[dict]) -> list[str]:
    lines = []
    for row in rows:
        if row["controller"] != "ppo":
            continue
        cell = [r for r in rows if r["topology"] == row["topology"] and r["robots"] == row["robots"]]
        tuned = next(r for r in cell if r["controller"].startswith("local_consensus_tuned"))
        name = f"{row['topology']} N={row['robots']}"
        if row["topology"] == "complete":
            ok = row["median_ratio_to_lower_bound"] is not None and row["median_ratio_to_lower_bound"] <= 1.1
            lines.append(
                f"- {name}: median t / LB = {row['median_ratio_to_lower_bound']:.3f} (target <= 1.1): "
                + ("met" if ok else "NOT met")
            )
            continue
        ratio = row["ratio_of_medians_to_tuned_lc"]
        success_ok = row["success_rate"] >= tuned["success_rate"]
        ok = ratio is not None and ratio <= 0.8 and success_ok
        bound = row["median_lower_bound_s"] / tuned["median_time_s"]
        note = ""
        if not ok and bound > 0.8:
            note = (
                f" (unreachable: the lower bound alone is {bound:.2f}x tuned local consensus's median, "
                "so no controller can get under 0.8x)"
            )
        lines.append(
            f"- {name}: PPO median {row['median_time_s']:.2f} s = {ratio:.3f}x tuned local consensus "
            f"(K = {tuned['tuned_gain_per_s']:g}, {tuned['median_time_s']:.2f} s), success "
            f"{row['success_rate']:.1%} vs {tuned['success_rate']:.1%} (target <= 0.8x, no loss of success): "
            + ("met" if ok else "NOT met")
            + note
        )
    return lines


def write(rows: list[dict], args: argparse.Namespace, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = {
        "model": args.model,
        "bc": args.bc,
        "starts": args.starts,
        "sizes": args.sizes,
        "topologies": args.topologies,
        "max_duration_s": args.max_duration,
        "v_max_mps": 0.5,
        "control_period_s": 0.05,
        "threshold_m": 0.2,
        "hold_s": 5.0,
    }
    (out_dir / "ppo_vs_tuned_lc.json").write_text(
        json.dumps({"settings": settings, "rows": rows}, indent=2) + "\n"
    )

    def fmt(value: object, digits: int = 2) -> str:
        return "-" if value is None else f"{value:.{digits}f}" if isinstance(value, float) else str(value)

    lines = [
        "# PPO-tuned GNN vs local consensus with a tuned gain (speed limit active)",
        "",
        f"Command: `python bench/eval_ppo.py {args.model} --bc {args.bc} --starts {args.starts} "
        f"--sizes {' '.join(map(str, args.sizes))} --topologies {' '.join(args.topologies)}`. Kinematic "
        "engine, v_max 0.5 m/s, control period 0.05 s, convergence = max_pairwise <= 0.2 m held 5 s, "
        f"the first {args.starts} starts of `swarm sweep` per cell (seed 0; random graphs: connected "
        "G(N, p), p = 1.5 ln N / N, one per start). Tuned K: `tuned_lc.md`. t / tuned: ratio of the "
        "medians; per-start: median over starts of the per-start ratio; t / LB: median per-start "
        "ratio to the lower bound of docs/design.md.",
        "",
        "| graph | N | controller | success | median t (s) | p90 t (s) | t / tuned LC | per-start / tuned LC "
        "| t / LB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['controller']} | {row['success_rate']:.1%} "
            f"| {fmt(row['median_time_s'])} | {fmt(row['p90_time_s'])} "
            f"| {fmt(row['ratio_of_medians_to_tuned_lc'], 3)} | {fmt(row['median_ratio_to_tuned_lc'], 3)} "
            f"| {fmt(row['median_ratio_to_lower_bound'], 3)} |"
        )
    lines += ["", "Targets:", "", *verdicts(rows)]
    (out_dir / "ppo_vs_tuned_lc.md").write_text("\n".join(lines) + "\n")


def plot_stages(out_dir: Path, stages: list[str]) -> None:
    """One learning-curve figure over the training stages from their ``<stage>_log.csv`` and
    ``<stage>_eval.csv`` in ``out_dir`` (copied from the runs): training episode time and PPO
    statistics against swarm ticks, and the deterministic policy's median times on the eval starts."""
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def read(path: Path) -> list[dict]:
        with open(path, newline="") as file:
            return [
                {k: float(v) if v not in ("", "None") else np.nan for k, v in row.items()}
                for row in csv.DictReader(file)
            ]

    fig, axes = plt.subplots(1, 3, figsize=(16, 4.2), dpi=110)
    offset = 0.0
    for index, stage in enumerate(stages):
        log, evaluation = read(out_dir / f"{stage}_log.csv"), read(out_dir / f"{stage}_eval.csv")
        steps = np.array([row["env_steps"] for row in log]) + offset
        window = 5
        times = np.array([row["episode_time_s"] for row in log])
        smooth = np.convolve(
            np.nan_to_num(times, nan=np.nanmean(times)), np.ones(window) / window, mode="same"
        )
        axes[0].plot(steps, smooth, color=f"C{index}", label=f"{stage}: mean episode time (5-update mean)")
        axes[1].plot(steps, [row["approx_kl"] for row in log], color=f"C{index}", label=f"{stage}: approx KL")
        axes[1].plot(
            steps, [row["policy_std"] for row in log], color=f"C{index}", ls="--", label=f"{stage}: std (m/s)"
        )
        eval_steps = np.array([row["env_steps"] for row in evaluation]) + offset
        for key, marker in (
            ("cycle20_median_s", "o"),
            ("line20_median_s", "s"),
            ("complete20_median_s", "^"),
        ):
            if key in evaluation[0]:
                axes[2].plot(
                    eval_steps, [row[key] for row in evaluation], marker=marker, ms=3, color=f"C{index}",
                    label=f"{stage}: {key[:-9]}",
                )  # fmt: skip
        axes[2].axvline(offset, color="grey", lw=0.8, ls=":")
        offset = steps[-1] if stage != stages[-1] else offset
    axes[0].set(xlabel="swarm ticks (all stages)", ylabel="s", title="training episodes (graph mix, N 14-24)")
    axes[1].set(xlabel="swarm ticks (all stages)", yscale="log", title="PPO statistics")
    axes[2].set(
        xlabel="swarm ticks (all stages)", ylabel="median convergence time (s)", yscale="log",
        title="deterministic policy on fixed starts (N = 20)",
    )  # fmt: skip
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out_dir / "learning_curve.png")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="the PPO policy file")
    parser.add_argument(
        "--bc", default="models/gnn_graph_filter.npz", help="the BC policy file it started from"
    )
    parser.add_argument("--topologies", nargs="+", default=["cycle", "line", "random", "complete"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[20])
    parser.add_argument("--starts", type=int, default=1000)
    parser.add_argument("--max-duration", type=float, default=3000.0)
    parser.add_argument("--tuned", default=str(OUT_DIR / "tuned_lc.json"))
    add_output_arguments(parser, committed=OUT_DIR)
    parser.add_argument(
        "--plot-stages",
        nargs="+",
        metavar="STAGE",
        help="only draw learning_curve.png from STAGE_log.csv ...",
    )
    args = parser.parse_args()
    if args.plot_stages:
        plot_stages(output_dir(args, committed=OUT_DIR), args.plot_stages)
        return
    rows = evaluate(args)
    write(rows, args, output_dir(args, committed=OUT_DIR))
    print("\n".join(verdicts(rows)))


if __name__ == "__main__":
    main()
