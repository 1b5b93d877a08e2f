"""``mec_flood`` and ``centralized_mec`` with the controlled point far ahead of the axle, in the kinematic
engine: success rate and median time / lower bound on the sweep's starts (``swarm.scenarios.sweep``:
threshold 0.2 m, v_max 0.5 m/s, T = 0.05 s, hold 5 s) for a robot with ``--offset`` (default 0.2 m).

    python bench/investigations/offset_baselines.py --starts 200 --offset 0.2

Before the controllers steered the axle (b22e47c) they gathered the controlled points and left the axles
up to 2 l apart: 0 % success at l = 0.2 m.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse

import numpy as np

from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import SweepConfig, cell_starts, converge_batch, make_controller
from swarm.sim.kinematic import KinematicSim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=200)
    parser.add_argument("--offset", type=float, default=0.2, help="controlled-point offset l (m)")
    parser.add_argument("--max-duration", type=float, default=200.0, help="give up after (s)")
    args = parser.parse_args()
    config = SweepConfig(seeds=1000, first_starts=args.starts)
    robot = RobotParams(v_max_mps=config.v_max_mps, offset_m=args.offset)
    print(f"offset {args.offset} m, {args.starts} starts per cell")
    print("| controller | graph | N | converged | median time / lower bound | worst |")
    print("|---|---|---:|---:|---:|---:|")
    from swarm.core import metrics

    for controller in ("mec_flood", "centralized_mec"):
        for topology in ("cycle", "line", "complete"):
            for count in (6, 24):
                poses, adjacency, _ = cell_starts(config, topology, count)
                law = make_controller(controller, robot, 1.0, None, count, config.control_period_s)
                sim = KinematicSim(robot, law, config.control_period_s, poses, adjacency=adjacency)
                times = converge_batch(sim, config.threshold_m, args.max_duration, config.hold_s)
                lower = np.array(
                    [metrics.lower_bound_s(p[:, :2], config.threshold_m, config.v_max_mps) for p in poses]
                )
                ok = ~np.isnan(times)
                ratio = times[ok] / lower[ok] if ok.any() else np.array([np.nan])
                print(
                    f"| {controller} | {topology} | {count} | {ok.sum()}/{len(times)} |"
                    f" {np.median(ratio):.3f} | {np.max(ratio):.3f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
