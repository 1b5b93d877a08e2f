"""Where centralized Lloyd itself stops: its fixed points from the coverage bench's starts, against H_ref.

``bench/coverage_kinematic.py`` measured the expert ``lloyd`` at N = 50 ending 60 s runs at a median of
1.045 H_ref with 60% of the starts within 1.05. Is that slow convergence or Lloyd's local minima? This
runs ``lloyd`` (complete graph, uniform density, the bench's starts and square) for ``--duration-s`` and
prints ``H / H_ref`` of every start every 20 s, then the fixed point that Lloyd's algorithm reaches from
each end (``swarm.core.tasks.coverage.lloyd``). Equal rows mean converged: what is left is the local
minimum, which no controller that imitates Lloyd can leave.

    python bench/investigations/lloyd_local_minima.py --count 50 --duration-s 120 \
        > bench/results/lloyd_local_minima.txt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import coverage_kinematic as bench

from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--starts", type=int, default=10)
    parser.add_argument("--duration-s", type=float, default=120.0)
    args = parser.parse_args()
    section = bench.section_for(args.count, "uniform")
    points, weights = section.quadrature()
    h_ref = coverage.reference_cost(section, args.count)
    poses = bench.starts(args.count, args.starts, seed=1000 * args.count + 7)
    robot = RobotParams()
    controller_args = ControllerArgs(
        robot=robot, control_period_s=bench.CONTROL_PERIOD_S, robot_count=args.count, task=section
    )
    sim = KinematicSim(
        robot,
        batched_controller("lloyd", controller_args),
        bench.CONTROL_PERIOD_S,
        poses,
        adjacency=np.ones((args.count, args.count)) - np.eye(args.count),
    )
    print(f"lloyd, N = {args.count}, {args.starts} starts, H_ref = {h_ref:.6f} m^2; H / H_ref sorted")
    every = round(20.0 / bench.CONTROL_PERIOD_S)
    for tick in range(1, round(args.duration_s / bench.CONTROL_PERIOD_S) + 1):
        sim.step()
        if tick % every == 0:
            ratio = coverage.locational_cost(sim.poses[..., :2], points, weights) / h_ref
            rows = np.round(np.sort(ratio), 4).tolist()
            print(f"{tick * bench.CONTROL_PERIOD_S:6.1f} s: {rows}", flush=True)
    fixed = [coverage.lloyd(sim.poses[b, :, :2], points, weights) for b in range(args.starts)]
    ratio = np.sort([float(coverage.locational_cost(end, points, weights)) / h_ref for end in fixed])
    within = int(np.sum(ratio <= 1.05))
    print(f"fixed points: {np.round(ratio, 4).tolist()}; within 1.05: {within}/{args.starts}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
