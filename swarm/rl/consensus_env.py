"""The thesis's single-agent Gymnasium environment (appendix C), ``swarm/Consensus-v0``.

Robot 0 (the thesis's "robot one") learns; robots 1..N-1 run local consensus on the graph (or, with
``others="centralized"``, the centralized expert). Observation: robot 0's ``[Mx, My, Phix, Phiy]`` in its
own frame, from its pose and its neighbours' messages of the previous tick (``float32``, zero on the
first tick when nothing has been heard yet). Actions: ``Discrete(4)``, the thesis's up/down/left/right
as unit point velocities times ``v_max`` in the robot's frame (0 forward, 1 backward, 2 left, 3 right),
held for ``action_repeat = 4`` control ticks (0.2 s); ``actions="continuous"`` gives ``Box(-1, 1, (2,))``.

Reward per step of ``dt = 0.2 s``: ``-dt * |x_0 - c_others|`` (m s; ``c_others`` the centroid of the other
robots' axle positions) plus ``success_bonus = 1`` on the step that reaches consensus. Terminated:
``max_pairwise <= 0.2 m`` over all robots. Truncated: 10 s of simulated time. ``info``: ``max_pairwise``,
``time_s`` and ``is_success`` (consensus reached on this step). Everything else, and the other options
(``robots``, ``topology``, ``frame``, ...), is ``swarm.rl.vector_env.ConsensusConfig``.

The thesis's environment ran V-REP and its DQN never trained; this one is the kinematic robot of the
whole project (same saturation and information timing) and ``swarm.rl.dqn`` learns it.

    import gymnasium, swarm.rl
    env = gymnasium.make("swarm/Consensus-v0", topology="line", actions="continuous")
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from swarm.rl.vector_env import ConsensusConfig, ConsensusVectorEnv, action_space, observation_space

THESIS_ENV = ConsensusConfig(learners="first", actions="discrete", action_repeat=4, time_limit_s=10.0)


def thesis_config(**overrides: object) -> ConsensusConfig:
    """The single-agent task's defaults (``THESIS_ENV``) with ``overrides``."""
    return ConsensusConfig.from_dict(overrides, base=THESIS_ENV)


class ConsensusEnv(gym.Env):
    """Robot 0 of a consensus swarm learns (thesis appendix C); see the module docstring."""

    metadata = {"render_modes": []}  # noqa: RUF012 (Gymnasium's convention)

    def __init__(self, render_mode: str | None = None, **overrides: object):
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r} is not supported")
        self.render_mode = render_mode
        self.config = thesis_config(**overrides)
        if self.config.learners != "first":
            raise ValueError("ConsensusEnv is single-agent: learners must be 'first'")
        self.observation_space = observation_space(self.config)
        self.action_space = action_space(self.config)
        self.core = ConsensusVectorEnv(1, self.config, autoreset=False)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        obs, info = self.core.reset(rngs=[self.np_random])
        return obs[0, 0], {"max_pairwise": float(info["max_pairwise"][0]), "time_s": 0.0, "is_success": False}

    def step(self, action) -> tuple[np.ndarray, float, bool, bool, dict]:
        actions = np.asarray(action).reshape(1, 1, *(() if self.config.actions == "discrete" else (2,)))
        obs, reward, terminated, truncated, info = self.core.step(actions)
        info = {
            "max_pairwise": float(info["max_pairwise"][0]),
            "time_s": float(info["time_s"][0]),
            "is_success": bool(terminated[0]),
        }
        return obs[0, 0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), info


def make_thesis_vector_env(num_envs: int, autoreset: bool = True, **overrides: object) -> ConsensusVectorEnv:
    """``num_envs`` copies of ``ConsensusEnv(**overrides)`` in one batch (fast evaluation)."""
    return ConsensusVectorEnv(num_envs, thesis_config(**overrides), autoreset=autoreset)
