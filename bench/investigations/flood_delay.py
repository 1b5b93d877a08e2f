"""Success of the shipped ``gnn_flood`` policy on sweep cells under a whole-run message delay.

The starts of ``swarm sweep``'s cells (``swarm.scenarios.sweep.cell_starts``, the sweep's defaults:
v_max 0.5 m/s, threshold 0.2 m held 5 s, 300 s at most) run in the kinematic engine with a
``delay`` link fault of ``--delay`` ticks on every link for the whole run, in batches of ``--batch``
starts (the batch composition once mattered: issue 18's out-of-bounds read failed the last starts of
every batch). Prints one line per cell: the success rate, the failed starts and the median time.

    python bench/investigations/flood_delay.py [--topology line] [--sizes 50] [--delay 5] \
        [--starts 200] [--batch 50] [--model models/gnn_flood.npz]
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse

import numpy as np

from swarm.core.faults import LinkFaults
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import SweepConfig, cell_starts, converge_batch
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import load_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--topology", default="line")
    parser.add_argument("--sizes", type=int, nargs="+", default=[50])
    parser.add_argument("--delay", type=int, default=5, help="extra ticks of age of every message")
    parser.add_argument("--starts", type=int, default=200)
    parser.add_argument("--batch", type=int, default=50, help="starts per engine batch")
    parser.add_argument("--model", default="models/gnn_flood.npz")
    args = parser.parse_args()
    config = SweepConfig(seeds=args.starts)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    faults = LinkFaults([{"kind": "delay", "ticks": args.delay}], config.control_period_s, 0)
    for count in args.sizes:
        poses, adjacency, radius = cell_starts(config, args.topology, count)
        times = np.full(len(poses), np.nan)
        for first in range(0, len(poses), args.batch):
            part = slice(first, first + args.batch)
            sim = KinematicSim(
                robot,
                load_policy(args.model, robot, count),
                config.control_period_s,
                poses[part],
                adjacency=None if adjacency is None else adjacency[part],
                disk_radius_m=radius,
                link_faults=faults,
            )
            times[part] = converge_batch(sim, config.threshold_m, config.max_duration_s, config.hold_s)
        failed = np.flatnonzero(np.isnan(times))
        print(
            f"{args.topology} {count}, delay {args.delay} ticks, {len(poses)} starts in batches of "
            f"{args.batch}: success {1 - len(failed) / len(poses):.3f}, failed starts {failed.tolist()}, "
            f"median {np.nanmedian(times):.2f} s"
        )


if __name__ == "__main__":
    main()
