"""The sweep and evaluate figures (``swarm.scenarios.plots``), rendered for real and read back.

The oracle is what a reader needs, not the plotting code: a saved PNG no wider than a screen and
not a strip; a tick labelled with the plain number at every N of the data and none elsewhere; one
colour and one marker per controller, different between controllers; a linear axis for data within
a decade; every tick label inside the saved image.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from swarm.scenarios import plots

SIZES = [6, 12, 24, 50, 100]
CONTROLLERS = ["local_consensus", "centralized", "gnn", "mec_flood", "mec_flood_forward", "centralized_mec"]
TOPOLOGIES = ["complete", "cycle", "line", "star", "random", "disk"]


def fake_rows() -> list[dict]:
    """Rows as ``swarm sweep`` writes them: times within a decade except local consensus on cycle and
    line, which grows like N^2."""
    rows = []
    for topology in TOPOLOGIES:
        for index, controller in enumerate(CONTROLLERS):
            for n in SIZES:
                slow = controller == "local_consensus" and topology in ("cycle", "line")
                time_s = 0.1 * n**2 if slow else 4.0 + 0.2 * n + 0.05 * index
                lambda2 = 4 * np.pi**2 / n**2 if topology in ("cycle", "line") else 1.0
                rows.append(
                    {
                        "topology": topology,
                        "controller": controller,
                        "robots": n,
                        "median_time_s": time_s,
                        "median_lambda2": lambda2,
                    }
                )
    return rows


def fake_cells() -> list[dict]:
    rng = np.random.default_rng(0)
    cells = []
    for controller in CONTROLLERS:
        for topology in TOPOLOGIES:
            for n in SIZES:
                lower = rng.uniform(2.0, 4.0, 50)
                cells.append(
                    {
                        "controller": controller,
                        "topology": topology,
                        "robots": n,
                        "lower_bound_s": lower,
                        "times_s": lower * rng.uniform(1.01, 1.2, 50),
                    }
                )
    return cells


def saved(fig, tmp_path, name: str):
    """Draw and save ``fig``; its renderer-space bounding box and the PNG's size in pixels."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    texts = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        for axis, labels in ((ax.xaxis, ax.get_xticklabels()), (ax.yaxis, ax.get_yticklabels())):
            low, high = sorted(axis.get_view_interval())
            texts += [label for label in labels if low <= label.get_position()[axis is ax.yaxis] <= high]
        texts += [ax.xaxis.label, ax.yaxis.label, ax.title]
    texts = [text.get_window_extent(renderer) for text in texts if text.get_text()]
    width_px, height_px = fig.canvas.get_width_height()
    path = plots.save(fig, tmp_path / f"{name}.png")
    with Image.open(path) as image:
        size = image.size
    return size, texts, (width_px, height_px)


def check_readable(size, texts, canvas):
    width, height = size
    assert width <= 2200 and height <= 1600, size
    assert width / height <= 2.6, f"a strip of panels: {size}"
    for box in texts:  # every label inside the image: none cut
        assert box.x0 >= -1 and box.y0 >= -1 and box.x1 <= canvas[0] + 1 and box.y1 <= canvas[1] + 1, box


def test_time_figure_is_a_grid_with_ticks_at_every_n_and_a_style_per_controller(tmp_path):
    fig = plots.sweep_time_figure(fake_rows())
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == len(TOPOLOGIES) + 1  # one per topology and the 1/lambda2 panel
    for ax in panels[: len(TOPOLOGIES)]:
        assert [label.get_text() for label in ax.get_xticklabels()] == [str(n) for n in SIZES]
        assert list(ax.get_xticks()) == SIZES
        styles = {(line.get_color(), line.get_marker()) for line in ax.get_lines()}
        colours = {line.get_color() for line in ax.get_lines()}
        markers = {line.get_marker() for line in ax.get_lines()}
        assert len(styles) == len(colours) == len(markers) == len(CONTROLLERS)
    by_title = {ax.get_title(): ax for ax in panels}
    assert by_title["complete"].get_yscale() == "linear"  # 5-25 s: within a decade
    assert by_title["cycle"].get_yscale() == "log"  # 3.6-1000 s
    low, high = by_title["complete"].get_ylim()
    values = [r["median_time_s"] for r in fake_rows() if r["topology"] == "complete"]
    assert low <= min(values) and high >= max(values) and (high - low) < 1.5 * (max(values) - min(values))
    labels = [text.get_text() for text in panels[0].get_legend().get_texts()]
    assert labels == [plots.controller_label(c) for c in CONTROLLERS]
    check_readable(*saved(fig, tmp_path, "time"))


@pytest.mark.parametrize("controllers", [CONTROLLERS, CONTROLLERS[:2]])
def test_ratio_figure_labels_are_whole_and_fit(tmp_path, controllers):
    fig = plots.sweep_ratio_figure([cell for cell in fake_cells() if cell["controller"] in controllers])
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == len(controllers)
    labels = [label.get_text() for label in panels[0].get_xticklabels()]
    assert "cycle 6" in labels and "random 100" in labels  # whole names, not "cycl6"
    assert panels[0].get_yscale() == "linear"  # ratios 1.0-1.2
    assert panels[0].get_ylim()[0] <= 1.0 <= panels[0].get_ylim()[1]  # the lower bound in view
    check_readable(*saved(fig, tmp_path, "ratio"))


@pytest.mark.parametrize("topologies", [TOPOLOGIES, TOPOLOGIES[:2]])
def test_curves_figure_is_a_grid(tmp_path, topologies):
    times = np.arange(200) * 0.05
    curves = {
        topology: {
            controller: (
                times,
                1e-9 + 3 * np.exp(-times / (1 + i)),
                0.2 + 4 * np.exp(-times / (1 + i)),
                0.3 + 5 * np.exp(-times / (1 + i)),
            )
            for i, controller in enumerate(CONTROLLERS)
        }
        for topology in topologies
    }
    fig = plots.curves_figure(curves, 24, 0.2, "model: median and 10-90 % over 100 starts")
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == len(topologies)
    lines = [
        line for line in panels[0].get_lines() if line.get_label() in map(plots.controller_label, CONTROLLERS)
    ]
    assert len({(line.get_color(), line.get_marker()) for line in lines}) == len(CONTROLLERS)
    assert len({line.get_marker() for line in lines}) == len(CONTROLLERS)
    low, high = panels[0].get_ylim()
    assert low >= 0.2 / 10 / 1.5 and high <= 5.3 * 1.5, (low, high)  # no decades below the threshold
    size, texts, canvas = saved(fig, tmp_path, "curves")
    check_readable(size, texts, canvas)
    assert size[0] <= 1600  # at most three panels a row
