"""Tune the gain K of local consensus per graph under the speed limit: the baseline PPO must beat.

For each graph kind at N robots, local consensus ``u_i = -K sum_j (p_i(k) - p_j(k-1))`` runs with
every K of a log grid (default 0.25 .. 64 1/s, factor sqrt 2) from the same random starts as
``swarm sweep`` (``swarm.scenarios.sweep.cell_starts``: seed 0, the box growing with N, 0.4 m apart; random
graphs Erdos-Renyi with p = 1.5 ln N / N, redrawn until connected), kinematic engine, v_max 0.5 m/s,
control period 0.05 s, convergence = max_pairwise <= 0.2 m held for 5 s. The tuned K is the one
with the smallest median convergence time among those that converged from every start (ties: the
smaller K), after refining around the grid's best by a quarter, then an eighth of an octave either
side. Writes ``docs/results/rl/ppo/tuned_lc.json`` and ``.md`` (every K's success rate and median
time, the pick).

    python bench/tune_consensus_gain.py [--sizes 20] [--starts 200] [--gains 0.25 0.5 ...]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from _output import add_output_arguments, output_dir

from swarm.core import metrics
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import SweepConfig, cell_starts, converge_batch
from swarm.sim.controllers import LocalConsensus
from swarm.sim.kinematic import KinematicSim

OUT_DIR = Path(__file__).resolve().parent.parent / "docs" / "results" / "rl" / "ppo"
DEFAULT_GAINS = [round(0.25 * math.sqrt(2.0) ** k, 4) for k in range(17)]  # 0.25 .. 64 1/s


def sweep_config(starts: int, threshold_m: float, v_max_mps: float, control_period_s: float) -> SweepConfig:
    """The sweep's settings whose ``cell_starts`` give the evaluation's starts (first ``starts`` of 1000)."""
    return SweepConfig(
        seeds=1000,
        first_starts=starts if starts < 1000 else None,
        threshold_m=threshold_m,
        v_max_mps=v_max_mps,
        control_period_s=control_period_s,
    )


def run_gain(
    config: SweepConfig, topology: str, count: int, gain: float, max_duration_s: float, hold_s: float
) -> np.ndarray:
    """Convergence time (s, NaN: not converged) of local consensus with gain ``gain`` per start."""
    poses, adjacency, _ = cell_starts(config, topology, count)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    sim = KinematicSim(robot, LocalConsensus(robot, gain), config.control_period_s, poses, adjacency)
    return converge_batch(sim, config.threshold_m, max_duration_s, hold_s)


def measure(
    config: SweepConfig,
    topology: str,
    count: int,
    lower: np.ndarray,
    max_duration_s: float,
    hold_s: float,
    gain: float,
) -> dict:
    """Success rate and median time (and ratio to the lower bounds ``lower``) of one gain."""
    started = time.perf_counter()
    times = run_gain(config, topology, count, gain, max_duration_s, hold_s)
    ok = ~np.isnan(times)
    result = {
        "gain_per_s": gain,
        "success_rate": float(ok.mean()),
        "median_time_s": float(np.median(times[ok])) if ok.any() else None,
        "median_ratio_to_lower_bound": float(np.median(times[ok] / lower[ok])) if ok.any() else None,
        "wall_s": round(time.perf_counter() - started, 2),
    }
    print(f"{topology} N={count} K={gain:g}: {result}", flush=True)
    return result


def best_of(results: list[dict]) -> dict | None:
    """The fastest gain (median time; ties: the smaller K) among those that converged from every start."""
    complete = [g for g in results if g["success_rate"] == 1.0]
    return min(complete, key=lambda g: (g["median_time_s"], g["gain_per_s"])) if complete else None


def tune(
    topologies: list[str],
    sizes: list[int],
    gains: list[float],
    starts: int,
    threshold_m: float = 0.2,
    v_max_mps: float = 0.5,
    control_period_s: float = 0.05,
    max_duration_s: float = 3000.0,
    hold_s: float = 5.0,
    quiet: bool = True,
) -> list[dict]:
    from tqdm import tqdm

    config = sweep_config(starts, threshold_m, v_max_mps, control_period_s)
    rows = []
    cells = [(topology, count) for topology in topologies for count in sizes]
    for topology, count in tqdm(cells, desc="tune gain", unit="cell", disable=quiet):
        poses, _, _ = cell_starts(config, topology, count)
        lower = np.array([metrics.lower_bound_s(p[:, :2], threshold_m, v_max_mps) for p in poses])
        settings = (config, topology, count, lower, max_duration_s, hold_s)
        per_gain = [measure(*settings, gain) for gain in gains]
        for octave in (0.25, 0.125):  # refine around the best so far: 1/4, then 1/8 octave either side
            best = best_of(per_gain)
            if best is None:
                break
            for factor in (2.0**-octave, 2.0**octave):
                gain = round(best["gain_per_s"] * factor, 4)
                if all(g["gain_per_s"] != gain for g in per_gain):
                    per_gain.append(measure(*settings, gain))
        best = best_of(per_gain)
        per_gain.sort(key=lambda g: g["gain_per_s"])
        rows.append(
            {
                "topology": topology,
                "robots": count,
                "starts": len(poses),
                "tuned_gain_per_s": None if best is None else best["gain_per_s"],
                "tuned_median_time_s": None if best is None else best["median_time_s"],
                "median_lower_bound_s": float(np.median(lower)),
                "gains": per_gain,
            }
        )
    return rows


def write(rows: list[dict], settings: dict, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "tuned_lc.json").write_text(json.dumps({"settings": settings, "cells": rows}, indent=2) + "\n")
    lines = [
        "# Local consensus with its gain K tuned per graph (speed limit active)",
        "",
        f"Command: `python bench/tune_consensus_gain.py {settings['command']}`. Kinematic engine, "
        f"v_max {settings['v_max_mps']} m/s, control period {settings['control_period_s']} s, "
        f"max_pairwise <= {settings['threshold_m']} m held {settings['hold_s']} s, the first "
        f"{settings['starts']} starts of `swarm sweep` (seed 0). Tuned K: smallest median time among the "
        "gains that converged from every start, on a log grid (factor sqrt 2) refined around its best by a "
        "quarter, then an eighth of an octave.",
        "",
        "| graph | N | tuned K (1/s) | median t (s) | median LB (s) | t / LB |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        best = next((g for g in row["gains"] if g["gain_per_s"] == row["tuned_gain_per_s"]), None)
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['tuned_gain_per_s']} "
            f"| {row['tuned_median_time_s']:.2f} | {row['median_lower_bound_s']:.2f} "
            f"| {best['median_ratio_to_lower_bound']:.2f} |"
            if best is not None
            else f"| {row['topology']} | {row['robots']} | none converged everywhere | - | - | - |"
        )
    lines += ["", "Every gain (success rate, median time in s):", ""]
    for row in rows:
        cells = ", ".join(
            f"K={g['gain_per_s']:g}: {g['success_rate']:.0%} "
            + ("-" if g["median_time_s"] is None else f"{g['median_time_s']:.2f}")
            for g in row["gains"]
        )
        lines.append(f"- {row['topology']} N={row['robots']}: {cells}")
    (out_dir / "tuned_lc.md").write_text("\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--topologies", nargs="+", default=["complete", "cycle", "line", "random"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[20])
    parser.add_argument("--gains", nargs="+", type=float, default=DEFAULT_GAINS)
    parser.add_argument("--starts", type=int, default=200)
    parser.add_argument("--max-duration", type=float, default=3000.0)
    add_output_arguments(parser, committed=OUT_DIR)
    args = parser.parse_args()
    settings = {
        "command": f"--topologies {' '.join(args.topologies)} --sizes {' '.join(map(str, args.sizes))} "
        f"--starts {args.starts}",
        "starts": args.starts,
        "threshold_m": 0.2,
        "v_max_mps": 0.5,
        "control_period_s": 0.05,
        "hold_s": 5.0,
        "max_duration_s": args.max_duration,
        "gains_per_s": args.gains,
    }
    rows = tune(
        args.topologies,
        args.sizes,
        args.gains,
        args.starts,
        max_duration_s=args.max_duration,
        quiet=args.quiet,
    )
    write(rows, settings, output_dir(args, committed=OUT_DIR))
    for row in rows:
        print(row["topology"], row["robots"], "tuned K", row["tuned_gain_per_s"], row["tuned_median_time_s"])


if __name__ == "__main__":
    main()
