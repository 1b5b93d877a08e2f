"""Contacts and clearance of a run's bodies (``metrics.json``), from the trajectory, and the safety
filter's counts.

In the kinematic engine bodies are discs of radius ``r`` at the axle centres with nothing to stop
them overlapping; a contact is an overlap: robots i and j at a tick with ``|c_i - c_j| < 2 r``, or a
robot within ``r`` of an obstacle's surface. ``contacts`` counts (pair, tick) contacts of each kind and
the ticks with any; ``min_clearance_m`` is the smallest gap met, ``|c_i - c_j| - 2 r`` or the distance
to an obstacle's surface minus ``r`` (negative: overlap).
"""

from __future__ import annotations

import numpy as np

from swarm.core.obstacles import Capsules


def _gaps(poses: np.ndarray, body_radius_m: float, obstacles: Capsules):
    """Chunks of ticks of ``poses (T, N, 3)`` (bounded memory on long runs of many robots): per chunk,
    the bumper gaps of every robot pair ``(C, N (N - 1) / 2)`` and of every robot to every obstacle
    ``(C, N K)``, negative for an overlap."""
    centres = poses[..., :2]
    upper = np.triu_indices(centres.shape[1], k=1)
    for start in range(0, len(centres), 256):
        chunk = centres[start : start + 256]
        gaps = np.linalg.norm(chunk[:, :, None] - chunk[:, None], axis=-1)[:, upper[0], upper[1]]
        walls = obstacles.surface_distance(chunk).reshape(len(chunk), -1) - body_radius_m
        yield gaps - 2.0 * body_radius_m, walls


def contact_results(poses: np.ndarray, body_radius_m: float, obstacles: Capsules) -> dict:
    """``{"contacts": {...}, "min_clearance_m": ...}`` of a trajectory ``poses (T, N, 3)``."""
    robot_robot = robot_obstacle = ticks = 0
    clearance = np.inf
    for gaps, walls in _gaps(poses, body_radius_m, obstacles):
        robot_robot += int(np.count_nonzero(gaps < 0))
        robot_obstacle += int(np.count_nonzero(walls < 0))
        ticks += int(np.count_nonzero(np.any(gaps < 0, axis=1) | np.any(walls < 0, axis=1)))
        clearance = min(clearance, gaps.min(initial=np.inf), walls.min(initial=np.inf))
    return {
        "contacts": {"robot_robot": robot_robot, "robot_obstacle": robot_obstacle, "ticks": ticks},
        "min_clearance_m": None if clearance == np.inf else float(clearance),
    }


def clearance_series(
    poses: np.ndarray, body_radius_m: float, obstacles: Capsules
) -> tuple[np.ndarray, np.ndarray | None]:
    """Per tick of ``poses (T, N, 3)``: the smallest bumper gap between two robots ``(T,)`` (inf for
    one robot) and the smallest gap to an obstacle ``(T,)`` (None without obstacles); as
    :func:`contact_results` measures them."""
    robots, walls = [], []
    for gaps, wall_gaps in _gaps(poses, body_radius_m, obstacles):
        robots.append(gaps.min(axis=1, initial=np.inf))
        walls.append(wall_gaps.min(axis=1, initial=np.inf))
    return np.concatenate(robots), np.concatenate(walls) if len(obstacles) else None


def clearance_plot(
    path, times_s: np.ndarray, poses: np.ndarray, body_radius_m: float, obstacles: Capsules
) -> None:
    """``clearance.png`` (+ ``.json``, ``swarm.scenarios.report.plot_data``): the smallest gap between
    two bodies, and between a body and an obstacle, over time, with the contact line at 0."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from swarm.scenarios.report import plot_data

    robots, walls = clearance_series(poses, body_radius_m, obstacles)
    fig, ax = plt.subplots(figsize=(7.5, 3.5), dpi=110)
    if np.all(np.isfinite(robots)):
        (line,) = ax.plot(times_s, robots, color="black", lw=1.6, label="robot-robot")
        line.set_gid("robot_robot")
    if walls is not None:
        (line,) = ax.plot(times_s, walls, color="tab:brown", lw=1.6, label="robot-obstacle")
        line.set_gid("robot_obstacle")
    (zero,) = ax.plot([times_s[0], times_s[-1]], [0.0, 0.0], color="red", lw=1, ls="--", label="contact")
    zero.set_gid("contact")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("smallest gap (m)")
    ax.set_title("Clearance between bodies")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    path.with_suffix(".json").write_text(json.dumps(plot_data(ax)))
    plt.close(fig)


def add_safety_results(
    outcome: dict, poses: np.ndarray, body_radius_m: float, obstacles: Capsules, filter_counts: dict | None
) -> dict:
    """``outcome`` with ``contacts``, ``min_clearance_m`` and ``safety_filter`` (None without a filter:
    ``{"interventions", "infeasible"}`` robot-ticks otherwise)."""
    outcome.update(contact_results(poses, body_radius_m, obstacles))
    outcome["safety_filter"] = dict(filter_counts) if filter_counts is not None else None
    return outcome


def safety_summary_line(outcome: dict) -> str | None:
    """The summary's line on bodies, or None for an outcome without them."""
    if "contacts" not in outcome:
        return None
    contacts, clearance = outcome["contacts"], outcome["min_clearance_m"]
    line = (
        f"  bodies: {contacts['ticks']} contact ticks ({contacts['robot_robot']} robot-robot,"
        f" {contacts['robot_obstacle']} robot-obstacle)"
    )
    if clearance is not None:
        line += f", min clearance {clearance:.3f} m"
    counts = outcome.get("safety_filter")
    if counts is not None:
        line += f"; filter changed {counts['interventions']} commands, {counts['infeasible']} infeasible"
        if counts.get("missing"):
            line += f", {counts['missing']} ticks braked without a sensor reading"
    return line
