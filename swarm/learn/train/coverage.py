"""Imitation of the coverage expert ``lloyd`` by ``lloyd_gnn`` (``swarm.sim.coverage_gnn``): DAgger.

Reads top to bottom: hyperparameters, episodes (rollout + expert labels), the closed-loop check, the
loop (the fit and the DAgger loop are ``swarm.learn.train.steering``'s, shared with ``capt_gnn``).

- An episode is a batch of ``envs`` starts at every N of ``counts`` (all <= 12) on every graph of
  ``graphs``: the coverage sweep's cells (``swarm.scenarios.task_sweep.cell_starts``: every robot in
  one quadrant of a square of side ``0.9 sqrt(N)`` m, uniform density; disk graphs of
  ``disk_radius_m``), run in ``KinematicSim`` for ``episode_s``, under a packet loss drawn from
  ``packet_losses`` (default: none). Every tick each robot runs
  ``lloyd_gnn``'s flood and cell (fixed, not learned) and its features are recorded with the expert's
  label: the point velocity, in the robot's frame, that centralized Lloyd commands at that state
  (toward the centroid of its true Voronoi cell, ``drive_toward_velocity``).
- Who drives: iteration 0 the expert everywhere (behavioural cloning); iteration i >= 1 the expert in a
  share ``beta_decay ** i`` of the environments and the current learner in the others (DAgger).
- The fit: every row so far; the direction only (eq. (1) drives at the expert's speed
  ``v_max min(rho_n, 1)`` toward the robot's own cell's centroid).
- Every iteration's weights are checked in closed loop on ``eval_cells``: the median over their starts
  of the first time ``H <= 1.05 H_ref`` (``eval_s`` where never), beside ``lloyd_predict``'s,
  ``lloyd_flood``'s and ``lloyd``'s on the same starts; the best iterate is the result (``policy.npz``).

Seeded: numpy and torch from ``seed``, torch on one thread: the same command on the same machine gives
the same weights.

Run: ``swarm train --algo coverage --out runs/coverage`` (``models/README.md``: the shipped file).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from swarm.core.faults import LinkFaults
from swarm.core.robot import RobotParams, world_to_local
from swarm.core.tasks import coverage
from swarm.learn.train import preset_with_overrides
from swarm.learn.train.steering import dagger
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_chunk
from swarm.sim.coverage_controllers import LloydExpert, LloydGnn
from swarm.sim.coverage_gnn import FEATURES, CoverageGnnWeights
from swarm.sim.kinematic import KinematicSim

# ------------------------------------------------------------------------------------ hyperparameters
DIRECTION_WEIGHTS = ("equal", "velocity")  # how a row's 1 - cos counts in the fit (train.steering)


@dataclass(frozen=True)
class CoverageConfig:
    out: str = "runs/coverage"
    seed: int = 0
    counts: tuple[int, ...] = (4, 6, 8, 10, 12)  # every N trained on (the issue: N <= 12)
    graphs: tuple[str, ...] = ("complete", "cycle", "line", "random", "disk")
    envs: int = 8  # starts per (N, graph) and iteration
    iterations: int = 5
    beta_decay: float = 0.5  # the expert's share of the environments in iteration i >= 1
    episode_s: float = 8.0
    disk_radius_m: float = 2.0  # the coverage sweep's
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    hidden: int = 32
    learning_rate: float = 3e-3
    steps: int = 4000  # Adam steps per iteration
    batch_rows: int = 2048
    eval_cells: tuple[tuple[str, int], ...] = (("line", 12), ("cycle", 12), ("disk", 12), ("complete", 8))
    eval_starts: int = 8
    eval_s: float = 15.0
    packet_losses: tuple[float, ...] = (0.0,)  # each episode's loss drawn from these (one: no draw)
    horizon_ticks: int = 3  # the cell's prediction horizon, kept in the policy file (docs/tasks.md)
    direction_weight: str = "equal"  # "velocity": a row's 1 - cos weighted by gate * |label| (steering.py)
    progress: bool = True


PRESETS: dict[str, CoverageConfig] = {
    "default": CoverageConfig(),
    "smoke": CoverageConfig(
        counts=(4, 6), envs=2, iterations=2, steps=50, eval_starts=2, episode_s=3.0, eval_s=4.0
    ),
}


def make_config(preset: str = "default", overrides: dict | None = None) -> CoverageConfig:
    overrides = dict(overrides or {})
    if "eval_cells" in overrides:
        overrides["eval_cells"] = tuple(tuple(cell) for cell in overrides["eval_cells"])
    tuple_fields = ("counts", "graphs", "packet_losses")
    config = preset_with_overrides("coverage", PRESETS, preset, overrides, tuple_fields)
    if config.direction_weight not in DIRECTION_WEIGHTS:
        raise ValueError(
            f"coverage option 'direction_weight': {config.direction_weight!r} is not one of"
            f" {', '.join(DIRECTION_WEIGHTS)}"
        )
    return config


def _cells(
    config: CoverageConfig, seed: int, number: int, duration_s: float | None = None
) -> TaskSweepConfig:
    return TaskSweepConfig(
        task="coverage",
        seeds=number,
        seed=seed,
        v_max_mps=config.v_max_mps,
        control_period_s=config.control_period_s,
        disk_radius_m=config.disk_radius_m,
        duration_s=duration_s,
    )


# ------------------------------------------------------------------------------------ episodes
def episode(
    config: CoverageConfig, weights: CoverageGnnWeights, beta: float, topology: str, count: int, rng
) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(features (R, 8), labels (R, 2))`` of one batch of starts (module docstring)."""
    robot = RobotParams(v_max_mps=config.v_max_mps)
    section = coverage.sweep_section(count)
    poses, adjacency = cell_starts(_cells(config, int(rng.integers(2**31)), config.envs), topology, count)
    learner = LloydGnn(robot, config.control_period_s, section, count, weights)
    expert = LloydExpert(robot, config.control_period_s, section, reverse=True)
    losses = config.packet_losses
    loss = losses[int(rng.integers(len(losses)))] if len(losses) > 1 else losses[0]
    faults = None
    if loss > 0.0:
        faults = LinkFaults.packet_loss(loss, config.control_period_s, seed=int(rng.integers(2**31)))
    sim = KinematicSim(
        robot,
        learner,
        config.control_period_s,
        poses,
        adjacency=adjacency,
        disk_radius_m=config.disk_radius_m if adjacency is None else None,
        link_faults=faults,
    )
    expert_drives = rng.random(len(poses)) < beta
    features, labels = [], []
    for _ in range(round(config.episode_s / config.control_period_s)):
        u_world = sim.act()
        expert_world = expert.velocity(sim.poses)
        assert learner.last_features is not None
        features.append(learner.last_features.reshape(-1, len(FEATURES)))
        labels.append(world_to_local(expert_world, sim.poses[..., 2]).reshape(-1, 2))
        sim.move(np.where(expert_drives[:, None, None], expert_world, u_world))
    return np.concatenate(features), np.concatenate(labels)


