"""GNN throughput inside the kinematic engine: robot-steps per second of the max-flooding GNN
(``gnn_flood``, compiled batched forward ``swarm.sim.flood_kernel``) at (B = 64, N = 100) and
(B = 1024, N = 6), on cycle and random graphs. Target: 1e7 robot-steps/s on 2 cores.

For every shape, in this one invocation (the cores are shared with other jobs: the figures that
matter are ratios measured side by side, and per CPU second of this process):

- **engine**: the whole ``KinematicSim.step`` (forward + unicycle step + Python), per wall second and
  per CPU second, on one numba thread and on ``--threads`` threads (both kernels threaded);
- **profile** (one thread, per robot-step): the forward kernel called directly with the memory
  unchanged, the same kernel without the steering MLP, with every target recomputed, the unicycle
  step alone and the Python around them; the share of robot-steps whose memory changed and, of
  those, whose target was taken from a neighbour that sent the same memory;
- **limits** of this CPU for this work: the engine with a trivial controller (a constant velocity:
  Python per tick + the unicycle step), a numba loop doing the forward's floating-point operations
  per robot-step as perfectly vectorized multiply-adds with the forward's memory traffic, and the
  cosine and sine every robot-step needs (libm, as the per-robot form). Their sum per robot-step is
  what one core could do at best with this arithmetic if every heard message were read; the kernel
  skips the neighbours whose memory did not change at the last tick, so it can beat it.

Then it re-runs one committed 1000-start evaluation cell (``--cell``, default the line of 100 of
``docs/results/flood/eval_a``, the settings of ``docs/results/flood/evaluate.sh``) and records its
CPU seconds and whether every start's convergence time is the committed one.

Writes ``gnn.json`` (with the load average before and after) to ``--out`` (default ``runs/bench/``);
``--update-results`` rewrites the committed ``bench/results/gnn.json``.

    python bench/bench_gnn.py [--model models/gnn_flood.npz] [--ticks 200] [--repeats 5] [--threads 2]
        [--cell line:100] [--cells docs/results/flood/eval_a] [--out DIR | --update-results] [--quiet]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

import numba
import numpy as np
from _output import add_output_arguments, output_dir, progress

from swarm.core import graphs
from swarm.core.initial_poses import box_for, random_poses
from swarm.scenarios.sweep import SweepConfig, cell_path, random_edge_probability, run_cell
from swarm.sim import flood_kernel, kernels
from swarm.sim.kinematic import KinematicSim, same_lists
from swarm.sim.policy import FloodPolicy, load_policy

SHAPES = [(64, 100), (1024, 6)]
TARGET_ROBOT_STEPS_PER_S = 1e7
LIMIT_CHAINS = 8  # independent multiply-add chains per lane in the FLOP-limit loop


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


class ConstantVelocity:
    """The trivial controller of the engine limit: every robot the same world velocity, no messages."""

    centralized = False
    message_dim = 0

    def __init__(self, batch: int, count: int):
        self.u_world = np.tile([0.3, 0.1], (batch, count, 1))
        self.outbox = np.zeros((batch, count, 0))

    def act(self, poses, points, inbox, heard):
        return self.u_world, self.outbox


@numba.njit(cache=True)
def _flop_limit(poses, inbox, neighbour_index, multiply_adds, lanes, u_world, outbox):
    """The forward's memory traffic (pose, own message, heard messages in; message and velocity out)
    around ``multiply_adds`` multiply-adds per robot in ``LIMIT_CHAINS`` independent chains, the loop
    over a block of robots innermost (vectorized: AVX-512 here, no fastmath), the form the steering
    MLP takes in ``swarm.sim.flood_kernel``: what numba sustains on this CPU for that work."""
    batch, count = poses.shape[0], poses.shape[1]
    dim, slots, rows = outbox.shape[2], neighbour_index.shape[2], batch * count
    seed = np.empty(lanes)
    chains = np.empty((LIMIT_CHAINS, lanes))
    rounds = multiply_adds // LIMIT_CHAINS
    for block in range(0, rows, lanes):
        filled = min(lanes, rows - block)
        env, i = block // count, block % count - 1
        for lane in range(filled):
            i += 1
            if i == count:
                env, i = env + 1, 0
            value = poses[env, i, 0] + poses[env, i, 1] + poses[env, i, 2]
            for d in range(dim):
                value = max(value, inbox[env, i, d])
            for k in range(slots):
                j = neighbour_index[env, i, k]
                if j < 0:
                    break
                for d in range(dim):
                    value = max(value, inbox[env, j, d])
            seed[lane] = 1e-3 * value
        for chain in range(LIMIT_CHAINS):
            for lane in range(lanes):
                chains[chain, lane] = seed[lane]
        for _ in range(rounds):
            for chain in range(LIMIT_CHAINS):
                factor = 0.999 - 1e-3 * chain
                for lane in range(lanes):
                    chains[chain, lane] = chains[chain, lane] * factor + 1e-3
        env, i = block // count, block % count - 1
        for lane in range(filled):
            i += 1
            if i == count:
                env, i = env + 1, 0
            total = 0.0
            for chain in range(LIMIT_CHAINS):
                total += chains[chain, lane]
            for d in range(dim):
                outbox[env, i, d] = total
            u_world[env, i, 0] = total
            u_world[env, i, 1] = -total


@numba.njit(cache=True)
def _trig_limit(poses, out):
    """The cosine and sine of every robot's heading (libm), nothing else."""
    batch, count = poses.shape[0], poses.shape[1]
    for env in range(batch):
        for i in range(count):
            theta = poses[env, i, 2]
            out[env, i, 0] = math.cos(theta)
            out[env, i, 1] = math.sin(theta)


