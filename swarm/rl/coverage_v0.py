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

import functools
import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from swarm.core import tasks, topologies
from swarm.core.initial_poses import random_poses
from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.rl.consensus_v0 import global_state
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links


@dataclass(frozen=True)
class CoverageConfig:
    """The environment's options (keyword arguments of :func:`parallel_env`)."""

    robots: int = 6
    topology: str = "cycle"
    density: str = "uniform"
    side_m: float | None = None  # None: 0.9 sqrt(robots)
    control_period_s: float = 0.05
    action_repeat: int = 2
    time_limit_s: float = 30.0
    tolerance: float = 0.05
    success_bonus: float = 1.0
    grid_per_axis: int = 32

    def __post_init__(self) -> None:
        if self.robots < 2:
            raise ValueError(f"robots: {self.robots} is fewer than 2")
        if self.topology not in topologies.kinds() or topologies.get(self.topology).proximity:
            fixed = [kind for kind in topologies.kinds() if not topologies.get(kind).proximity]
            raise ValueError(f"topology: {self.topology!r} is not a fixed graph kind (choose from {fixed})")
        if self.density not in ("uniform", "gaussian"):
            raise ValueError(f"density: {self.density!r} is not 'uniform' or 'gaussian'")
        if self.action_repeat < 1 or self.time_limit_s <= 0 or self.control_period_s <= 0:
            raise ValueError("action_repeat >= 1, time_limit_s > 0 and control_period_s > 0")

    @classmethod
    def from_dict(cls, overrides: dict) -> CoverageConfig:
        known = {field.name for field in fields(cls)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown environment option(s) {unknown} (known: {sorted(known)})")
        return cls(**overrides)

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


class CoverageParallelEnv(ParallelEnv):
    """N robots cover a square, each an agent with local observations; see the module docstring."""

    metadata = {"name": "coverage_v0", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported")
        self.render_mode = render_mode
        self.config = CoverageConfig.from_dict(overrides)
        self.robot = RobotParams()
        self.section = self.config.section()
        self.points, self.weights = self.section.quadrature()
        self.h_ref = coverage.reference_cost(self.section, self.config.robots)
        self.centroid = coverage.density_centroid(self.points, self.weights)
        adjacency = topologies.build(self.config.topology, self.config.robots)
        assert adjacency is not None  # a fixed kind (CoverageConfig checks)
        self.adjacency: np.ndarray = adjacency
        self.possible_agents = [f"robot_{i}" for i in range(self.config.robots)]
        self.agents: list[str] = []
        self.state_space = spaces.Box(-np.inf, np.inf, shape=(4 * self.config.robots,), dtype=np.float32)
        self._rng: np.random.Generator | None = None
        self.sim: KinematicSim | None = None
        self._heard: np.ndarray | None = None  # (N, 2) what each robot broadcast last tick (its axle)
        self._cost = 0.0

    @functools.cache  # noqa: B019 (PettingZoo requires the same object at every call)
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, shape=(6 + 3 * (self.config.robots - 1),), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        half = self.config.side / 2
        poses = random_poses(self._rng, 1, self.config.robots, (-half, 0.0), (-half, 0.0), 0.3)
        args = ControllerArgs(
            robot=self.robot,
            control_period_s=self.config.control_period_s,
            robot_count=self.config.robots,
            task=self.section,
        )
        self.sim = KinematicSim(
            self.robot,
            batched_controller("lloyd", args),  # only expert_actions() calls it
            self.config.control_period_s,
            poses,
            adjacency=self.adjacency,
        )
        self._heard = None
        self._cost = float(coverage.locational_cost(self.sim.poses[0, :, :2], self.points, self.weights))
        self.agents = list(self.possible_agents)
        return self._observations(), {agent: {"ratio": self._cost / self.h_ref} for agent in self.agents}

    def expert_actions(self) -> dict[str, np.ndarray]:
        """The centralized Lloyd expert's actions now (``lloyd``'s command over ``v_max``)."""
        assert self.sim is not None, "reset() first"
        nobody = Links.nobody(1, self.config.robots)  # the central expert reads no links
        u_world = self.sim.controller.act(self.sim.poses, self.sim.points, self.sim.inbox, nobody)[0][0]
        scaled = np.clip(u_world / self.robot.v_max_mps, -1.0, 1.0).astype(np.float32)
        return {agent: scaled[i] for i, agent in enumerate(self.possible_agents)}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents or self.sim is None:
            raise RuntimeError("step() after the episode ended: call reset()")
        wished = np.stack([np.asarray(actions[agent], dtype=np.float64) for agent in self.possible_agents])
        u_world = np.clip(wished, -1.0, 1.0)[None] * self.robot.v_max_mps
        for _ in range(self.config.action_repeat):
            self._heard = self.sim.poses[0, :, :2].copy()
            self.sim.move(u_world)
        cost = float(coverage.locational_cost(self.sim.poses[0, :, :2], self.points, self.weights))
        ratio = cost / self.h_ref
        reward = (self._cost - cost) / self.h_ref
        self._cost = cost
        done = ratio <= 1.0 + self.config.tolerance
        reward += self.config.success_bonus if done else 0.0
        time_s = self.sim.tick * self.config.control_period_s
        truncated = not done and time_s >= self.config.time_limit_s - 1e-9
        agents = self.agents
        infos = {agent: {"ratio": ratio, "time_s": time_s} for agent in agents}
        observations = self._observations()
        if done or truncated:
            self.agents = []
        return (
            observations,
            dict.fromkeys(agents, float(reward)),
            dict.fromkeys(agents, bool(done)),
            dict.fromkeys(agents, bool(truncated)),
            infos,
        )

    def _observations(self) -> dict[str, np.ndarray]:
        assert self.sim is not None
        poses = self.sim.poses[0]
        count, side = self.config.robots, self.config.side
        out = {}
        for i, agent in enumerate(self.possible_agents):
            own = poses[i, :2]
            row = np.zeros(6 + 3 * (count - 1), dtype=np.float32)
            row[:4] = (own[0] / side, own[1] / side, math.cos(poses[i, 2]), math.sin(poses[i, 2]))
            row[4:6] = (self.centroid - own) / side
            if self._heard is not None:
                for slot, j in enumerate(np.flatnonzero(self.adjacency[i])):
                    row[6 + 3 * slot : 9 + 3 * slot] = (*((self._heard[j] - own) / side), 1.0)
            out[agent] = row
        return out

    def state(self) -> np.ndarray:
        assert self.sim is not None
        return global_state(self.sim.poses[0])

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass


def parallel_env(**kwargs: Any) -> CoverageParallelEnv:
    """The parallel (simultaneous-action) form; keyword arguments are ``CoverageConfig`` fields."""
    return CoverageParallelEnv(**kwargs)


def env(**kwargs: Any):
    """The AEC (turn-based) form, PettingZoo's ``parallel_to_aec``."""
    return parallel_to_aec(parallel_env(**kwargs))


raw_env = env
