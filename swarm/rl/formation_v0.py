"""Multi-agent formation with assignment, PettingZoo module style: ``parallel_env(**kwargs)`` and ``env()``.

The formation task (``swarm.core.tasks.formation``, docs/tasks.md) as a learning problem. Every robot is
an agent, ``robot_0`` ... ``robot_{N-1}``, starting uniformly in the rendezvous sweep's box; the N goal
slots are a circle with neighbours 0.5 m apart (radius at least 1 m: ``swarm sweep --task formation``'s
cells, ``formation.sweep_section``). Each agent sees what its robot knows: its own axle position and
heading, the public slot list, and the axle positions its graph neighbours broadcast last tick
(docs/design.md timing; none on the first tick), positions relative to its own axle in units of the
slot circle's radius: ``[x, y, cos, sin]``, then ``[dx, dy]`` per slot (N), then ``[dx, dy, heard]`` per
neighbour slot (N - 1, zero when not heard): ``Box(-inf, inf, (4 + 2 N + 3 (N - 1),))``. Actions:
``Box(-1, 1, (2,))``, the world velocity of the controlled point in units of ``v_max`` (saturated like
every controller's), held ``action_repeat`` ticks.

Shared reward per step: the decrease of the bottleneck distance B (the task's metric: the least, over
assignments of robots to slots, largest axle-to-slot distance) in units of what one step at ``v_max``
covers, ``(B_before - B_after) / (v_max action_repeat dt)``: at most 1 a step, and an episode's return
telescopes to ``(B_0 - B_end) / (v_max step)``, so a return near the lower bound's step count is
near-optimal. Plus ``success_bonus`` on the step where every slot holds exactly one axle within
``tolerance_m`` (the task's rule at one instant), which terminates every agent; ``time_limit_s``
truncates. ``info``: ``bottleneck_m``, ``lower_bound_s`` (the task's bound from the start) and
``time_s``. ``expert_actions()`` gives the centralized expert ``capt``'s actions (the CAPT assignment of
the start, time-synchronized straight lines), for imitation and as the baseline to beat.

    from swarm.rl import formation_v0
    env = formation_v0.parallel_env(robots=6, topology="cycle")
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

from swarm.core import topologies
from swarm.core.robot import RobotParams
from swarm.core.tasks import formation
from swarm.rl.consensus_v0 import global_state
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links


@dataclass(frozen=True)
class FormationConfig:
    """The environment's options (keyword arguments of :func:`parallel_env`)."""

    robots: int = 6
    topology: str = "cycle"
    control_period_s: float = 0.05
    action_repeat: int = 2
    time_limit_s: float = 30.0
    success_bonus: float = 10.0

    def __post_init__(self) -> None:
        if self.robots < 2:
            raise ValueError(f"robots: {self.robots} is fewer than 2")
        if self.topology not in topologies.kinds() or topologies.get(self.topology).proximity:
            fixed = [kind for kind in topologies.kinds() if not topologies.get(kind).proximity]
            raise ValueError(f"topology: {self.topology!r} is not a fixed graph kind (choose from {fixed})")
        if self.action_repeat < 1 or self.time_limit_s <= 0 or self.control_period_s <= 0:
            raise ValueError("action_repeat >= 1, time_limit_s > 0 and control_period_s > 0")

    @classmethod
    def from_dict(cls, overrides: dict) -> FormationConfig:
        known = {field.name for field in fields(cls)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise ValueError(f"unknown environment option(s) {unknown} (known: {sorted(known)})")
        return cls(**overrides)


class FormationParallelEnv(ParallelEnv):
    """N robots take N slots, each an agent with local observations; see the module docstring."""

    metadata = {"name": "formation_v0", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, **overrides: Any):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported")
        self.render_mode = render_mode
        self.config = FormationConfig.from_dict(overrides)
        self.robot = RobotParams()
        self.section = formation.sweep_section(self.config.robots)
        self.slots = self.section.slot_positions(self.config.robots)
        self.scale_m = float(np.max(np.linalg.norm(self.slots - self.slots.mean(axis=0), axis=1)))
        adjacency = topologies.build(self.config.topology, self.config.robots)
        assert adjacency is not None  # a fixed kind (FormationConfig checks)
        self.adjacency: np.ndarray = adjacency
        self.possible_agents = [f"robot_{i}" for i in range(self.config.robots)]
        self.agents: list[str] = []
        self.state_space = spaces.Box(-np.inf, np.inf, shape=(4 * self.config.robots,), dtype=np.float32)
        self._rng: np.random.Generator | None = None
        self.sim: KinematicSim | None = None
        self._heard: np.ndarray | None = None  # (N, 2) what each robot broadcast last tick (its axle)
        self._bottleneck_m = 0.0
        self._bound_s = 0.0

    @property
    def step_m(self) -> float:
        """How far an axle goes in one step at ``v_max``: the reward's unit."""
        return self.robot.v_max_mps * self.config.action_repeat * self.config.control_period_s

    @functools.cache  # noqa: B019 (PettingZoo requires the same object at every call)
    def observation_space(self, agent: str) -> spaces.Box:
        count = self.config.robots
        return spaces.Box(-np.inf, np.inf, shape=(4 + 2 * count + 3 * (count - 1),), dtype=np.float32)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        poses = formation.sweep_starts(self._rng, 1, self.config.robots)
        args = ControllerArgs(
            robot=self.robot,
            control_period_s=self.config.control_period_s,
            robot_count=self.config.robots,
            task=self.section,
        )
        self.sim = KinematicSim(
            self.robot,
            batched_controller("capt", args),  # only expert_actions() calls it
            self.config.control_period_s,
            poses,
            adjacency=self.adjacency,
        )
        self.expert_actions()  # the expert's assignment is the start's (CaptExpert fixes it at its first act)
        self._heard = None
        start = self.sim.poses[0, :, :2]
        self._bottleneck_m = formation.bottleneck_distance(start, self.slots)
        self._bound_s = formation.lower_bound_s(start, self.section, self.robot.v_max_mps)
        self.agents = list(self.possible_agents)
        info = {"bottleneck_m": self._bottleneck_m, "lower_bound_s": self._bound_s, "time_s": 0.0}
        return self._observations(), {agent: dict(info) for agent in self.agents}

    def expert_actions(self) -> dict[str, np.ndarray]:
        """The centralized expert ``capt``'s actions now (its command over ``v_max``)."""
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
        positions = self.sim.poses[0, :, :2]
        bottleneck_m = formation.bottleneck_distance(positions, self.slots)
        reward = (self._bottleneck_m - bottleneck_m) / self.step_m
        self._bottleneck_m = bottleneck_m
        done = bool(formation.occupied(positions, self.slots, self.section.tolerance_m))
        reward += self.config.success_bonus if done else 0.0
        time_s = self.sim.tick * self.config.control_period_s
        truncated = not done and time_s >= self.config.time_limit_s - 1e-9
        agents = self.agents
        info = {"bottleneck_m": bottleneck_m, "lower_bound_s": self._bound_s, "time_s": time_s}
        infos = {agent: dict(info) for agent in agents}
        observations = self._observations()
        if done or truncated:
            self.agents = []
        return (
            observations,
            dict.fromkeys(agents, float(reward)),
            dict.fromkeys(agents, done),
            dict.fromkeys(agents, bool(truncated)),
            infos,
        )

    def _observations(self) -> dict[str, np.ndarray]:
        assert self.sim is not None
        poses = self.sim.poses[0]
        count, scale = self.config.robots, self.scale_m
        out = {}
        for i, agent in enumerate(self.possible_agents):
            own = poses[i, :2]
            row = np.zeros(4 + 2 * count + 3 * (count - 1), dtype=np.float32)
            row[:4] = (own[0] / scale, own[1] / scale, math.cos(poses[i, 2]), math.sin(poses[i, 2]))
            row[4 : 4 + 2 * count] = ((self.slots - own) / scale).ravel()
            if self._heard is not None:
                base = 4 + 2 * count
                for slot, j in enumerate(np.flatnonzero(self.adjacency[i])):
                    row[base + 3 * slot : base + 3 * slot + 3] = (*((self._heard[j] - own) / scale), 1.0)
            out[agent] = row
        return out

    def state(self) -> np.ndarray:
        assert self.sim is not None
        return global_state(self.sim.poses[0])

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass


def parallel_env(**kwargs: Any) -> FormationParallelEnv:
    """The parallel (simultaneous-action) form; keyword arguments are ``FormationConfig`` fields."""
    return FormationParallelEnv(**kwargs)


def env(**kwargs: Any):
    """The AEC (turn-based) form, PettingZoo's ``parallel_to_aec``."""
    return parallel_to_aec(parallel_env(**kwargs))


raw_env = env
