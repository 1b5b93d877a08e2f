"""The distributed runtime: running a scenario on any engine, and the processes' shared parts.

``runner`` runs one scenario on the kinematic engine or as processes; ``distributed`` starts and
watches ``sim_server`` and the robot agents (``procs`` supervises process groups), ``wire`` is the
Zenoh protocol, ``acl`` the router's access control, ``ticks`` which ticks a receiver accepts, and
``usage`` the one-line bad-input convention of every command line; ``netns`` emulates several
hosts on one machine (network namespaces, for tests and benchmarks). Imports ``swarm.scenarios``,
``swarm.sim``, ``swarm.core``; never ``swarm.learn``.
"""
