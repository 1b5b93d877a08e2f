"""Multi-agent consensus, PettingZoo module style: ``parallel_env(**kwargs)`` and ``env(**kwargs)`` (AEC).

Every robot is an agent, ``robot_0`` ... ``robot_{N-1}``. Each sees only local information: its own
``[M, Phi2, ..., PhiK]`` (``[Mx, My, Phix, Phiy]`` for K = 2) in its own frame, computed from its pose at
tick k and the messages its graph neighbours broadcast at tick k-1 (docs/design.md timing; zero on the first
tick). Actions: ``Box(-1, 1, (2,))``, the wished point velocity in the robot's frame in units of
``v_max``, saturated like every controller's (``actions="discrete"``: the thesis's four unit
velocities). Shared reward per tick of ``dt`` seconds: ``-dt * mean_i |x_i - c_{-i}|`` (m s, ``c_{-i}``
the centroid of the robots other than i) plus 1 when the swarm reaches consensus
(``max_pairwise <= 0.2 m``), which terminates every agent; 10 s of simulated time truncate.
Options: ``swarm.rl.vector_env.ConsensusConfig`` (``robots``, ``topology``, ``hops``, ...).

``state()`` is the global state for centralized critics: ``[x, y, cos th, sin th]`` of every robot.

    from swarm.rl import consensus_v0
    env = consensus_v0.parallel_env(robots=8, topology="line")
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from swarm.rl.vector_env import ConsensusConfig, ConsensusVectorEnv, action_space, observation_space


def global_state(poses: np.ndarray) -> np.ndarray:
    """``(4 N,)`` float32: ``[x, y, cos th, sin th]`` of every robot (``state()`` of the parallel envs)."""
    theta = poses[:, 2]
    columns = (poses[:, 0], poses[:, 1], np.cos(theta), np.sin(theta))
    return np.stack(columns, axis=-1).reshape(-1).astype(np.float32)


class ConsensusParallelEnv(ParallelEnv):
    """N robots, each an agent with local observations and a shared reward; see the module docstring."""

    metadata = {"name": "consensus_v0", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None, **overrides: object):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported")
        self.render_mode = render_mode
        self.config = ConsensusConfig.from_dict(overrides)
        if self.config.learners != "all":
            raise ValueError("consensus_v0: every robot is an agent (learners must be 'all')")
        self.possible_agents = [f"robot_{i}" for i in range(self.config.robots)]
        self.agents: list[str] = []
        self.core = ConsensusVectorEnv(1, self.config, autoreset=False)
        self.state_space = spaces.Box(-np.inf, np.inf, shape=(4 * self.config.robots,), dtype=np.float32)
        self._rng: np.random.Generator | None = None

    @functools.cache  # noqa: B019 (PettingZoo requires the same object at every call)
    def observation_space(self, agent: str) -> spaces.Box:
        return observation_space(self.config)

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Space:
        return action_space(self.config)

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        if seed is not None or self._rng is None:
            self._rng = np.random.default_rng(seed)
        obs, _ = self.core.reset(rngs=[self._rng])
        self.agents = list(self.possible_agents)
        return self._per_agent(obs[0]), {agent: {} for agent in self.agents}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset()")
        stacked = np.stack([np.asarray(actions[agent]) for agent in self.possible_agents])
        obs, reward, terminated, truncated, info = self.core.step(stacked[None])
        agents = self.agents
        rewards = dict.fromkeys(agents, float(reward[0]))
        terminations = dict.fromkeys(agents, bool(terminated[0]))
        truncations = dict.fromkeys(agents, bool(truncated[0]))
        shared = {"max_pairwise": float(info["max_pairwise"][0]), "time_s": float(info["time_s"][0])}
        infos = {agent: dict(shared) for agent in agents}
        observations = self._per_agent(obs[0])
        if terminated[0] or truncated[0]:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _per_agent(self, obs: np.ndarray) -> dict[str, np.ndarray]:
        return {agent: obs[i] for i, agent in enumerate(self.possible_agents)}

    def state(self) -> np.ndarray:
        return global_state(self.core.sim.poses[0])

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass


def parallel_env(**kwargs: Any) -> ConsensusParallelEnv:
    """The parallel (simultaneous-action) form; keyword arguments are ``ConsensusConfig`` fields."""
    return ConsensusParallelEnv(**kwargs)


def env(**kwargs: object):
    """The AEC (turn-based) form, PettingZoo's ``parallel_to_aec``: actions apply once every agent acted."""
    return parallel_to_aec(parallel_env(**kwargs))


raw_env = env
