"""Quick closed-loop check of a learned policy against local consensus in the batched simulator.

Same starts, graphs and stopping rule as ``swarm sweep`` (``swarm.scenarios.sweep``): every controller of a
cell runs from identical random starts; convergence time is the first time after which
``max_pairwise`` stays under the threshold (held for ``hold_s``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from swarm.core import metrics
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams
from swarm.core.topologies import grid_index
from swarm.scenarios.sweep import SweepConfig, cell_graphs, connecting_radius, converge_batch
from swarm.sim.controllers import BatchedController, LocalConsensus
from swarm.sim.kinematic import KinematicSim

ControllerFactory = Callable[[RobotParams, int], BatchedController]


def local_consensus(robot: RobotParams, robot_count: int) -> BatchedController:
    return LocalConsensus(robot, 1.0)


def _median(values: np.ndarray, where: np.ndarray) -> float | None:
    return float(np.median(values[where])) if where.any() else None


def compare(
    controllers: dict[str, ControllerFactory],
    topologies: list[str],
    sizes: list[int],
    seeds: int = 50,
    max_duration_s: float = 600.0,
    hold_s: float = 2.0,
    threshold_m: float = 0.2,
    seed: int = 0,
    progress: bool = False,
) -> list[dict]:
    """One row per (topology, N, controller): success rate, median and p90 time, median ratio to the
    lower bound, and the median over starts of the time ratio to the first controller."""
    robot = RobotParams()
    config = SweepConfig(seeds=seeds, seed=seed)
    rows = []
    cells = [(topology, count) for topology in topologies for count in sizes]
    if progress:
        from tqdm import tqdm

        cells = tqdm(cells, desc="evaluate", unit="cell")
    for topology, count in cells:
        rng = np.random.default_rng(np.random.SeedSequence([seed, grid_index(topology), count]))
        box = box_for(count)
        poses = random_poses(rng, seeds, count, box, box, config.min_separation_m)
        adjacency = cell_graphs(config, topology, count, rng)
        radius = connecting_radius(poses[..., :2]) if adjacency is None else None
        lower = np.array(
            [metrics.lower_bound_s(start[:, :2], threshold_m, robot.v_max_mps) for start in poses]
        )
        reference = None
        for name, factory in controllers.items():
            sim = KinematicSim(robot, factory(robot, count), 0.05, poses, adjacency, radius)
            times = converge_batch(sim, threshold_m, max_duration_s, hold_s)
            if reference is None:
                reference = times
            ok = ~np.isnan(times)
            both = ok & ~np.isnan(reference)  # starts where this and the first controller converged
            rows.append(
                {
                    "topology": topology,
                    "robots": count,
                    "controller": name,
                    "success_rate": float(ok.mean()),
                    "median_time_s": _median(times, ok),
                    "p90_time_s": float(np.percentile(times[ok], 90)) if ok.any() else None,
                    "median_ratio_to_lower_bound": _median(times / np.maximum(lower, 1e-9), ok & (lower > 0)),
                    "median_ratio_to_first": _median(times / reference, both),
                }
            )
    return rows


def format_rows(rows: list[dict]) -> str:
    def fmt(value: object) -> str:
        return "-" if value is None else f"{value:.2f}" if isinstance(value, float) else str(value)

    lines = ["| topology | N | controller | success | median t (s) | p90 t (s) | t / LB | t / first |"]
    lines.append("|---|---|---|---|---|---|---|---|")
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['controller']} | {row['success_rate']:.0%} "
            f"| {fmt(row['median_time_s'])} | {fmt(row['p90_time_s'])} "
            f"| {fmt(row['median_ratio_to_lower_bound'])} | {fmt(row['median_ratio_to_first'])} |"
        )
    return "\n".join(lines)
