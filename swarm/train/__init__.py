"""Training algorithms. Each module ``swarm.train.<algo>`` has a config dataclass, ``PRESETS``,
``make_config(preset, overrides)`` and ``train(config) -> Path`` (the exported policy file);
``swarm train --algo <algo>`` dispatches through ``ALGORITHMS``."""

from __future__ import annotations

ALGORITHMS: dict[str, str] = {"bc": "swarm.train.bc", "dagger": "swarm.train.dagger", "dqn": "swarm.rl.dqn"}
