"""Reinforcement learning for consensus (thesis section 2.5, appendices C-D, fixed).

- ``swarm.rl.vector_env``: B environments x N robots on ``KinematicSim`` (the engine, numpy in/out).
- ``swarm.rl.consensus_env``: the thesis's single-agent Gymnasium env, registered as ``swarm/Consensus-v0``.
- ``swarm.rl.consensus_v0``: the multi-agent PettingZoo env (every robot an agent, local observations).
- ``swarm.rl.dqn``: DQN on ``swarm/Consensus-v0`` with Stable-Baselines3 (``swarm train --algo dqn``).

Importing ``swarm.rl`` registers the Gymnasium id; it does not import torch.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "swarm/Consensus-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="swarm.rl.consensus_env:ConsensusEnv")
