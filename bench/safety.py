"""The barrier filter in the kinematic engine: a seeded soak of random starts with obstacles, with and
without the filter, and its cost on rendezvous cells where no bodies meet.

    .venv/bin/python bench/safety.py [--starts 200] [--update-results]

Soak: ``--starts`` random starts, N uniform in 6..50, in a square of 2.5 m^2 per robot, axle centres
0.5 m apart, 0-4 random obstacles (discs of radius 0.1-0.5 m and walls 1-3 m long, 0.1 m thick) kept
0.3 m from every start, the time-optimal centralized expert ``centralized_mec`` driving everyone to one
point for 30 s, once unfiltered and once with ``safety: {kind: barrier}`` (defaults). Reported: contact
ticks and the smallest clearance (``swarm.scenarios.safety_results``), the filter's changed and
infeasible robot-ticks.

Cost: rendezvous cells (mec_flood, complete and cycle graphs, N = 6 and 20, 16 seeded starts each, no
obstacles) with a threshold of 3x the packing estimate of ``bench/make_safety_scenarios.py``, where the
bodies need not touch to succeed; convergence time filtered over unfiltered, per start.

Writes ``safety.json`` and ``safety.md`` to ``--out`` (default ``runs/bench/``) or ``bench/results/``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _output import add_output_arguments, output_dir, progress
from make_safety_scenarios import packing_estimate_m

from swarm.core import graphs, metrics
from swarm.core.initial_poses import random_poses
from swarm.core.obstacles import Capsules, ObstacleSpec
from swarm.core.robot import RobotParams
from swarm.core.safety import SafetyParams, body_distance_m
from swarm.scenarios.safety_results import contact_results
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.safety_filter import SafetyFilter

ROBOT = RobotParams()
PARAMS = SafetyParams()
PERIOD_S = 0.05


def _obstacles(rng: np.random.Generator, half: float) -> list[ObstacleSpec]:
    specs = []
    for _ in range(int(rng.integers(0, 5))):
        centre = rng.uniform(-half, half, 2)
        if rng.random() < 0.5:
            radius = float(rng.uniform(0.1, 0.5))
            specs.append(ObstacleSpec(kind="disc", centre=tuple(centre), radius_m=radius))
        else:
            angle, length = rng.uniform(0, math.pi), rng.uniform(1.0, 3.0)
            half_segment = 0.5 * length * np.array([math.cos(angle), math.sin(angle)])
            start, end = tuple(centre - half_segment), tuple(centre + half_segment)
            specs.append(ObstacleSpec(kind="wall", start=start, end=end))
    return specs


def _soak_start(seed: int) -> tuple[int, np.ndarray, list[ObstacleSpec]]:
    rng = np.random.default_rng(seed)
    count = int(rng.integers(6, 51))
    half = 0.5 * math.sqrt(2.5 * count)
    specs = _obstacles(rng, half)
    capsules = Capsules(specs)
    for _ in range(1000):
        poses = random_poses(rng, 1, count, (-half, half), (-half, half), 0.5)
        if len(capsules) == 0 or (capsules.surface_distance(poses[0, :, :2]) > 0.3).all():
            return count, poses, specs
    raise RuntimeError(f"start {seed}: no start clear of the obstacles")


def _rollout(count, poses, capsules, kind, adjacency, safe, ticks):
    controller = batched_controller(kind, ControllerArgs(robot=ROBOT, robot_count=count))
    layer = SafetyFilter(ROBOT, PARAMS, capsules) if safe else None
    sim = KinematicSim(ROBOT, controller, PERIOD_S, poses.copy(), adjacency=adjacency, safety=layer)
    started = time.perf_counter()
    trajectory = sim.rollout(ticks)
    return trajectory, (layer.counts if layer else None), time.perf_counter() - started


def soak(starts: int, args) -> dict:
    rows = []
    for seed in progress(range(starts), args, desc="soak"):
        count, poses, specs = _soak_start(seed)
        capsules = Capsules(specs)
        row: dict = {"seed": seed, "robots": count, "obstacles": len(specs)}
        for safe in (False, True):
            trajectory, counts, wall = _rollout(
                count, poses, capsules, "centralized_mec", graphs.complete(count), safe, 600
            )
            result = contact_results(trajectory[:, 0], ROBOT.body_radius_m, capsules)
            key = "filtered" if safe else "unfiltered"
            row[key] = {**result, "filter": counts, "wall_s": round(wall, 3)}
        rows.append(row)
    summary = {}
    for key in ("unfiltered", "filtered"):
        summary[key] = {
            "starts_with_contacts": sum(row[key]["contacts"]["ticks"] > 0 for row in rows),
            "contact_ticks": sum(row[key]["contacts"]["ticks"] for row in rows),
            "min_clearance_m": min(row[key]["min_clearance_m"] for row in rows),
        }
    counts = [row["filtered"]["filter"] for row in rows]
    summary["filtered"]["infeasible_robot_ticks"] = sum(c["infeasible"] for c in counts)
    summary["filtered"]["changed_robot_ticks"] = sum(c["interventions"] for c in counts)
    return {"starts": starts, "summary": summary, "rows": rows}


def cost(args) -> dict:
    cells = []
    for count in (6, 20):
        threshold = 3.0 * packing_estimate_m(count, body_distance_m(ROBOT, PARAMS))
        for graph in ("complete", "cycle"):
            adjacency = graphs.complete(count) if graph == "complete" else graphs.cycle(count)
            rng = np.random.default_rng(count)
            half = 0.5 * math.sqrt(2.5 * count) * 2.0
            poses = random_poses(rng, 16, count, (-half, half), (-half, half), 0.5)
            times = np.arange(1201) * PERIOD_S
            result = {}
            for safe in (False, True):
                trajectory, counts, wall = _rollout(
                    count, poses, Capsules(), "mec_flood", adjacency, safe, len(times) - 1
                )
                values = metrics.METRICS["max_pairwise"](np.moveaxis(trajectory[..., :2], 0, 1))
                result[safe] = (metrics.convergence_time(times, values, threshold), counts, wall)
            plain, filtered = result[False][0], result[True][0]
            ratio = filtered / plain
            cells.append(
                {
                    "robots": count,
                    "graph": graph,
                    "threshold_m": round(threshold, 3),
                    "unfiltered_s": plain.tolist(),
                    "filtered_s": filtered.tolist(),
                    "ratio_median": float(np.nanmedian(ratio)),
                    "ratio_max": float(np.nanmax(ratio)),
                    "not_converged_filtered": int(np.isnan(filtered).sum()),
                    "changed_robot_ticks": result[True][1]["interventions"],
                    "wall_s": {
                        key: round(result[safe][2], 2)
                        for key, safe in (("unfiltered", False), ("filtered", True))
                    },
                }
            )
    return {"cells": cells}


def _markdown(results: dict) -> str:
    s = results["soak"]["summary"]
    lines = [
        "# Safety filter (bench/safety.py)",
        "",
        f"`{results['command']}`",
        "",
        f"## Soak: {results['soak']['starts']} random starts, 6-50 robots, 0-4 obstacles,"
        " centralized_mec, 30 s",
        "",
        "| | starts with contacts | contact ticks | min clearance (m) |",
        "|---|---|---|---|",
    ]
    for key in ("unfiltered", "filtered"):
        lines.append(
            f"| {key} | {s[key]['starts_with_contacts']} | {s[key]['contact_ticks']} |"
            f" {s[key]['min_clearance_m']:.3f} |"
        )
    lines += [
        "",
        f"Filtered: {s['filtered']['changed_robot_ticks']} robot-ticks changed,"
        f" {s['filtered']['infeasible_robot_ticks']} infeasible (braked).",
        "",
        "## Cost on rendezvous cells where bodies need not meet (mec_flood, 16 starts per cell)",
        "",
        "| robots | graph | threshold (m) | filtered / unfiltered time: median | max"
        " | filtered not converged |",
        "|---|---|---|---|---|---|",
    ]
    for c in results["cost"]["cells"]:
        lines.append(
            f"| {c['robots']} | {c['graph']} | {c['threshold_m']:.2f} | {c['ratio_median']:.3f} |"
            f" {c['ratio_max']:.3f} | {c['not_converged_filtered']} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=200)
    add_output_arguments(parser)
    args = parser.parse_args()
    out = output_dir(args)
    command = "python bench/safety.py" + (f" --starts {args.starts}" if args.starts != 200 else "")
    results = {"command": command, "soak": soak(args.starts, args), "cost": cost(args)}
    (out / "safety.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "safety.md").write_text(_markdown(results))
    print(_markdown(results))


if __name__ == "__main__":
    main()
