"""Learning: datasets, the torch models and their training.

``data`` collects expert datasets on the sweep's graphs, ``models`` holds the torch models that
export policy files (read back in numpy by ``swarm.sim.policy``), ``train`` behavioural cloning,
DAgger, PPO, the flooding GNN's training and their evaluation. The reinforcement-learning
environments are ``swarm.rl`` (a package of its own so that its Gymnasium id keeps its name).
Imports ``swarm.scenarios``, ``swarm.sim``, ``swarm.core``; never the runtime.
"""
