"""The controllers and the batched kinematic engine that runs them.

``kinematic`` steps B x N unicycles with the information timing of docs/design.md; its numba
kernels are ``kernels``, ``mec_kernels`` and ``flood_kernel`` (with ``flood_readout``'s
constants), who heard whom is ``links``. Every controller kind is here in both forms: batched
(``controllers``; ``policy`` for a learned policy file, with its inputs in ``features``) and on
board one robot (``onboard``, numpy only); ``controller_kinds`` is their one registry.
Imports only ``swarm.core``.
"""
