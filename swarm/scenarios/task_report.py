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


def _save_convergence(fig, ax, out_dir: Path, title: str, ylabel: str) -> None:
    """A task's ``convergence.png`` (its metric over time, log scale) and its data ``<png>.json``."""
    import matplotlib.pyplot as plt

    from swarm.scenarios.report import plot_data

    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel(ylabel)
    ax.set_yscale("log")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out_dir / "convergence.png")
    (out_dir / "convergence.png.json").write_text(json.dumps(plot_data(ax), separators=(",", ":")) + "\n")
    plt.close(fig)


def formation_pictures(
    out_dir: Path, scenario: Scenario, times_s: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """``convergence.png``: the bottleneck distance over time with the tolerance, the success time and
    the bound; ``formation.png``: the axle paths, the slots and a line from each robot's start to its
    slot in the expert's assignment. The plotted data go to ``<png>.json`` (``report.plot_data``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from swarm.core.tasks.formation import bottleneck_series
    from swarm.scenarios.report import plot_data, run_title

    slots = np.asarray(outcome["slots"])
    positions = poses[..., :2]
    title = run_title(scenario)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    values = bottleneck_series(positions, scenario.task)
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
    _save_convergence(fig, ax, out_dir, title, "bottleneck distance (m)")

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


def coverage_pictures(
    out_dir: Path, scenario: Scenario, times_s: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """``convergence.png``: ``H / H_ref`` over time with the success line ``1 + tolerance`` and the
    success time; ``coverage.png``: the density on the region (shaded quadrature cells), the final
    Voronoi cells (each quadrature point coloured by its nearest robot), the axle paths and the final
    axles. The plotted data go to ``<png>.json`` (``report.plot_data``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from swarm.core.tasks.coverage import ratio_series
    from swarm.scenarios.report import plot_data, run_title

    section = scenario.task
    points, weights = section.quadrature()
    positions = poses[..., :2]
    title = run_title(scenario)
    ratio = ratio_series(positions, section)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    ax.plot(times_s, ratio, color="black", lw=2, label="H / H_ref")[0].set_gid("judged")
    threshold = outcome["threshold"]
    ax.axhline(threshold, color="tab:green", ls=":", label=f"{threshold:g} H_ref").set_gid("threshold")
    ax.axhline(1.0, color="tab:red", ls="-.", lw=0.8, label="H_ref (best Lloyd: a reference)").set_gid(
        "reference"
    )
    if (held_s := outcome["convergence_time_s"]) is not None:
        ax.axvline(held_s, color="tab:green", label=f"held from {held_s:.2f} s").set_gid("converged")
    _save_convergence(fig, ax, out_dir, title, "locational cost / reference")

    final = positions[-1]
    fig, ax = plt.subplots(figsize=(6, 6), dpi=110)
    if np.ptp(weights) > 0:  # a uniform density has nothing to shade
        ax.tricontourf(points[:, 0], points[:, 1], weights, levels=12, cmap="Blues", alpha=0.6).set_gid(
            "density"
        )
    if len(final) >= 3 and np.linalg.matrix_rank(final - final.mean(axis=0)) == 2:
        from scipy.spatial import Voronoi, voronoi_plot_2d

        voronoi_plot_2d(
            Voronoi(final), ax, show_points=False, show_vertices=False, line_colors="tab:gray", line_width=0.8
        )
    region = np.asarray([*section.region, section.region[0]])
    ax.plot(region[:, 0], region[:, 1], color="black", lw=1.2)[0].set_gid("region")
    for robot in range(positions.shape[1]):
        ax.plot(positions[:, robot, 0], positions[:, robot, 1], lw=0.8, alpha=0.7)[0].set_gid(f"path:{robot}")
    ax.scatter(final[:, 0], final[:, 1], s=14, color="black", label="final axles", zorder=3).set_gid("final")
    low, high = np.min(region, axis=0), np.max(region, axis=0)
    margin = 0.05 * float(np.max(high - low))
    ax.set_xlim(min(low[0], positions[..., 0].min()) - margin, max(high[0], positions[..., 0].max()) + margin)
    ax.set_ylim(min(low[1], positions[..., 1].min()) - margin, max(high[1], positions[..., 1].max()) + margin)
    ax.set_aspect("equal")
    ax.set_title(f"{title}\nVoronoi cells at the end, H / H_ref = {ratio[-1]:.3f}", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "coverage.png")
    (out_dir / "coverage.png.json").write_text(json.dumps(plot_data(ax), separators=(",", ":")) + "\n")
    plt.close(fig)