def cpu_per_call(function, calls: int, repeats: int) -> float:
    """Best CPU seconds of this process per call over ``repeats`` runs of ``calls`` calls."""
    best = math.inf
    for _ in range(repeats):
        start = time.process_time()
        for _ in range(calls):
            function()
        best = min(best, (time.process_time() - start) / calls)
    return best


def run_engine(policy, batch, count, graph, ticks, repeats, threads) -> dict:
    """The whole engine tick on ``threads`` numba threads: best and median robot-steps per wall second
    and per CPU second over ``repeats`` runs of ``ticks`` ticks (the swarm keeps moving between runs)."""
    numba.set_num_threads(threads)
    kernels.PARALLEL_MIN_ROBOTS = 0 if threads > 1 else 1 << 62
    try:
        sim = make_sim(policy, batch, count, graph)
        for _ in range(10):  # compile and warm up
            sim.step()
        steps = batch * count * ticks
        wall, cpu = [], []
        for _ in range(repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            for _ in range(ticks):
                sim.step()
            wall.append(steps / (time.perf_counter() - start))
            cpu.append(steps / (time.process_time() - start_cpu))
    finally:
        kernels.PARALLEL_MIN_ROBOTS = PARALLEL_MIN_ROBOTS
    return {
        "threads": threads,
        "robot_steps_per_wall_s_best": float(np.max(wall)),
        "robot_steps_per_wall_s_median": float(np.median(wall)),
        "robot_steps_per_cpu_s_best": float(np.max(cpu)),
        "robot_steps_per_cpu_s_median": float(np.median(cpu)),
    }


def recompute_shares(policy, batch, count, graph, ticks) -> dict:
    """Over the first ``10 + ticks`` ticks of the benchmark's run: the share of robot-steps whose
    memory changed (the target must be had anew) and, of those, the share whose new memory equals a
    heard neighbour's last memory (whose target came with it)."""
    sim = make_sim(policy, batch, count, graph)
    dim = policy.memory_dim
    changed_total = reused_total = 0
    for _ in range(10 + ticks):
        before, links = sim.inbox.copy(), sim._sent_over
        sim.step()
        memory = sim.inbox[..., :dim]
        changed = np.any(memory != before[..., :dim], axis=-1) | (before[..., dim + 2] <= 0)
        reused = np.zeros_like(changed)
        for slot in range(links.index.shape[-1]):
            j = links.index[..., slot]
            theirs = np.take_along_axis(before, np.maximum(j, 0)[..., None], axis=1)
            reused |= (j >= 0) & (theirs[..., dim + 2] > 0) & np.all(theirs[..., :dim] == memory, axis=-1)
        changed_total += int(changed.sum())
        reused_total += int((changed & reused).sum())
    robot_steps = (10 + ticks) * batch * count
    return {
        "memory_changed_share": changed_total / robot_steps,
        "target_from_neighbour_share_of_changed": reused_total / max(changed_total, 1),
        "target_recomputed_share": (changed_total - reused_total) / robot_steps,
    }


def profile(policy, batch, count, graph, repeats) -> dict:
    """Nanoseconds of one CPU per robot-step (one thread) of the parts of an engine tick."""
    numba.set_num_threads(1)
    kernels.PARALLEL_MIN_ROBOTS = 1 << 62
    try:
        sim = make_sim(policy, batch, count, graph)
        for _ in range(60):  # past the flood: the memory no longer changes
            sim.step()
        robots = batch * count
        calls = max(3, 2_000_000 // robots)
        heard = sim._sent_over  # the links the engine's next call hears over (a fixed graph: links)
        last = sim._flood_call
        assert last is not None and last.outbox is sim.inbox
        skip = flood_kernel.Skip(last.unchanged, same_lists(heard, last.heard))  # as the engine's call
        weights = flood_kernel.packed(policy)
        inputs = flood_kernel.Inputs(sim.poses, sim.inbox, np.ascontiguousarray(heard.index), skip)
        outputs = flood_kernel.Outputs(
            np.empty((batch, count, 2)), np.empty(sim.inbox.shape), np.empty((batch, count), dtype=np.bool_)
        )
        block = flood_kernel.BLOCK
        direct = cpu_per_call(
            lambda: flood_kernel._serial(weights, inputs, outputs, block, 1), calls, repeats
        )
        no_mlp = weights._replace(steer_shapes=weights.steer_shapes[:0])  # no steering layers
        without_mlp = cpu_per_call(
            lambda: flood_kernel._serial(no_mlp, inputs, outputs, block, 1), calls, repeats
        )
        invalid = sim.inbox.copy()
        invalid[..., -1] = 0.0  # no message is valid: every target recomputed (and no max skipped)
        fresh = inputs._replace(inbox=invalid)
        recompute = cpu_per_call(
            lambda: flood_kernel._serial(weights, fresh, outputs, block, 1), max(3, calls // 20), repeats
        )
        act = cpu_per_call(
            lambda: flood_kernel.act(policy, sim.poses, sim.inbox, heard, skip), calls, repeats
        )
        u_world = np.zeros((batch, count, 2))
        poses, headings, points = sim.poses.copy(), sim.headings.copy(), sim.points.copy()
        robot = policy.robot

        def advance():
            kernels.advance_unicycles(
                poses.reshape(-1, 3),
                headings.reshape(-1, 2),
                points.reshape(-1, 2),
                u_world.reshape(-1, 2),
                robot.offset_m,
                robot.half_axle_m,
                robot.v_max_mps,
                0.05,
            )

        unicycle = cpu_per_call(advance, calls, repeats)
        engine = cpu_per_call(sim.step, calls, repeats)
    finally:
        kernels.PARALLEL_MIN_ROBOTS = PARALLEL_MIN_ROBOTS
    per_step = 1e9 / robots
    return {
        "engine_step_ns": engine * per_step,
        "forward_kernel_unchanged_memory_ns": direct * per_step,
        "steering_mlp_ns": (direct - without_mlp) * per_step,
        "forward_kernel_without_mlp_ns": without_mlp * per_step,
        "target_recompute_extra_ns": (recompute - direct) * per_step,
        "python_and_allocations_of_act_ns": (act - direct) * per_step,
        "unicycle_step_ns": unicycle * per_step,
        "python_of_engine_step_ns": (engine - act - unicycle) * per_step,
    }


def limits(policy, batch, count, graph, flops: float, repeats: int) -> dict:
    """Robot-steps per CPU second of the three floors (module docstring), one thread."""
    numba.set_num_threads(1)
    robots = batch * count
    calls = max(3, 2_000_000 // robots)
    sim = make_sim(policy, batch, count, graph)
    nobody = np.zeros((count, count))
    trivial = KinematicSim(policy.robot, ConstantVelocity(batch, count), 0.05, sim.poses, adjacency=nobody)
    for _ in range(3):
        trivial.step()
    engine = cpu_per_call(trivial.step, calls, repeats)
    links = sim.links()
    u_world = np.empty((batch, count, 2))
    outbox = np.empty(sim.inbox.shape)
    index = np.ascontiguousarray(links.index)
    multiply_adds = round(flops / 2 / LIMIT_CHAINS) * LIMIT_CHAINS
    _flop_limit(sim.poses, sim.inbox, index, multiply_adds, flood_kernel.BLOCK, u_world, outbox)
    arithmetic = cpu_per_call(
        lambda: _flop_limit(sim.poses, sim.inbox, index, multiply_adds, flood_kernel.BLOCK, u_world, outbox),
        calls,
        repeats,
    )
    trig = np.empty((batch, count, 2))
    cosine_sine = cpu_per_call(lambda: _trig_limit(sim.poses, trig), calls, repeats)
    floor = engine + arithmetic + cosine_sine
    return {
        "engine_trivial_controller_robot_steps_per_cpu_s": robots / engine,
        "flops_and_traffic_robot_steps_per_cpu_s": robots / arithmetic,
        "flops_and_traffic_gflops_per_cpu_s": 2 * multiply_adds * robots / arithmetic / 1e9,
        "cos_sin_robot_steps_per_cpu_s": robots / cosine_sine,
        "sum_of_floors_robot_steps_per_cpu_s": robots / floor,
    }


PARALLEL_MIN_ROBOTS = kernels.PARALLEL_MIN_ROBOTS


def measure(policy, batch: int, count: int, graph: str, ticks: int, repeats: int, threads: int) -> dict:
    serial = run_engine(policy, batch, count, graph, ticks, repeats, 1)
    threaded = run_engine(policy, batch, count, graph, ticks, repeats, threads) if threads > 1 else None
    sim = make_sim(policy, batch, count, graph)
    degree = float((sim.links().index >= 0).sum(-1).mean())
    flops = flops_per_robot_step(policy, degree)
    shares = recompute_shares(policy, batch, count, graph, ticks)
    recomputed = shares["target_recomputed_share"]
    mean_flops = flops["total_unchanged"] + recomputed * flops["target_when_memory_changed"]
    limit = limits(policy, batch, count, graph, flops["total_unchanged"], repeats)
    return {
        "batch": batch,
        "robots": count,
        "graph": graph,
        "mean_degree": round(degree, 2),
        "ticks_per_repeat": ticks,
        "repeats": repeats,
        "engine_one_thread": serial,
        "engine_threaded": threaded,
        "profile_ns_per_robot_step_one_thread": profile(policy, batch, count, graph, repeats),
        "recompute": shares,
        "limits_one_thread": limit,
        "flops_per_robot_step": flops,
        "mean_flops_per_robot_step_of_the_run": mean_flops,
        "engine_gflops_per_cpu_s": round(mean_flops * serial["robot_steps_per_cpu_s_best"] / 1e9, 2),
    }


def reproduce_cell(model: str, cell: str, cells_dir: Path) -> dict:
    """Re-run a committed evaluation cell (``topology:N``, 1000 starts, at most 300 s each, one
    thread) and compare every start's convergence time with the committed file's."""
    topology, count = cell.split(":")
    config = SweepConfig(
        topologies=[topology],
        sizes=[int(count)],
        seeds=1000,
        controllers=["gnn"],
        max_duration_s=300.0,
        model=model,
    )
    committed_path = cell_path(cells_dir / "cells", config, topology, int(count), "gnn")
    if not committed_path.is_file():  # another model: its cells are under its own hash
        return {"cell": cell, "skipped": f"no committed cell {committed_path}"}
    numba.set_num_threads(1)
    start, start_cpu = time.perf_counter(), time.process_time()
    result = run_cell(config, topology, int(count), "gnn")
    cpu_s, wall_s = time.process_time() - start_cpu, time.perf_counter() - start
    times = result["times_s"]
    with np.load(committed_path) as committed:
        same = bool(np.array_equal(times, committed["times_s"], equal_nan=True))
        differing = int(
            np.sum(~((times == committed["times_s"]) | (np.isnan(times) & np.isnan(committed["times_s"]))))
        )
    ratio = times / result["lower_bound_s"]
    return {
        "cell": f"{topology}, N = {count}, 1000 starts, gnn {Path(model).name}",
        "committed_file": str(committed_path),
        "cpu_s": round(cpu_s, 1),
        "wall_s": round(wall_s, 1),
        "every_start_time_identical": same,
        "starts_differing": differing,
        "median_ratio": round(float(np.nanmedian(ratio)), 4),
        "p95_ratio": round(float(np.nanpercentile(ratio, 95)), 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", default="models/gnn_flood.npz")
    parser.add_argument("--ticks", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2, help="numba threads of the threaded engine run")
    add_output_arguments(parser)
    parser.add_argument(
        "--cell", default="line:100", help="committed cell to re-run, topology:N ('' for none)"
    )
    parser.add_argument(
        "--cells", default="docs/results/flood/eval_a", help="directory whose cells/ holds it"
    )
    args = parser.parse_args()
    policy = load_policy(args.model)
    if not isinstance(policy, FloodPolicy):
        raise SystemExit(f"{args.model}: not a gnn_flood policy (kind {policy.kind})")
    load_before = [round(v, 1) for v in os.getloadavg()]
    results = []
    cases = [(graph, batch, count) for graph in ("cycle", "random") for batch, count in SHAPES]
    bar = progress(cases, args, desc="bench_gnn", unit="shape")
    for graph, batch, count in bar:
        row = measure(policy, batch, count, graph, args.ticks, args.repeats, args.threads)
        results.append(row)
        one, many, limit = row["engine_one_thread"], row["engine_threaded"], row["limits_one_thread"]
        wall = many["robot_steps_per_wall_s_best"] if many else float("nan")
        many_cpu = many["robot_steps_per_cpu_s_best"] if many else float("nan")
        bar.write(
            f"{graph:7s} B={batch:5d} N={count:4d}: engine "
            f"{one['robot_steps_per_cpu_s_best']:.3g} per CPU s (1 thread), {wall:.3g} per wall s "
            f"({args.threads} threads, {many_cpu:.3g} per CPU s); floors "
            f"{limit['sum_of_floors_robot_steps_per_cpu_s']:.3g} per CPU s; target recomputed in "
            f"{100 * row['recompute']['target_recomputed_share']:.1f}% of robot-steps"
        )
    reproduction = reproduce_cell(args.model, args.cell, Path(args.cells)) if args.cell else None
    if reproduction and "skipped" in reproduction:
        print(f"cell {args.cell}: skipped, {reproduction['skipped']}")
    elif reproduction:
        print(
            f"cell {reproduction['cell']}: {reproduction['cpu_s']} CPU s, every start's time as committed: "
            f"{reproduction['every_start_time_identical']}"
        )
    report = {
        "benchmark": "gnn_flood forward inside the kinematic engine, robot-steps per second",
        "command": f"python bench/bench_gnn.py --update-results --model {args.model} "
        f"--threads {args.threads} --ticks {args.ticks} --repeats {args.repeats} "
        f"--cell '{args.cell}' --cells {args.cells}",
        "target_robot_steps_per_s": TARGET_ROBOT_STEPS_PER_S,
        "machine": {
            "python": platform.python_version(),
            "numba": numba.__version__,
            "cpu_count": os.cpu_count(),
            "threads": args.threads,
            "load_average_1_5_15_before": load_before,
            "load_average_1_5_15_after": [round(v, 1) for v in os.getloadavg()],
        },
        "results": results,
        "cell_reproduction": reproduction,
    }
    out = output_dir(args) / "gnn.json"
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
