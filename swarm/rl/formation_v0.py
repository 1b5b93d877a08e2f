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

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pettingzoo.utils.conversions import parallel_to_aec

from swarm.core.tasks import formation
from swarm.rl.task_env import SwarmEnvConfig, TaskParallelEnv


@dataclass(frozen=True)
class FormationConfig(SwarmEnvConfig):
    """The environment's options (keyword arguments of :func:`parallel_env`)."""

    success_bonus: float = 10.0


class FormationParallelEnv(TaskParallelEnv):
    """N robots take N slots, each an agent with local observations; see the module docstring."""

    metadata = {"name": "formation_v0", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012
    expert = "capt"

    def __init__(self, render_mode: str | None = None, **overrides: Any):
        config = FormationConfig.from_dict(overrides)
        super().__init__(config, formation.sweep_section(config.robots), render_mode)
        self.config: FormationConfig = config
        self.slots = self.section.slot_positions(config.robots)
        self.scale_m = float(np.max(np.linalg.norm(self.slots - self.slots.mean(axis=0), axis=1)))
        self._bottleneck_m = 0.0
        self._bound_s = 0.0

    @property
    def own_size(self) -> int:
        return 4 + 2 * self.config.robots

    @property
    def step_m(self) -> float:
        """How far an axle goes in one step at ``v_max``: the reward's unit."""
        return self.robot.v_max_mps * self.config.action_repeat * self.config.control_period_s

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self._start(formation.sweep_starts(self._generator(seed), 1, self.config.robots))
        self.expert_actions()  # the expert's assignment is the start's (CaptExpert fixes it at its first act)
        assert self.sim is not None
        start = self.sim.poses[0, :, :2]
        self._bottleneck_m = formation.bottleneck_distance(start, self.slots)
        self._bound_s = formation.lower_bound_s(start, self.section, self.robot.v_max_mps)
        info = {"bottleneck_m": self._bottleneck_m, "lower_bound_s": self._bound_s, "time_s": 0.0}
        return self._observations(), {agent: dict(info) for agent in self.agents}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        positions, time_s = self._move(actions)
        bottleneck_m = formation.bottleneck_distance(positions, self.slots)
        reward = (self._bottleneck_m - bottleneck_m) / self.step_m
        self._bottleneck_m = bottleneck_m
        done = bool(formation.occupied(positions, self.slots, self.section.tolerance_m))
        reward += self.config.success_bonus if done else 0.0
        truncated = not done and time_s >= self.config.time_limit_s - 1e-9
        info = {"bottleneck_m": bottleneck_m, "lower_bound_s": self._bound_s, "time_s": time_s}
        return self._finish(self._observations(), reward, done, truncated, info)

    def _observations(self) -> dict[str, np.ndarray]:
        assert self.sim is not None
        poses = self.sim.poses[0]
        count, scale = self.config.robots, self.scale_m
        out = {}
        for i, agent in enumerate(self.possible_agents):
            own = poses[i, :2]
            row = np.zeros(self.observation_space(agent).shape, dtype=np.float32)
            row[:4] = (own[0] / scale, own[1] / scale, math.cos(poses[i, 2]), math.sin(poses[i, 2]))
            row[4 : 4 + 2 * count] = ((self.slots - own) / scale).ravel()
            self._heard_slots(row, i, own, scale)
            out[agent] = row
        return out


def parallel_env(**kwargs: Any) -> FormationParallelEnv:
    """The parallel (simultaneous-action) form; keyword arguments are ``FormationConfig`` fields."""
    return FormationParallelEnv(**kwargs)


def env(**kwargs: Any):
    """The AEC (turn-based) form, PettingZoo's ``parallel_to_aec``."""
    return parallel_to_aec(parallel_env(**kwargs))


raw_env = env
