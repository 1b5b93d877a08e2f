"""Kinematic simulator throughput: robot-steps per second (robots x environments x ticks / wall s).

Local consensus (the delayed-information law of swarm.sim.controllers) on fixed cycle and random
graphs and on disk graphs recomputed every tick, for the batch shapes the learning code uses:
(B=1, N=1000), (B=1024, N=6) and (B=64, N=100). Target: at least 2e7 robot-steps/s for
the two batched shapes. Writes bench/results/kinematic.json.

    python bench/bench_kinematic.py [--ticks 400] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.core import graphs
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import connecting_radius, random_edge_probability
from swarm.sim.controllers import LocalConsensus
from swarm.sim.kinematic import KinematicSim

SHAPES = [(1, 1000), (1024, 6), (64, 100)]
TARGET_ROBOT_STEPS_PER_S = 2e7


def make_sim(batch: int, count: int, graph: str, seed: int = 0) -> KinematicSim:
    rng = np.random.default_rng(seed)
    box = box_for(count)
    poses = random_poses(rng, batch, count, box, box, min_separation_m=0.0)
    robot = RobotParams()
    if graph == "cycle":
        return KinematicSim(robot, LocalConsensus(robot), 0.05, poses, adjacency=graphs.cycle(count))
    if graph == "random":
        p = random_edge_probability(count)
        adjacency = np.stack([graphs.erdos_renyi(count, p, seed + b, connected=True) for b in range(batch)])
        return KinematicSim(robot, LocalConsensus(robot), 0.05, poses, adjacency=adjacency)
    radius = connecting_radius(poses[..., :2])
    return KinematicSim(robot, LocalConsensus(robot), 0.05, poses, disk_radius_m=radius)


def measure(batch: int, count: int, graph: str, ticks: int, repeats: int) -> dict:
    sim = make_sim(batch, count, graph)
    for _ in range(10):  # compile and warm up
        sim.step()
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(ticks):
            sim.step()
        rates.append(batch * count * ticks / (time.perf_counter() - start))
    return {
        "batch": batch,
        "robots": count,
        "graph": graph,
        "ticks_per_repeat": ticks,
        "robot_steps_per_s_median": float(np.median(rates)),
        "robot_steps_per_s_best": float(np.max(rates)),
        "robot_steps_per_s_all": [round(rate) for rate in rates],
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--ticks", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=5)
    add_output_arguments(parser)
    args = parser.parse_args()
    out = output_dir(args) / "kinematic.json"
    results = []
    cases = [(graph, batch, count) for graph in ("cycle", "random", "disk") for batch, count in SHAPES]
    for graph, batch, count in progress(cases, args, desc="bench_kinematic", unit="case"):
        row = measure(batch, count, graph, args.ticks, args.repeats)
        results.append(row)
        batched = batch > 1
        verdict = ""
        if batched and graph != "disk":
            verdict = (
                "  meets 2e7"
                if row["robot_steps_per_s_median"] >= TARGET_ROBOT_STEPS_PER_S
                else "  BELOW 2e7"
            )
        print(
            f"{graph:6s} B={batch:5d} N={count:5d}: {row['robot_steps_per_s_median']:.3g} robot-steps/s "
            f"(best {row['robot_steps_per_s_best']:.3g}){verdict}"
        )
    load = os.getloadavg()
    report = {
        "benchmark": "kinematic simulator, local consensus, robot-steps per second",
        "command": "python bench/bench_kinematic.py",
        "target_batched_robot_steps_per_s": TARGET_ROBOT_STEPS_PER_S,
        "machine": {
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "load_average_1_5_15": [round(value, 2) for value in load],
        },
        "results": results,
    }
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"written {out} (load average {load[0]:.2f})")


if __name__ == "__main__":
    main()
