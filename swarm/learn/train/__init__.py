"""Training algorithms. Each module ``swarm.learn.train.<algo>`` has a config dataclass, ``PRESETS``,
``make_config(preset, overrides)`` and ``train(config) -> Path`` (the exported policy file);
``swarm train --algo <algo>`` dispatches through ``ALGORITHMS``."""

from __future__ import annotations

ALGORITHMS: dict[str, str] = {
    "bc": "swarm.learn.train.bc",
    "dagger": "swarm.learn.train.dagger",
    "flood": "swarm.learn.train.flood",
    "formation": "swarm.learn.train.formation",
    "coverage": "swarm.learn.train.coverage",
    "dqn": "swarm.rl.dqn",
    "ppo": "swarm.learn.train.ppo",
}


def preset_with_overrides(algo: str, presets: dict, preset: str, overrides: dict | None, tuple_fields=()):
    """``presets[preset]`` with ``overrides`` applied; unknown presets or fields raise one-line
    ValueErrors; list values of ``tuple_fields`` (YAML has no tuples) become tuples."""
    from dataclasses import fields, replace

    if preset not in presets:
        raise ValueError(f"unknown {algo} preset {preset!r}; choose one of {sorted(presets)}")
    overrides = dict(overrides or {})
    known = {item.name for item in fields(presets[preset])}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown {algo} option {unknown[0]!r}; known: {sorted(known)}")
    for name in tuple_fields:
        if name in overrides:
            overrides[name] = tuple(overrides[name])
    return replace(presets[preset], **overrides)
