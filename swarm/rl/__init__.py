"""Reinforcement learning for consensus (thesis section 2.5, appendices C-D, fixed).

- ``swarm.rl.vector_env``: B environments x N robots on ``KinematicSim`` (the engine, numpy in/out).
- ``swarm.rl.consensus_env``: the thesis's single-agent Gymnasium env, registered as ``swarm/Consensus-v0``.
- ``swarm.rl.consensus_v0``: the multi-agent PettingZoo env (every robot an agent, local observations).
- ``swarm.rl.coverage_v0``: the coverage task as a multi-agent PettingZoo env (reward: the decrease of
  the locational cost over the reference; ``expert_actions()``: centralized Lloyd's).
- ``swarm.rl.formation_v0``: the formation task as a multi-agent PettingZoo env (reward: the decrease of
  the bottleneck distance in steps at ``v_max``; ``expert_actions()``: the CAPT expert's).
- ``swarm.rl.dqn``: DQN on ``swarm/Consensus-v0`` with Stable-Baselines3 (``swarm train --algo dqn``).
- ``swarm.rl.torchrl_env``: the batched torch swarm of ``swarm train --algo ppo`` as a TorchRL
  multi-agent ``EnvBase`` (extra ``torchrl``; ``bench/ppo_torchrl.py`` trains TorchRL's MAPPO on it).

Importing ``swarm.rl`` registers the Gymnasium id; it does not import torch. Without importing it:
``gymnasium.make("swarm.rl:swarm/Consensus-v0")`` (Gymnasium imports the module named before the
colon). The package also declares ``register_envs`` as its ``gymnasium.envs`` entry point, which the
Gymnasium versions with the plugin system (0.26-0.29) call when ``gymnasium`` is imported.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "swarm/Consensus-v0"


def register_envs() -> None:
    """Register ``swarm/Consensus-v0`` (idempotent); the ``gymnasium.envs`` entry point of the package."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="swarm.rl.consensus_env:ConsensusEnv")


register_envs()