# ------------------------------------------------------------------------------------ the check
def closed_loop(config: CoverageConfig, weights: CoverageGnnWeights | str, seed: int) -> float:
    """Median over ``eval_cells``' starts of the first time within ``1.05 H_ref`` (``eval_s`` where never)
    of ``lloyd_gnn`` with ``weights``, or of the controller kind named (on the same starts)."""
    times = []
    robot = RobotParams(v_max_mps=config.v_max_mps)
    for topology, count in config.eval_cells:
        section = coverage.sweep_section(count)
        sweep = _cells(config, seed, config.eval_starts, config.eval_s)
        poses, adjacency = cell_starts(sweep, topology, count)
        controller = (
            weights
            if isinstance(weights, str)
            else LloydGnn(robot, config.control_period_s, section, count, weights)
        )
        frame_times, frames = run_chunk(sweep, section, controller, poses, adjacency, 0.0, 0)
        for b in range(len(poses)):
            first = coverage.outcome(frame_times, frames[:, b], section, config.v_max_mps)["first_within_s"]
            times.append(config.eval_s if first is None else first)
    return float(np.median(times))


# ------------------------------------------------------------------------------------ the loop
def train(config: CoverageConfig) -> Path:
    meta = {
        "config": asdict(config),
        "features": list(FEATURES),
        "speed": "full",
        "horizon_ticks": config.horizon_ticks,
    }
    return dagger(
        config,
        weights_class=CoverageGnnWeights,
        meta=meta,
        episode=episode,
        closed_loop=closed_loop,
        score="median_first_within_s",
        references=("lloyd_predict", "lloyd_flood", "lloyd"),
        imitate_speed=False,  # the direction only
        weighted=config.direction_weight == "velocity",
    )
