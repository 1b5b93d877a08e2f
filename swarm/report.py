"""Pictures of a run: the convergence plot (PNG) and a top-down animation (GIF).

Poses are logged during the run and drawn afterwards; frames are drawn with
PIL (well under a millisecond each), the plot with matplotlib.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from swarm import graphs, metrics

if TYPE_CHECKING:
    from swarm.scenario import Scenario

ROBOT_COLOURS = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
]
FADED_COLOURS = [tuple(255 - (255 - channel) // 3 for channel in colour) for colour in ROBOT_COLOURS]


def convergence_plot(
    path: Path,
    times_s: np.ndarray,
    positions: np.ndarray,
    outcome: dict,
    title: str,
) -> None:
    """The success metric over time, per component when the graph is disconnected, with the
    threshold, the convergence time and the lower bound marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric, threshold = outcome["metric"], outcome["threshold"]
    metric_fn = metrics.METRICS[metric]
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=110)
    ax.plot(times_s, metric_fn(positions), color="black", lw=2, label=f"{metric}, all robots")
    if len(outcome["components"]) > 1:
        for component in outcome["components"]:
            if len(component["robots"]) > 1:
                values = metric_fn(positions[:, component["robots"]])
                ax.plot(times_s, values, lw=1.3, ls="--", label=f"component {component['robots']}")
    ax.axhline(threshold, color="tab:green", lw=1, ls=":", label=f"threshold {threshold:g} m")
    if outcome["convergence_time_s"] is not None:
        ax.axvline(
            outcome["convergence_time_s"],
            color="tab:green",
            lw=1,
            label=f"converged at {outcome['convergence_time_s']:.2f} s",
        )
    if outcome.get("lower_bound_s"):
        ax.axvline(
            outcome["lower_bound_s"],
            color="tab:red",
            lw=1,
            ls="-.",
            label=f"lower bound {outcome['lower_bound_s']:.2f} s",
        )
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel(f"{metric} (m)")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def animation_gif(
    path: Path,
    times_s: np.ndarray,
    poses: np.ndarray,
    adjacency: np.ndarray | None,
    disk_radius_m: float | None,
    body_radius_m: float,
    size_px: int = 360,
    max_frames: int = 150,
    frame_ms: int = 80,
) -> None:
    """Top-down frames: robots as discs with a heading tick, their paths so far, graph edges in grey."""
    from PIL import Image, ImageDraw

    stride = max(1, int(np.ceil(len(times_s) / max_frames)))
    frame_indices = list(range(0, len(times_s), stride))
    if frame_indices[-1] != len(times_s) - 1:
        frame_indices.append(len(times_s) - 1)
    xy = poses[..., :2]
    low = xy.reshape(-1, 2).min(axis=0) - 2 * body_radius_m
    high = xy.reshape(-1, 2).max(axis=0) + 2 * body_radius_m
    span = float(max(high - low))
    centre = 0.5 * (low + high)
    scale = (size_px - 20) / span

    def to_px(point: np.ndarray) -> tuple[float, float]:
        return (
            size_px / 2 + (point[0] - centre[0]) * scale,
            size_px / 2 - (point[1] - centre[1]) * scale,
        )

    frames = []
    radius_px = max(2.0, body_radius_m * scale)
    for index in frame_indices:
        image = Image.new("RGB", (size_px, size_px + 18), "white")
        draw = ImageDraw.Draw(image)
        edges = adjacency if adjacency is not None else graphs.disk(xy[index], disk_radius_m or 0.0)
        for robot in range(poses.shape[1]):
            trail = [to_px(xy[past, robot]) for past in frame_indices if past <= index]
            if len(trail) > 1:
                draw.line(trail, fill=FADED_COLOURS[robot % len(FADED_COLOURS)], width=1)
        rows, cols = np.nonzero(np.triu(edges))
        for i, j in zip(rows, cols, strict=True):
            draw.line([to_px(xy[index, i]), to_px(xy[index, j])], fill=(190, 190, 190), width=1)
        for robot, (x, y, theta) in enumerate(poses[index]):
            cx, cy = to_px(np.array((x, y)))
            colour = ROBOT_COLOURS[robot % len(ROBOT_COLOURS)]
            draw.ellipse(
                [cx - radius_px, cy - radius_px, cx + radius_px, cy + radius_px], outline=colour, width=2
            )
            draw.line(
                [(cx, cy), (cx + radius_px * np.cos(theta), cy - radius_px * np.sin(theta))],
                fill=colour,
                width=2,
            )
        spread_m = float(metrics.max_pairwise(xy[index]))
        caption = f"t = {times_s[index]:6.2f} s   max_pairwise = {spread_m:.2f} m"
        draw.text((4, size_px + 3), caption, fill=(0, 0, 0))
        frames.append(image)
    # Every colour drawn is known: quantize all frames to that one palette (no per-frame palette search).
    colours: list[tuple[int, ...]] = [(255, 255, 255), (0, 0, 0), (190, 190, 190)]
    colours += ROBOT_COLOURS + FADED_COLOURS
    palette = Image.new("P", (1, 1))
    palette.putpalette([channel for colour in colours for channel in colour] + [0] * 3 * (256 - len(colours)))
    frames = [frame.quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=frame_ms, loop=0, optimize=False)


def write_pictures(
    out_dir: Path, scenario: Scenario, times: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """``convergence.png`` and ``animation.gif`` of a run in ``out_dir``."""
    robots, topology = scenario.robots.count, scenario.topology.kind
    title = f"{scenario.name}: {scenario.controller.kind}, {robots} robots, {topology}"
    convergence_plot(out_dir / "convergence.png", times, poses[..., :2], outcome, title)
    animation_gif(
        out_dir / "animation.gif",
        times,
        poses,
        scenario.adjacency(),
        scenario.topology.radius_m,
        scenario.robot.body_radius_m,
    )
