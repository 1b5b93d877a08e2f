"""The batched torch swarm of ``swarm train --algo ppo`` as a TorchRL multi-agent environment.

``SwarmTorchRLEnv`` wraps ``swarm.learn.train.ppo.TorchSwarm`` (B swarms of up to ``n_max`` robots,
padded, stepped together) in ``torchrl.envs.EnvBase`` with batch size ``[B]`` and one agent group
``"agents"`` of shape ``[B, n_max]`` (TorchRL's multi-agent layout, as in its MAPPO/IPPO
tutorials), so TorchRL's collectors, GAE and ``ClipPPOLoss`` train the same task as the
hand-written loop. Everything task-side is that loop's: the episodes (``EpisodeSampler``: graph
kind, N, start poses), the robot-frame GNN features (the timing of ``swarm.sim.kinematic``: hop-h
information is h ticks old), the saturation and the reward, shared by all robots, per tick of
``dt`` seconds::

    r_t = -dt + shaping * (gamma * Phi(s_{t+1}) - Phi(s_t)),     Phi(s) = -max_pairwise(s) / (2 v_max)

with ``Phi = 0`` at consensus (``max_pairwise <= threshold_m``: terminated) and truncation at
``max_episode_s``. Padding slots (robots a smaller swarm does not have) carry ``("agents", "mask")
= False``; their features are zero.

Keys (``B`` swarms, ``N = n_max``, ``K`` hops):

- ``("agents", "observation")`` ``(B, N, K, 2)``: each robot's features (the policy's input);
- ``("agents", "mask")`` ``(B, N)``: the robot exists;
- ``("agents", "critic_robots")`` ``(B, N, D)`` and ``"critic_summary"`` ``(B, G)``: the centralized
  critic's inputs (``swarm.learn.train.ppo.critic_inputs``), used only in training;
- ``("agents", "action")`` ``(B, N, 2)``: robot-frame point velocity (m/s), saturated on applying;
- ``"reward"`` ``(B, 1)`` (team reward), ``"done"``/``"terminated"``/``"truncated"`` ``(B, 1)``.

Partial resets (``"_reset"``) redraw only the swarms that ended, as the hand-written loop does.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from swarm.core.robot import RobotParams
from swarm.learn.train.ppo import Critic, EpisodeSampler, PPOConfig, TorchSwarm, critic_inputs

AGENTS = "agents"


class SwarmTorchRLEnv(EnvBase):
    """``config``: a ``PPOConfig`` (graphs, sizes, speed limit, period, threshold, shaping, gamma,
    ``num_envs``, ``seed``); ``hops`` and ``feature_scale_m`` come from the policy's GNN."""

    batch_locked = True

    def __init__(self, config: PPOConfig, hops: int, feature_scale_m: float, device: str = "cpu"):
        super().__init__(device=device, batch_size=torch.Size([config.num_envs]))
        self.config, self.hops, self.scale_m = config, hops, feature_scale_m
        self.robot = RobotParams(v_max_mps=config.v_max_mps)
        self.n_max = config.sizes[1]
        self.max_ticks = round(config.max_episode_s / config.control_period_s)
        self.swarm = TorchSwarm(
            config.num_envs, self.n_max, hops, self.robot, config.control_period_s, self.device, torch.float32
        )
        self.sampler = EpisodeSampler(config, np.random.default_rng(config.seed))
        self._make_specs()

    def _make_specs(self) -> None:
        B, N, K = self.config.num_envs, self.n_max, self.hops
        per_robot = K + K * (K - 1) // 2 + 2
        agents = (B, N)
        self.observation_spec = Composite(
            {
                AGENTS: Composite(
                    {
                        "observation": Unbounded((*agents, K, 2)),
                        "mask": Categorical(2, agents, dtype=torch.bool),
                        "critic_robots": Unbounded((*agents, per_robot)),
                    },
                    shape=agents,
                ),
                "critic_summary": Unbounded((B, Critic.GLOBAL)),
            },
            shape=(B,),
        )
        # any velocity is accepted: the robot saturates it (|ux| + (d/l)|uy| <= v_max)
        self.action_spec = Composite(
            {AGENTS: Composite({"action": Unbounded((*agents, 2))}, shape=agents)}, shape=(B,)
        )
        self.reward_spec = Composite({"reward": Unbounded((B, 1))}, shape=(B,))
        self.done_spec = Composite(
            {key: Categorical(2, (B, 1), dtype=torch.bool) for key in ("done", "terminated", "truncated")},
            shape=(B,),
        )

    def _set_seed(self, seed: int | None) -> None:
        self.sampler = EpisodeSampler(self.config, np.random.default_rng(seed))

    def _observation(self) -> TensorDict:
        features, _, _ = self.swarm.observe()
        robots, summary = critic_inputs(self.swarm, features, self.scale_m, self.n_max)
        agents = TensorDict(
            {"observation": features, "mask": self.swarm.valid.clone(), "critic_robots": robots},
            batch_size=(self.config.num_envs, self.n_max),
        )
        return TensorDict({AGENTS: agents, "critic_summary": summary}, batch_size=self.batch_size)

    def _potential(self) -> torch.Tensor:
        """``Phi(s) = -max_pairwise / (2 v_max)`` (s): minus a lower bound on the time left."""
        return -self.swarm.max_pairwise() / (2 * self.config.v_max_mps)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        B = self.config.num_envs
        mask = None if tensordict is None else tensordict.get("_reset", None)
        envs = list(range(B)) if mask is None else mask.reshape(B).nonzero().flatten().tolist()
        if envs:
            drawn = [self.sampler.draw() for _ in envs]
            self.swarm.load(envs, [d[0] for d in drawn], [d[1] for d in drawn], [d[2] for d in drawn])
        out = self._observation()
        false = torch.zeros(B, 1, dtype=torch.bool, device=self.device)
        out.update({"done": false, "terminated": false.clone(), "truncated": false.clone()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        config = self.config
        action = tensordict.get((AGENTS, "action"))
        potential = self._potential()
        _, phi_world, points = self.swarm.observe()
        self.swarm.step(action, phi_world, points)
        diameter = self.swarm.max_pairwise()
        terminated = diameter <= config.threshold_m
        truncated = (self.swarm.ticks >= self.max_ticks) & ~terminated
        new_potential = torch.where(terminated, torch.zeros_like(diameter), self._potential())
        reward = -config.control_period_s + config.shaping * (config.gamma * new_potential - potential)
        out = self._observation()
        out.update(
            {
                "reward": reward[:, None],
                "done": (terminated | truncated)[:, None],
                "terminated": terminated[:, None],
                "truncated": truncated[:, None],
            }
        )
        return out

    def episode_seconds(self) -> torch.Tensor:
        """Simulated time of each swarm's current episode ``(B,)`` (s)."""
        return self.swarm.ticks.to(torch.float64) * self.config.control_period_s
