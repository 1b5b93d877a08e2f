"""Benchmark of :class:`sim_server.physics.PhysicsWorld`: physics steps/s and real-time factor.

Robots stand on a grid and get new random wheel speeds every control period (as a lockstep
server would: set wheel speeds, step one control period, read all poses). Reported per N:

- ``steps_per_s``: physics substeps per wall-clock second (including the control-tick work);
- ``real_time_factor``: simulated seconds per wall-clock second;
- ``set_wheels_us`` / ``poses_us``: wall time of one ``set_wheel_speeds`` / ``poses`` call;
- ``load_s``: construction time (loading N robots and settling).

Run: ``python bench/bench_physics.py`` (writes ``bench/results/physics.json``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
from _output import add_output_arguments, output_dir, progress

from sim_server.physics import PhysicsWorld
from swarm.core.robot import RobotParams

RESULTS = Path(__file__).resolve().parent / "results" / "physics.json"


def grid_poses(n: int, spacing_m: float, rng: np.random.Generator) -> np.ndarray:
    """N axle-centre poses on a square grid centred on the origin, random headings."""
    side = math.ceil(math.sqrt(n))
    idx = np.arange(n)
    xy = np.column_stack([idx % side, idx // side]).astype(float) * spacing_m
    xy -= xy.mean(axis=0)
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n)])


def bench_one(
    n: int,
    sim_seconds: float,
    physics_hz: float,
    solver_iterations: int,
    control_period_s: float,
    seed: int,
) -> dict:
    rng = np.random.default_rng(seed)
    params = RobotParams()
    t0 = time.perf_counter()
    world = PhysicsWorld(
        params, grid_poses(n, 0.6, rng), physics_hz=physics_hz, solver_iterations=solver_iterations
    )
    load_s = time.perf_counter() - t0
    with world:
        ticks = round(sim_seconds / control_period_s)
        commands = rng.uniform(-params.v_max_mps, params.v_max_mps, (ticks, n, 2))
        set_s = poses_s = 0.0
        start_sim = world.time_s
        t_start = time.perf_counter()
        for k in range(ticks):
            a = time.perf_counter()
            world.set_wheel_speeds(commands[k])
            b = time.perf_counter()
            world.step(control_period_s)
            c = time.perf_counter()
            world.poses()
            d = time.perf_counter()
            set_s += b - a
            poses_s += d - c
        wall = time.perf_counter() - t_start
        simulated = world.time_s - start_sim
        flipped = int(np.sum(world.tilt_rad() > np.radians(30.0)))
    steps = simulated * physics_hz
    return {
        "robots": n,
        "sim_seconds": round(simulated, 6),
        "wall_seconds": round(wall, 4),
        "steps_per_s": round(steps / wall, 1),
        "real_time_factor": round(simulated / wall, 3),
        "set_wheels_us": round(1e6 * set_s / ticks, 1),
        "poses_us": round(1e6 * poses_s / ticks, 1),
        "load_s": round(load_s, 3),
        "flipped": flipped,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[6, 50, 100, 200])
    ap.add_argument(
        "--sim-seconds",
        type=float,
        default=None,
        help="simulated seconds per size (default: 5 s for N <= 50, else 2 s)",
    )
    ap.add_argument("--physics-hz", type=float, default=240.0)
    ap.add_argument("--solver-iterations", type=int, default=10)
    ap.add_argument("--control-period", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=0)
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    out = output_dir(args) / RESULTS.name

    rows = []
    for n in progress(args.robots, args, desc="bench_physics", unit="size"):
        sim_seconds = args.sim_seconds if args.sim_seconds is not None else (5.0 if n <= 50 else 2.0)
        rows.append(
            bench_one(n, sim_seconds, args.physics_hz, args.solver_iterations, args.control_period, args.seed)
        )
        r = rows[-1]
        print(
            f"N={r['robots']:>4}  steps/s={r['steps_per_s']:>9.1f}  RTF={r['real_time_factor']:>7.2f}  "
            f"set_wheels={r['set_wheels_us']:>7.1f} us  poses={r['poses_us']:>7.1f} us  "
            f"load={r['load_s']:.2f} s  flipped={r['flipped']}",
            flush=True,
        )
    result = {
        "benchmark": "physics",
        "settings": {
            "physics_hz": args.physics_hz,
            "solver_iterations": args.solver_iterations,
            "control_period_s": args.control_period,
            "seed": args.seed,
        },
        "machine": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "pybullet": version("pybullet"),
        },
        "results": rows,
    }
    out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
