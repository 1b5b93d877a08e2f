"""A run's pictures by its task (``swarm.core.tasks``): the ``plot`` its entry names; rendezvous keeps
``swarm.scenarios.report.write_pictures`` exactly. (Its outcome: ``swarm.scenarios.results.task_outcome``.)
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np

from swarm.core import tasks
from swarm.scenarios.scenario import Scenario


def task_pictures(
    out_dir: Path, scenario: Scenario, times_s: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """The pictures the task's entry names (``module:function``), and ``clearance.png`` for a scenario
    with a safety filter or obstacles."""
    module, _, function = tasks.get(scenario.task.kind).plot.partition(":")
    getattr(importlib.import_module(module), function)(out_dir, scenario, times_s, poses, outcome)
    if scenario.safety is not None or scenario.obstacles:  # bodies that must keep apart: their gaps
        from swarm.core.obstacles import Capsules
        from swarm.scenarios.safety_results import clearance_plot

        clearance_plot(
            out_dir / "clearance.png",
            times_s,
            poses,
            scenario.robot.body_radius_m,
            Capsules(scenario.obstacles),
        )


def formation_pictures(
    out_dir: Path, scenario: Scenario, times_s: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """``convergence.png``: the bottleneck distance over time with the tolerance, the success time and
    the bound; ``formation.png``: the axle paths, the slots and a line from each robot's start to its
    slot in the expert's assignment. The plotted data go to ``<png>.json`` (``report.plot_data``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from swarm.core.tasks.formation import bottleneck_distance
    from swarm.scenarios.report import plot_data, run_title

    slots = np.asarray(outcome["slots"])
    positions = poses[..., :2]
    title = run_title(scenario)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    values = [bottleneck_distance(frame, slots) for frame in positions]
    ax.plot(times_s, values, color="black", lw=2, label="bottleneck distance")[0].set_gid("judged")
    ax.axhline(
        outcome["threshold"], color="tab:green", ls=":", label=f"tolerance {outcome['threshold']:g} m"
    ).set_gid("threshold")
    if outcome["convergence_time_s"] is not None:
        ax.axvline(
            outcome["convergence_time_s"],
            color="tab:green",
            label=f"held from {outcome['convergence_time_s']:.2f} s",
        ).set_gid("converged")
    if outcome["lower_bound_s"]:
        ax.axvline(
            outcome["lower_bound_s"],
            color="tab:red",
            ls="-.",
            label=f"lower bound {outcome['lower_bound_s']:.2f} s",
        ).set_gid("lower_bound")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("bottleneck distance (m)")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out_dir / "convergence.png")
    (out_dir / "convergence.png.json").write_text(json.dumps(plot_data(ax), separators=(",", ":")) + "\n")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 6), dpi=110)
    for robot in range(positions.shape[1]):
        ax.plot(positions[:, robot, 0], positions[:, robot, 1], lw=1, alpha=0.7)[0].set_gid(f"path:{robot}")
        start, slot = positions[0, robot], slots[outcome["assignment"][robot]]
        ax.plot([start[0], slot[0]], [start[1], slot[1]], color="gray", ls=":", lw=0.8)[0].set_gid(
            f"assigned:{robot}"
        )
    ax.scatter(slots[:, 0], slots[:, 1], marker="x", color="tab:red", label="slots", zorder=3)
    ax.scatter(positions[-1, :, 0], positions[-1, :, 1], s=12, color="black", label="final axles", zorder=3)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "formation.png")
    (out_dir / "formation.png.json").write_text(json.dumps(plot_data(ax), separators=(",", ":")) + "\n")
    plt.close(fig)
