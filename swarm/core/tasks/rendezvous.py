"""Rendezvous (the thesis's task): every robot gathers with the others, anywhere.

Metric and success: the scenario's ``success`` section (``swarm.core.metrics.METRICS``, default
``max_pairwise`` at or under ``success.threshold``, from some time on). Lower bound:
``swarm.core.metrics.lower_bound_s``, ``max(0, R_mec - threshold / sqrt(3)) / v_max``, proved in its
docstring (Jung's theorem and the axle speed limit). This entry only names what existed before the
registry; every result of the task is what it was (docs/tasks.md).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict

from swarm.core import metrics
from swarm.core.tasks.registry import Task, register


class RendezvousSection(BaseModel):
    """``task: rendezvous`` (the default): no parameters of its own."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["rendezvous"] = "rendezvous"


def bound_s(initial_positions, section: RendezvousSection, v_max_mps: float, threshold_m: float) -> float:
    """``swarm.core.metrics.lower_bound_s`` (a lower bound; the proof is there)."""
    return metrics.lower_bound_s(initial_positions, threshold_m, v_max_mps)


RENDEZVOUS = register(
    Task(
        name="rendezvous",
        summary="gather: every pairwise distance at or under the threshold",
        section=RendezvousSection,
        knows="its own pose and what its heard neighbours sent last tick",
        experts=("centralized", "centralized_mec"),
        baselines=("local_consensus", "mec_flood", "pack_flood"),
        learned=("gnn",),
        metric="success.metric of the scenario (max_pairwise, spread, thesis_disk)",
        success="the metric at or under success.threshold from some time to the end",
        bound="lower_bound",
        bound_s=bound_s,  # the signature of registry.Task.bound_s
        reward="swarm.rl.vector_env:ConsensusVectorEnv.step",
        plot="swarm.scenarios.report:write_pictures",
    )
)
