"""The task registry: the one place that says what a task is (docs/tasks.md).

A :class:`Task` names everything a run of it needs beyond the robot and the graph: its scenario
section (a pydantic model, the ``task`` key of a scenario; ``kind`` selects the entry), what each
robot knows, its centralized expert(s) and decentralized baseline(s) (names of controller kinds of
``swarm.sim.controller_kinds``, which holds their engines' forms), its metric and success rule, its
lower bound (with its proof) or reference value, its reward for the RL environments and its plot.
The last two are dotted names (``module:function``) resolved by the layers above, so that this
module stays in the math layer. The scenario schema, ``swarm run`` and the results read this
registry; nothing else lists tasks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

Outcome = Callable[..., dict]


class StrictSection(BaseModel):
    """The base of a task's scenario section and its parts: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)


@dataclass(frozen=True)
class SweepCells:
    """How ``swarm sweep --task`` (``swarm.scenarios.task_sweep``) draws and judges a cell of a task.

    ``section``: ``N -> section`` of a cell with N robots. ``starts``: ``(rng, number, N) -> (B, N, 3)``
    poses. ``duration_s``: simulated time of a cell, unless every start holds ``held`` (when given) for
    the section's ``hold_s`` before it. ``held``: ``(positions (B, N, 2), section) -> (B,)`` the success
    rule at one instant (None: a cell always runs ``duration_s``). ``sample_every_ticks``: positions kept
    for the outcome every this many ticks. ``columns``: the ``outcome`` keys tabled as median and p95
    over the starts (a dotted key reads into a mapping: ``ratio_at_s.5``)."""

    section: Callable[[int], Any]
    starts: Callable[[np.random.Generator, int, int], np.ndarray]
    duration_s: float
    columns: tuple[str, ...]
    held: Callable[[np.ndarray, Any], np.ndarray] | None = None
    sample_every_ticks: int = 1


@dataclass(frozen=True)
class Task:
    """One task. ``section``: the pydantic model of the scenario's ``task`` mapping (a ``kind``
    field with this task's name as its only value). ``knows``: what each robot knows, in words.
    ``experts`` / ``baselines`` / ``learned``: controller kinds that do this task. ``metric`` and
    ``success``: in words; ``outcome`` (None: the scenario's ``success`` section and
    ``swarm.scenarios.results.summarize`` judge the run, as for rendezvous) computes the task's
    results from ``(times_s (T,), positions (T, N, 2), section, v_max_mps)``. ``bound``: ``lower_bound``
    (proved in the function's docstring) or ``reference`` (a value to compare with, not a bound);
    ``bound_s``: ``(initial_positions (N, 2), section, v_max_mps, threshold_m) -> s`` (``threshold_m``: the
    scenario's success threshold, which only rendezvous reads). ``reward`` and ``plot``:
    ``module:function`` of the RL reward and of the results' pictures."""

    name: str
    summary: str
    section: type[BaseModel]
    knows: str
    experts: tuple[str, ...]
    baselines: tuple[str, ...]
    metric: str
    success: str
    bound: Literal["lower_bound", "reference"]
    bound_s: Callable[..., float] | None
    reward: str
    plot: str
    learned: tuple[str, ...] = ()
    outcome: Outcome | None = None
    series: Callable[..., np.ndarray] | None = None
    """``(positions (T, N, 2), section) -> (T,)``: the task's metric over a run (what its plot and the
    recordings draw); None: the scenario's success metric (``swarm.core.metrics.METRICS``)."""
    reference: Callable[..., float] | None = None
    """``bound == "reference"``: ``(section, robot_count) -> value`` of the metric to compare with (its
    docstring says how it is found and that it is not a bound)."""
    sweep: SweepCells | None = None
    """How ``swarm sweep --task`` measures this task (None: not by that command; rendezvous has its own
    sweep, ``swarm.scenarios.sweep``)."""

    @property
    def controllers(self) -> tuple[str, ...]:
        """Every controller kind that does this task."""
        return (*self.experts, *self.baselines, *self.learned)


_REGISTRY: dict[str, Task] = {}


def register(task: Task) -> Task:
    if task.name in _REGISTRY:
        raise ValueError(f"task {task.name!r} is already registered")
    kind = task.section.model_fields.get("kind")
    if kind is None or kind.default != task.name:
        raise ValueError(f"task {task.name!r}: its section needs a field kind defaulting to {task.name!r}")
    _REGISTRY[task.name] = task
    return task


def get(name: str) -> Task:
    """The registered task; ValueError naming the known ones otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; choose from {list(_REGISTRY)}") from None


def names() -> tuple[str, ...]:
    """Registered tasks in registration order."""
    return tuple(_REGISTRY)


def sections() -> tuple[type[BaseModel], ...]:
    """The scenario sections of the registered tasks (the schema's union of ``task`` mappings)."""
    return tuple(task.section for task in _REGISTRY.values())


def default_section(name: str = "rendezvous") -> Any:
    """The section of ``name`` with every default (what a scenario without ``task`` runs)."""
    return get(name).section()


def parse_section(section: Mapping[str, Any] | None) -> Any:
    """The typed section of a scenario's ``task`` mapping (a plain mapping, as an agent's configuration
    carries it; None: the default, rendezvous); ValueError when it does not validate."""
    from pydantic import ValidationError

    data = dict(section or {"kind": "rendezvous"})
    task = get(str(data.get("kind", "rendezvous")))
    try:
        return task.section.model_validate(data)
    except ValidationError as error:
        raise ValueError(f"task section of the config: {error}") from None


def settle_time(times_s: np.ndarray, ok: np.ndarray, hold_s: float) -> float | None:
    """First time from which ``ok`` holds to the end, if it held at least ``hold_s``; else None."""
    times_s = np.asarray(times_s, dtype=np.float64)
    ok = np.asarray(ok, dtype=bool)
    if not ok[-1]:
        return None
    failed = np.flatnonzero(~ok)
    start = int(failed[-1]) + 1 if len(failed) else 0
    time_s = float(times_s[start])
    return time_s if float(times_s[-1]) - time_s >= hold_s - 1e-9 else None
