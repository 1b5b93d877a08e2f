"""Is centralized Lloyd's stop at 1.3 H_ref (N = 100, one-corner starts) its local minima or the grid's?

Lloyd's map on the quadrature grid is k-means on the grid's points. With 48 points a side at N = 100
a robot's cell holds about 23 of them, and a configuration can be a fixed point of the grid's map
while the continuous map would still move it: a small move carries no point across a cell's boundary.
This runs the expert ``lloyd`` (complete graph, the coverage sweep's square and one-corner starts,
``swarm.core.tasks.coverage.sweep_starts``) on the default grid and on the sweep's
(``sweep_grid_per_axis``: about ``QUADRATURE_POINTS_PER_ROBOT`` points a robot), each against the
H_ref of its own grid, and reports H / H_ref at 20, 40 and 60 s, the fixed point Lloyd's algorithm
reaches from the end, and the fewest points a cell holds there.

    python bench/investigations/lloyd_quadrature.py --out bench/results/lloyd_quadrature.md
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim

CONTROL_PERIOD_S = 0.05


def run(count: int, grid: int, starts: int, duration_s: float) -> dict:
    section = coverage.sweep_section(count).model_copy(update={"grid_per_axis": grid})
    points, weights = section.quadrature()
    h_ref = coverage.reference_cost(section, count)
    poses = coverage.sweep_starts(np.random.default_rng(count), starts, count)
    robot = RobotParams()
    args = ControllerArgs(robot=robot, control_period_s=CONTROL_PERIOD_S, robot_count=count, task=section)
    adjacency = np.ones((count, count)) - np.eye(count)
    sim = KinematicSim(robot, batched_controller("lloyd", args), CONTROL_PERIOD_S, poses, adjacency=adjacency)
    at = {}
    for tick in range(1, round(duration_s / CONTROL_PERIOD_S) + 1):
        sim.step()
        if tick % round(20.0 / CONTROL_PERIOD_S) == 0:
            ratio = coverage.locational_cost(sim.poses[..., :2], points, weights) / h_ref
            at[round(tick * CONTROL_PERIOD_S)] = np.sort(ratio)
    ends = sim.poses[..., :2]
    fixed = [coverage.lloyd(end, points, weights) for end in ends]
    fixed_ratio = np.sort([float(coverage.locational_cost(f, points, weights)) / h_ref for f in fixed])
    fewest = []
    for end in ends:
        owner = ((points[:, None, :] - end[None]) ** 2).sum(-1).argmin(axis=1)
        fewest.append(int(np.bincount(owner, minlength=count).min()))
    return {"points": len(points), "h_ref": h_ref, "at": at, "fixed": fixed_ratio, "fewest": fewest}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="*", type=int, default=[50, 100])
    parser.add_argument("--starts", type=int, default=8)
    parser.add_argument("--duration-s", type=float, default=60.0)
    parser.add_argument("--out", type=Path, default=None, help="markdown file (default: print only)")
    args = parser.parse_args()
    lines = [
        "# Centralized Lloyd against the quadrature grid (`bench/investigations/lloyd_quadrature.py`)",
        "",
        f"`python bench/investigations/lloyd_quadrature.py {' '.join(sys.argv[1:])}`"
        f" ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). The expert `lloyd` on the complete graph,"
        f" {args.starts} one-corner starts of the coverage sweep per N, each grid against its own H_ref."
        " Median and worst of H / H_ref; `fixed point`: where Lloyd's algorithm goes from the end.",
        "",
        "| N | points a side | points a robot | H_ref (m^2) | 20 s | 40 s | 60 s | fixed point"
        " | fewest points in a cell |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for count in args.sizes:
        for grid in sorted({48, coverage.sweep_grid_per_axis(count)}):
            result = run(count, grid, args.starts, args.duration_s)
            cells = [f"{np.median(r):.3f}, {r.max():.3f}" for r in result["at"].values()]
            fixed = result["fixed"]
            lines.append(
                f"| {count} | {grid} | {result['points'] / count:.0f} | {result['h_ref']:.4f} | "
                + " | ".join(cells)
                + f" | {np.median(fixed):.3f}, {fixed.max():.3f} | {min(result['fewest'])} |"
            )
            print(lines[-1], flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
