"""GNN throughput inside the kinematic engine: robot-steps per second of the max-flooding GNN
(``gnn_flood``, compiled batched forward ``swarm.flood_kernel``) at (B = 64, N = 100) and
(B = 1024, N = 6), on cycle and random graphs. Target: 1e7 robot-steps/s.

Reports the whole engine tick (forward + unicycle step) and the forward alone, per wall second and
per CPU second of this process (the cores are shared: the load average is recorded beside; with
one numba thread, robot-steps per CPU second is what one idle core would do), plus the limit they
imply: floating-point operations per robot-step of the forward (counted from the architecture)
times the robot-steps per CPU second gives the FLOP/s the kernel sustains on one core.
Writes bench/results/gnn.json.

    python bench/bench_gnn.py [--model models/gnn_default.npz] [--ticks 200] [--repeats 5] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numba
import numpy as np

from swarm import flood_kernel, graphs
from swarm.initial_poses import box_for, random_poses
from swarm.kinematic import KinematicSim
from swarm.policy import FloodPolicy, load_policy
from swarm.sweep import random_edge_probability

SHAPES = [(64, 100), (1024, 6)]
TARGET_ROBOT_STEPS_PER_S = 1e7


def flops_per_robot_step(policy: FloodPolicy, degree: float) -> dict:
    """Counted from the architecture (multiply-add = 2; tanh, exp, sqrt, division = 1 each)."""
    p = policy.directions
    steps = int(policy.model["newton_steps"])
    flood = 2 * p * 2 + 2 * p * degree  # own projections, max over heard messages
    # the target, recomputed only on ticks where the memory changed: per Newton step and direction
    # slack (4), exp (1), moments (10); plus the 2 x 2 solve and the damping (25)
    target = 12 * p + 10 + steps * (2 * p * 15 + 25)
    steer = 20 + sum(2 * w.shape[0] * w.shape[1] + w.shape[0] for w, _ in policy._steer)
    return {
        "flood": flood,
        "target_when_memory_changed": target,
        "steer": steer,
        "total_unchanged": flood + steer + 15,
        "total_changed": flood + target + steer + 15,
    }


def make_sim(policy, batch: int, count: int, graph: str, seed: int = 0) -> KinematicSim:
    rng = np.random.default_rng(seed)
    box = box_for(count)
    poses = random_poses(rng, batch, count, box, box, min_separation_m=0.0)
    if graph == "cycle":
        adjacency = graphs.cycle(count)
    else:
        p = random_edge_probability(count)
        adjacency = np.stack([graphs.erdos_renyi(count, p, seed + b, connected=True) for b in range(batch)])
    return KinematicSim(policy.robot, policy, 0.05, poses, adjacency=adjacency)


def measure(policy, batch: int, count: int, graph: str, ticks: int, repeats: int) -> dict:
    sim = make_sim(policy, batch, count, graph)
    for _ in range(10):  # compile and warm up
        sim.step()
    engine, forward, engine_cpu, forward_cpu = [], [], [], []
    links = sim.links()
    steps = batch * count * ticks
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        for _ in range(ticks):
            sim.step()
        engine.append(steps / (time.perf_counter() - start))
        engine_cpu.append(steps / (time.process_time() - start_cpu))
        start, start_cpu = time.perf_counter(), time.process_time()
        for _ in range(ticks):
            flood_kernel.act(policy, sim.poses, sim.inbox, links)
        forward.append(steps / (time.perf_counter() - start))
        forward_cpu.append(steps / (time.process_time() - start_cpu))
    degree = float((links.index >= 0).sum(-1).mean())
    flops = flops_per_robot_step(policy, degree)
    return {
        "batch": batch,
        "robots": count,
        "graph": graph,
        "mean_degree": round(degree, 2),
        "ticks_per_repeat": ticks,
        "engine_robot_steps_per_s_median": float(np.median(engine)),
        "engine_robot_steps_per_s_best": float(np.max(engine)),
        "forward_robot_steps_per_s_median": float(np.median(forward)),
        "forward_robot_steps_per_s_best": float(np.max(forward)),
        "engine_robot_steps_per_cpu_s_best": float(np.max(engine_cpu)),
        "forward_robot_steps_per_cpu_s_best": float(np.max(forward_cpu)),
        "forward_flops_per_robot_step": flops,
        "forward_gflops_per_cpu_s_unchanged_memory": round(
            flops["total_unchanged"] * float(np.max(forward_cpu)) / 1e9, 2
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", default=str(Path(__file__).parent.parent / "models" / "gnn_default.npz"))
    parser.add_argument("--ticks", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="numba threads (large batches only)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "gnn.json"))
    args = parser.parse_args()
    numba.set_num_threads(args.threads)
    policy = load_policy(args.model)
    if not isinstance(policy, FloodPolicy):
        raise SystemExit(f"{args.model}: not a gnn_flood policy (kind {policy.kind})")
    results = []
    for graph in ("cycle", "random"):
        for batch, count in SHAPES:
            row = measure(policy, batch, count, graph, args.ticks, args.repeats)
            results.append(row)
            print(
                f"{graph:7s} B={batch:5d} N={count:4d}: "
                f"engine {row['engine_robot_steps_per_s_best']:.3g} "
                f"({row['engine_robot_steps_per_cpu_s_best']:.3g} per CPU s), forward "
                f"{row['forward_robot_steps_per_s_best']:.3g} "
                f"({row['forward_robot_steps_per_cpu_s_best']:.3g} "
                f"per CPU s) robot-steps/s; {row['forward_flops_per_robot_step']['total_unchanged']:.0f} "
                f"FLOP/robot-step, {row['forward_gflops_per_cpu_s_unchanged_memory']} GFLOP per CPU s"
            )
    report = {
        "benchmark": "gnn_flood forward inside the kinematic engine, robot-steps per second",
        "command": f"python bench/bench_gnn.py --model {args.model} --threads {args.threads}",
        "target_robot_steps_per_s": TARGET_ROBOT_STEPS_PER_S,
        "machine": {
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "numba_threads": args.threads,
            "load_average_1_5_15": [round(v, 1) for v in os.getloadavg()],
        },
        "results": results,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
