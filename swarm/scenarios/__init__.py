"""Scenarios and their results.

The one scenario schema (``scenario``), a run's results directory and ``metrics.json``
(``results``), its plots and animation (``report``) and recordings (``recording``), and grids of
scenarios in the batched engine: ``sweep`` and ``evaluate``. Imports ``swarm.sim`` and
``swarm.core`` only; learning and the runtime build on it.
"""
