"""Multi-agent coverage, PettingZoo module style: ``parallel_env(**kwargs)`` and ``env(**kwargs)`` (AEC).

The coverage task (``swarm.core.tasks.coverage``, docs/tasks.md) as a learning problem. Every robot is an
agent, ``robot_0`` ... ``robot_{N-1}``, in a square of side ``0.9 sqrt(N)`` m (``side_m``) with a uniform or
(``density="gaussian"``) two-Gaussian density, starting from the lower-left quadrant (the scenarios' and
``bench/coverage_kinematic.py``'s starts). Each sees what its robot knows: its own axle position and
heading, the density's centroid (public), and the axle positions its graph neighbours broadcast last tick
(docs/design.md timing; none on the first tick), all relative to itself in units of the side, in a
fixed number of neighbour slots ``N - 1`` (``[dx, dy, heard]`` each, zero when not heard):
``Box(-inf, inf, (6 + 3 (N - 1),))``. Actions: ``Box(-1, 1, (2,))``, the world velocity of the controlled
point in units of ``v_max`` (saturated like every controller's), held ``action_repeat`` ticks.

Shared reward per step: ``(H_before - H_after) / H_ref`` (the decrease of the locational cost in units of
the reference, so that an episode's return telescopes to ``(H_0 - H_end) / H_ref``) plus
``success_bonus`` on the step where ``H <= (1 + tolerance) H_ref``, which terminates every agent;
``time_limit_s`` truncates. ``info``: ``ratio`` (``H / H_ref``) and ``time_s``. ``expert_actions()``
gives the centralized Lloyd expert's actions for the current state (``lloyd``: every robot toward its
Voronoi cell's centroid), for imitation and as the baseline to beat.

    from swarm.rl import coverage_v0
    env = coverage_v0.parallel_env(robots=8, topology="cycle")
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pettingzoo.utils.conversions import parallel_to_aec

from swarm.core import tasks
from swarm.core.initial_poses import random_poses
from swarm.core.tasks import coverage
from swarm.rl.task_env import SwarmEnvConfig, TaskParallelEnv


@dataclass(frozen=True)
class CoverageConfig(SwarmEnvConfig):
    """The environment's options (keyword arguments of :func:`parallel_env`)."""

    density: str = "uniform"
    side_m: float | None = None  # None: 0.9 sqrt(robots)
    tolerance: float = 0.05
    success_bonus: float = 1.0
    grid_per_axis: int = 32

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.density not in ("uniform", "gaussian"):
            raise ValueError(f"density: {self.density!r} is not 'uniform' or 'gaussian'")

    @property
    def side(self) -> float:
        return self.side_m if self.side_m is not None else 0.9 * math.sqrt(self.robots)

    def section(self) -> coverage.CoverageSection:
        half, side = self.side / 2, self.side
        gaussians = []
        if self.density == "gaussian":
            gaussians = [
                {"mean": [-0.2 * side, 0.25 * side], "sigma_m": 0.15 * side, "weight": 1.0},
                {"mean": [0.25 * side, -0.15 * side], "sigma_m": 0.2 * side, "weight": 1.5},
            ]
        return tasks.parse_section(
            {
                "kind": "coverage",
                "region": [[-half, -half], [half, -half], [half, half], [-half, half]],
                "gaussians": gaussians,
                "tolerance": self.tolerance,
                "grid_per_axis": self.grid_per_axis,
            }
        )


class CoverageParallelEnv(TaskParallelEnv):
    """N robots cover a square, each an agent with local observations; see the module docstring."""

    metadata = {"name": "coverage_v0", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012
    expert = "lloyd"

    def __init__(self, render_mode: str | None = None, **overrides: Any):
        config = CoverageConfig.from_dict(overrides)
        super().__init__(config, config.section(), render_mode)
        self.config: CoverageConfig = config
        self.points, self.weights = self.section.quadrature()
        self.h_ref = coverage.reference_cost(self.section, config.robots)
        self.centroid = coverage.density_centroid(self.points, self.weights)
        self._cost = 0.0

    @property
    def own_size(self) -> int:
        return 6

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        half = self.config.side / 2
        rng = self._generator(seed)
        self._start(random_poses(rng, 1, self.config.robots, (-half, 0.0), (-half, 0.0), 0.3))
        assert self.sim is not None
        self._cost = float(coverage.locational_cost(self.sim.poses[0, :, :2], self.points, self.weights))
        return self._observations(), {agent: {"ratio": self._cost / self.h_ref} for agent in self.agents}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        positions, time_s = self._move(actions)
        cost = float(coverage.locational_cost(positions, self.points, self.weights))
        ratio = cost / self.h_ref
        reward = (self._cost - cost) / self.h_ref
        self._cost = cost
        done = ratio <= 1.0 + self.config.tolerance
        reward += self.config.success_bonus if done else 0.0
        truncated = not done and time_s >= self.config.time_limit_s - 1e-9
        return self._finish(self._observations(), reward, done, truncated, {"ratio": ratio, "time_s": time_s})

    def _observations(self) -> dict[str, np.ndarray]:
        assert self.sim is not None
        poses = self.sim.poses[0]
        side = self.config.side
        out = {}
        for i, agent in enumerate(self.possible_agents):
            own = poses[i, :2]
            row = np.zeros(self.observation_space(agent).shape, dtype=np.float32)
            row[:4] = (own[0] / side, own[1] / side, math.cos(poses[i, 2]), math.sin(poses[i, 2]))
            row[4:6] = (self.centroid - own) / side
            self._heard_slots(row, i, own, side)
            out[agent] = row
        return out


def parallel_env(**kwargs: Any) -> CoverageParallelEnv:
    """The parallel (simultaneous-action) form; keyword arguments are ``CoverageConfig`` fields."""
    return CoverageParallelEnv(**kwargs)


def env(**kwargs: Any):
    """The AEC (turn-based) form, PettingZoo's ``parallel_to_aec``."""
    return parallel_to_aec(parallel_env(**kwargs))


raw_env = env
