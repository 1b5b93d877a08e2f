"""What the task environments share (``swarm.rl.coverage_v0``, ``swarm.rl.formation_v0``).

Each is a PettingZoo parallel environment of one swarm in the kinematic engine: every robot an agent,
``robot_0`` ... ``robot_{N-1}``, on a fixed graph, that hears its graph neighbours' axles of one tick
before (docs/design.md timing; nothing on the first tick) in ``N - 1`` neighbour slots ``[dx, dy,
heard]``; actions ``Box(-1, 1, (2,))``, the world velocity of the controlled point in units of ``v_max``
(saturated like every controller's), held ``action_repeat`` ticks; one shared reward; a central expert
(a controller kind of the task) whose ``expert_actions()`` are for imitation and the baseline to beat.
A task's environment says its starts, its observation's own part, its reward and when it is done.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import Any, TypeVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from swarm.core import topologies
from swarm.core.robot import RobotParams
from swarm.rl.consensus_v0 import global_state
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links

ConfigT = TypeVar("ConfigT", bound="SwarmEnvConfig")


@dataclass(frozen=True)
class SwarmEnvConfig:
    """The options every task environment takes (a task's config adds its own)."""

    robots: int = 6
    topology: str = "cycle"
    control_period_s: float = 0.05
    action_repeat: int = 2
    time_limit_s: float = 30.0

    def __post_init__(self) -> None:
        if self.robots < 2:
            raise ValueError(f"robots: {self.robots} is fewer than 2")
        if self.topology not in topologies.kinds() or topologies.get(self.topology).proximity:
            fixed = [kind for kind in topologies.kinds() if not topologies.get(kind).proximity]
            raise ValueError(f"topology: {self.topology!r} is not a fixed graph kind (choose from {fixed})")
        if self.action_repeat < 1 or self.time_limit_s <= 0 or self.control_period_s <= 0:
            raise ValueError("action_repeat >= 1, time_limit_s > 0 and control_period_s > 0")

    @classmethod
    def from_dict(cls: type[ConfigT], overrides: dict) -> ConfigT:
        known = {field.name for field in fields(cls)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown environment option(s) {unknown} (known: {sorted(known)})")
        return cls(**overrides)


class TaskParallelEnv(ParallelEnv):
    """The shared part of a task environment; see the module docstring. ``expert``: the central
    controller kind of ``expert_actions()``; ``own_size``: the observation's entries before the
    neighbour slots."""

    expert = ""

    def __init__(self, config: SwarmEnvConfig, section: Any, render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported")
        self.render_mode = render_mode
        self.config = config
        self.section = section
        self.robot = RobotParams()
        adjacency = topologies.build(config.topology, config.robots)
        assert adjacency is not None  # a fixed kind (SwarmEnvConfig checks)
        self.adjacency: np.ndarray = adjacency
        self.possible_agents = [f"robot_{i}" for i in range(config.robots)]
        self.agents: list[str] = []
        self.state_space = spaces.Box(-np.inf, np.inf, shape=(4 * config.robots,), dtype=np.float32)
        self._rng: np.random.Generator | None = None
        self.sim: KinematicSim | None = None
        self._heard: np.ndarray | None = None  # (N, 2) what each robot broadcast last tick (its axle)

    @property
    def own_size(self) -> int:
        raise NotImplementedError

    @functools.cache  # noqa: B019 (PettingZoo requires the same object at every call)
    def observation_space(self, agent: str) -> spaces.Box:
        size = self.own_size + 3 * (self.config.robots - 1)
        return spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def _generator(self, seed: int | None) -> np.random.Generator:
        """The episode's generator: reseeded by a seed, else the one of the last seeded reset."""
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        return self._rng

    def _start(self, poses: np.ndarray) -> None:
        """A new episode from ``poses (1, N, 3)``, with the expert ready to act."""
        args = ControllerArgs(
            robot=self.robot,
            control_period_s=self.config.control_period_s,
            robot_count=self.config.robots,
            task=self.section,
        )
        self.sim = KinematicSim(
            self.robot,
            batched_controller(self.expert, args),  # only expert_actions() calls it
            self.config.control_period_s,
            poses,
            adjacency=self.adjacency,
        )
        self._heard = None
        self.agents = list(self.possible_agents)

    def expert_actions(self) -> dict[str, np.ndarray]:
        """The central expert's actions now (its command over ``v_max``)."""
        assert self.sim is not None, "reset() first"
        nobody = Links.nobody(1, self.config.robots)  # a central expert reads no links
        u_world = self.sim.controller.act(self.sim.poses, self.sim.points, self.sim.inbox, nobody)[0][0]
        scaled = np.clip(u_world / self.robot.v_max_mps, -1.0, 1.0).astype(np.float32)
        return {agent: scaled[i] for i, agent in enumerate(self.possible_agents)}

    def _move(self, actions: dict) -> tuple[np.ndarray, float]:
        """Apply the actions for ``action_repeat`` ticks; the axles ``(N, 2)`` and the time after."""
        if not self.agents or self.sim is None:
            raise RuntimeError("step() after the episode ended: call reset()")
        wished = np.stack([np.asarray(actions[agent], dtype=np.float64) for agent in self.possible_agents])
        u_world = np.clip(wished, -1.0, 1.0)[None] * self.robot.v_max_mps
        for _ in range(self.config.action_repeat):
            self._heard = self.sim.poses[0, :, :2].copy()
            self.sim.move(u_world)
        return self.sim.poses[0, :, :2], self.sim.tick * self.config.control_period_s

    def _heard_slots(self, row: np.ndarray, i: int, own: np.ndarray, scale: float) -> None:
        """Write robot i's neighbour slots (after ``own_size``) into its observation ``row``."""
        if self._heard is None:
            return
        for slot, j in enumerate(np.flatnonzero(self.adjacency[i])):
            start = self.own_size + 3 * slot
            row[start : start + 3] = (*((self._heard[j] - own) / scale), 1.0)

    def _finish(
        self, observations: dict, reward: float, done: bool, truncated: bool, info: dict
    ) -> tuple[dict, dict, dict, dict, dict]:
        """The step's five mappings over the agents that acted; the episode ends when done or truncated."""
        agents = self.agents
        if done or truncated:
            self.agents = []
        return (
            observations,
            dict.fromkeys(agents, float(reward)),
            dict.fromkeys(agents, bool(done)),
            dict.fromkeys(agents, bool(truncated)),
            {agent: dict(info) for agent in agents},
        )

    def state(self) -> np.ndarray:
        assert self.sim is not None
        return global_state(self.sim.poses[0])

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass
