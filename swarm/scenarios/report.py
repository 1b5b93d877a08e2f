"""Pictures of a run: the convergence plot (PNG, with its data in a JSON sidecar) and a top-down
animation (GIF).

Poses are logged during the run and drawn afterwards; frames are drawn with PIL (well under a
millisecond each), the plot with matplotlib. Both show what happened to the run: the faults on
the time axis, dead and hung robots greyed, dropped links dashed, and a partial run (interrupted,
cut short, a server started by hand that ended early) marked as partial.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.core import graphs, metrics

if TYPE_CHECKING:
    from swarm.scenarios.scenario import Scenario

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
WHITE, BLACK, EDGE, DEAD, DOWN, ALERT = (
    (255, 255, 255),
    (0, 0, 0),
    (190, 190, 190),
    (160, 170, 190),  # blue-grey: no shade of antialiased text is quantized to it
    (225, 90, 90),
    (200, 0, 0),
)
ALIVE, KILLED, HUNG = 0, 1, 2
"""Agent states of :func:`robot_states`."""

FAULT_STYLE = {  # kind -> (colour, line style) of its mark on the time axis
    "kill_agent": ("tab:red", "-"),
    "restart_agent": ("tab:orange", "-"),
    "hang_agent": ("tab:purple", "-"),
    "resume_agent": ("tab:purple", ":"),
    "kill_server": ("darkred", "-"),
    "drop_link": ("tab:brown", "--"),
    "restore_link": ("tab:olive", "--"),
    "packet_loss": ("tab:gray", "--"),
    "delay": ("tab:cyan", "--"),
}


def partial_reason(outcome: dict) -> str | None:
    """Why a run's results are partial (``metrics.json`` key ``incomplete``), None when complete."""
    return outcome.get("incomplete") or None


def fault_marks(outcome: dict, times_s: np.ndarray) -> list[dict]:
    """The faults of a run on its time axis: ``{"time_s", "kind", "label"}`` per process fault done
    (at the tick the runner did it, ``events.jsonl``) and per scheduled link fault (at its ``at``)."""
    faults = outcome.get("faults") or {}
    dt = float(times_s[1] - times_s[0]) if len(times_s) > 1 else 0.0
    marks = []
    for event in faults.get("events", []):
        tick = event.get("tick")
        time_s = tick * dt if isinstance(tick, int) and dt else float(event.get("at_s") or 0.0)
        who = "" if event.get("robot") is None else f" robot {event['robot']}"
        marks.append({"time_s": time_s, "kind": event["kind"], "label": f"{event['kind']}{who}"})
    for fault in faults.get("scheduled", []):
        kind = fault.get("kind")
        if kind not in ("drop_link", "restore_link", "packet_loss", "delay"):
            continue
        what = f" {fault['link']}" if fault.get("link") else ""
        if kind == "packet_loss":
            what += f" p={fault['p']:g}"
        if kind == "delay":
            what += f" {fault['ticks']} ticks"
        marks.append({"time_s": float(fault.get("at_s") or 0.0), "kind": kind, "label": f"{kind}{what}"})
    return sorted(marks, key=lambda mark: mark["time_s"])


def robot_states(outcome: dict, count: int, ticks: int) -> np.ndarray:
    """``(ticks, count)`` agent state per tick (``ALIVE``, ``KILLED``, ``HUNG``) from the runner's events:
    killed from a ``kill_agent`` (or the kill of a ``restart_agent``) until a restart, hung from a
    ``hang_agent`` until its ``resume_agent``."""
    states = np.full((ticks, count), ALIVE, dtype=np.int8)
    for event in (outcome.get("faults") or {}).get("events", []):
        robot, tick = event.get("robot"), event.get("tick")
        if not isinstance(robot, int) or not isinstance(tick, int) or not 0 <= robot < count:
            continue
        tick = min(max(tick, 0), ticks)
        if event["kind"] == "kill_agent":
            states[tick:, robot] = KILLED
        elif event["kind"] == "hang_agent":
            states[tick:, robot] = HUNG
        elif event["kind"] in ("resume_agent", "restart_agent"):
            states[tick:, robot] = ALIVE
    return states


def live_robots(outcome: dict, count: int) -> list[int]:
    """The robots the run is judged on: those alive at the end (``faults.live_robots``), else all."""
    live = (outcome.get("faults") or {}).get("live_robots")
    return list(range(count)) if live is None else list(live)


def run_title(scenario: Scenario) -> str:
    robots = "1 robot" if scenario.robots.count == 1 else f"{scenario.robots.count} robots"
    controller, engine = scenario.controller.kind, scenario.sim.engine
    return f"{scenario.name}: {controller} on {engine}, {robots}, {scenario.topology.kind}"


def write_pictures(
    out_dir: Path, scenario: Scenario, times: np.ndarray, poses: np.ndarray, outcome: dict
) -> None:
    """``convergence.png`` (+ ``convergence.json``) and ``animation.gif`` of a run."""
    from swarm.core.faults import LinkFaults

    title = run_title(scenario)
    convergence_plot(out_dir / "convergence.png", times, poses[..., :2], outcome, title)
    schedule = LinkFaults.from_scenario(scenario) if scenario.faults else None
    animation_gif(
        out_dir / "animation.gif",
        times,
        poses,
        scenario.adjacency(),
        scenario.topology.radius_m,
        scenario.robot.body_radius_m,
        title=title,
        states=robot_states(outcome, poses.shape[1], len(times)),
        links_down=None if schedule is None or schedule.empty else schedule.down_matrix,
        partial=partial_reason(outcome),
        obstacles=_capsules(scenario),
    )


def _capsules(scenario: Scenario):
    """The scenario's obstacles as ``swarm.core.obstacles.Capsules``, or None without any."""
    from swarm.core.obstacles import Capsules

    return Capsules(scenario.obstacles) if scenario.obstacles else None


def _draw_obstacles(draw, obstacles, to_px, scale: float) -> None:
    """Every obstacle filled grey: a capsule is a thick segment with a disc at each end."""
    for start, end, radius in zip(obstacles.start, obstacles.end, obstacles.radius, strict=True):
        radius_px = max(1.0, radius * scale)
        for centre in (start, end):
            x, y = to_px(centre)
            draw.ellipse([x - radius_px, y - radius_px, x + radius_px, y + radius_px], fill=DEAD)
        if np.any(start != end):
            draw.line([to_px(start), to_px(end)], fill=DEAD, width=max(1, round(2 * radius_px)))


def convergence_plot(
    path: Path,
    times_s: np.ndarray,
    positions: np.ndarray,
    outcome: dict,
    title: str,
) -> None:
    """The success metric over time for the robots the run is judged on (the live ones; the all-robot
    curve faded behind it when they differ), per component when the graph is disconnected, with the
    threshold, the convergence time, the lower bound and every fault marked; a partial run says so in
    the title and on the axes. The plotted data go to ``<path>.json`` (``plot_data``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metric, threshold = outcome["metric"], outcome["threshold"]
    metric_fn = metrics.METRICS[metric]
    count = positions.shape[1]
    live = live_robots(outcome, count)
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=110)
    if len(live) == count:
        (line,) = ax.plot(times_s, metric_fn(positions), color="black", lw=2, label=f"{metric}, all robots")
        line.set_gid("judged")
    else:
        (faded,) = ax.plot(
            times_s, metric_fn(positions), color="gray", lw=1.2, alpha=0.35, label=f"{metric}, all robots"
        )
        faded.set_gid("all_robots")
        if len(live) > 1:
            (line,) = ax.plot(
                times_s,
                metric_fn(positions[:, live]),
                color="black",
                lw=2,
                label=f"{metric}, live robots {live}",
            )
            line.set_gid("judged")
    if len(outcome["components"]) > 1:
        for component in outcome["components"]:
            if len(component["robots"]) > 1:
                values = metric_fn(positions[:, component["robots"]])
                (line,) = ax.plot(times_s, values, lw=1.3, ls="--", label=f"component {component['robots']}")
                line.set_gid(f"component:{component['robots']}")
    ax.axhline(threshold, color="tab:green", lw=1, ls=":", label=f"threshold {threshold:g} m").set_gid(
        "threshold"
    )
    if outcome["convergence_time_s"] is not None:
        ax.axvline(
            outcome["convergence_time_s"],
            color="tab:green",
            lw=1,
            label=f"converged at {outcome['convergence_time_s']:.2f} s",
        ).set_gid("converged")
    if outcome.get("lower_bound_s"):
        ax.axvline(
            outcome["lower_bound_s"],
            color="tab:red",
            lw=1,
            ls="-.",
            label=f"lower bound {outcome['lower_bound_s']:.2f} s",
        ).set_gid("lower_bound")
    for mark in fault_marks(outcome, times_s):
        colour, style = FAULT_STYLE.get(mark["kind"], ("tab:gray", "--"))
        line = ax.axvline(
            mark["time_s"], color=colour, ls=style, lw=1.4, label=f"{mark['label']} at {mark['time_s']:.2f} s"
        )
        line.set_gid(f"fault:{mark['label']}")
    partial = partial_reason(outcome)
    if partial:
        title = f"PARTIAL: {title}"
        ax.text(
            0.01,
            0.02,
            f"partial run: {partial}",
            transform=ax.transAxes,
            fontsize=7,
            color="darkred",
            wrap=True,
        ).set_gid("partial")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel(f"{metric} (m)")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=10, color="darkred" if partial else "black")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    Path(f"{path}.json").write_text(json.dumps(plot_data(ax), separators=(",", ":")) + "\n")
    plt.close(fig)


def plot_data(ax: Any) -> dict:
    """What an axes shows, read back from its artists: every line (``gid``, label, style, data) and
    text, and the title; so a plot's content can be checked without looking at its pixels."""
    lines = []
    for line in ax.get_lines():
        x, y = (np.asarray(data, dtype=float) for data in line.get_data())
        lines.append(
            {
                "gid": line.get_gid(),
                "label": line.get_label(),
                "alpha": line.get_alpha(),
                "linestyle": line.get_linestyle(),
                "x": np.round(x, 6).tolist(),
                "y": np.round(y, 6).tolist(),
            }
        )
    texts = [{"gid": text.get_gid(), "text": text.get_text()} for text in ax.texts]
    return {"title": ax.get_title(), "lines": lines, "texts": texts}


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: one bitmap size
        return ImageFont.load_default()


def _dashed(draw, start: tuple[float, float], end: tuple[float, float], fill, dash_px: float = 5.0) -> None:
    length = float(np.hypot(end[0] - start[0], end[1] - start[1]))
    pieces = max(1, int(length // dash_px))
    for piece in range(0, pieces, 2):
        a, b = piece / pieces, min(1.0, (piece + 1) / pieces)
        draw.line(
            [
                (start[0] + a * (end[0] - start[0]), start[1] + a * (end[1] - start[1])),
                (start[0] + b * (end[0] - start[0]), start[1] + b * (end[1] - start[1])),
            ],
            fill=fill,
            width=1,
        )


def _scale_bar_m(span_m: float) -> float:
    """A round length (1, 2 or 5 x 10^k m) near a fifth of the view."""
    target = span_m / 5
    exponent = np.floor(np.log10(target))
    for step in (5.0, 2.0, 1.0):
        if step * 10**exponent <= target:
            return float(step * 10**exponent)
    return float(10**exponent)


def view_spans(xy: np.ndarray, frame_indices: list[int], body_radius_m: float) -> np.ndarray:
    """Side of the square view of each frame, in metres: the robots' extent from that frame on (with a
    margin of three body radii, at least ten body radii), so the view zooms in as the swarm gathers."""
    extent = np.array([float(np.max(np.ptp(xy[index], axis=0))) for index in frame_indices])
    ahead = np.maximum.accumulate(extent[::-1])[::-1]  # never zoom out: the largest extent still to come
    return np.maximum(ahead + 6 * body_radius_m, 10 * body_radius_m)


def animation_gif(
    path: Path,
    times_s: np.ndarray,
    poses: np.ndarray,
    adjacency: np.ndarray | None,
    disk_radius_m: float | None,
    body_radius_m: float,
    size_px: int = 480,
    max_frames: int = 150,
    frame_ms: int = 80,
    title: str = "",
    states: np.ndarray | None = None,
    links_down=None,
    partial: str | None = None,
    obstacles=None,
) -> None:
    """Top-down frames: robots as discs with a heading tick and their id, their paths so far, graph
    edges in grey (dashed red while the link carries nothing, or a robot at either end is dead), dead
    and hung robots grey; the title, the time, the metric and a scale bar. The view follows the swarm
    and zooms in as it gathers (:func:`view_spans`).

    ``states``: ``(T, N)`` agent states (:func:`robot_states`); ``links_down(count, tick)``: ``(N, N)``
    bool, links that carry nothing at that tick (``swarm.core.faults.LinkFaults.down_matrix``);
    ``obstacles``: ``swarm.core.obstacles.Capsules``, drawn grey under everything else."""
    from PIL import Image, ImageDraw

    stride = max(1, int(np.ceil(len(times_s) / max_frames)))
    frame_indices = list(range(0, len(times_s), stride))
    if frame_indices[-1] != len(times_s) - 1:
        frame_indices.append(len(times_s) - 1)
    count = poses.shape[1]
    xy = poses[..., :2]
    spans = view_spans(xy, frame_indices, body_radius_m)
    header_px, footer_px = 22, 20
    title_font, small_font = _font(13), _font(11)
    frames = []
    for frame, index in enumerate(frame_indices):
        span_m = float(spans[frame])
        centre = 0.5 * (xy[index].min(axis=0) + xy[index].max(axis=0))
        scale = (size_px - 20) / span_m

        def to_px(point, centre=centre, scale=scale) -> tuple[float, float]:
            return (
                size_px / 2 + (point[0] - centre[0]) * scale,
                header_px + size_px / 2 - (point[1] - centre[1]) * scale,
            )

        image = Image.new("RGB", (size_px, size_px + header_px + footer_px), WHITE)
        draw = ImageDraw.Draw(image)
        state = states[index] if states is not None else np.zeros(count, dtype=np.int8)
        edges = adjacency if adjacency is not None else graphs.disk(xy[index], disk_radius_m or 0.0)
        down = links_down(count, index) if links_down is not None else np.zeros((count, count), dtype=bool)
        if obstacles is not None:
            _draw_obstacles(draw, obstacles, to_px, scale)
        for robot in range(count):
            trail = [to_px(xy[past, robot]) for past in frame_indices if past <= index]
            if len(trail) > 1:
                draw.line(trail, fill=FADED_COLOURS[robot % len(FADED_COLOURS)], width=1)
        rows, cols = np.nonzero(np.triu(edges))
        for i, j in zip(rows, cols, strict=True):
            a, b = to_px(xy[index, i]), to_px(xy[index, j])
            if down[i, j] or down[j, i] or state[i] == KILLED or state[j] == KILLED:
                _dashed(draw, a, b, DOWN)
            else:
                draw.line([a, b], fill=EDGE, width=1)
        radius_px = max(3.0, body_radius_m * scale)
        for robot, (x, y, theta) in enumerate(poses[index]):
            cx, cy = to_px(np.array((x, y)))
            colour = ROBOT_COLOURS[robot % len(ROBOT_COLOURS)] if state[robot] == ALIVE else DEAD
            box = [cx - radius_px, cy - radius_px, cx + radius_px, cy + radius_px]
            if state[robot] == KILLED:
                draw.ellipse(box, outline=DEAD, fill=(235, 235, 235), width=2)
                draw.line([box[0], box[1], box[2], box[3]], fill=DEAD, width=1)
                draw.line([box[0], box[3], box[2], box[1]], fill=DEAD, width=1)
            else:
                draw.ellipse(box, outline=colour, width=2)
            draw.line(
                [(cx, cy), (cx + radius_px * np.cos(theta), cy - radius_px * np.sin(theta))],
                fill=colour,
                width=2,
            )
            label = str(robot) + {ALIVE: "", KILLED: " dead", HUNG: " hung"}[int(state[robot])]
            draw.text((cx + radius_px + 2, cy - radius_px - 2), label, fill=BLACK, font=small_font)
        # header: the title (and PARTIAL); footer: time, metric, scale bar
        heading = f"PARTIAL  {title}" if partial else title
        draw.rectangle([0, 0, size_px, header_px - 1], fill=WHITE)
        draw.text((4, 3), heading, fill=ALERT if partial else BLACK, font=title_font)
        top = header_px + size_px
        draw.rectangle([0, top, size_px, top + footer_px], fill=WHITE)
        spread_m = float(metrics.max_pairwise(xy[index]))
        caption = f"t = {times_s[index]:6.2f} s   max_pairwise = {spread_m:.2f} m"
        draw.text((4, top + 3), caption, fill=BLACK, font=small_font)
        bar_m = _scale_bar_m(span_m)
        bar_px = bar_m * scale
        right = size_px - 8
        draw.line([(right - bar_px, top + 12), (right, top + 12)], fill=BLACK, width=2)
        for end in (right - bar_px, right):
            draw.line([(end, top + 8), (end, top + 16)], fill=BLACK, width=1)
        label = f"{bar_m:g} m"
        width_px = draw.textlength(label, font=small_font)
        draw.text((right - bar_px - width_px - 6, top + 3), label, fill=BLACK, font=small_font)
        frames.append(image)
    # Every colour drawn is known (text is antialiased: grey shades too): one palette for all frames.
    colours: list[tuple[int, ...]] = [WHITE, BLACK, EDGE, DEAD, DOWN, ALERT, (235, 235, 235)]
    colours += ROBOT_COLOURS + FADED_COLOURS
    colours += [(level, level, level) for level in range(32, 240, 16)]
    colours += [(255, level, level) for level in range(64, 240, 32)]
    palette = Image.new("P", (1, 1))
    palette.putpalette([channel for colour in colours for channel in colour] + [0] * 3 * (256 - len(colours)))
    frames = [frame.quantize(palette=palette, dither=Image.Dither.NONE) for frame in frames]
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=frame_ms, loop=0, optimize=False)
