"""The figures of ``swarm sweep`` and ``swarm evaluate``, made to be read at a glance.

Every controller has one colour and one marker in every figure (:data:`CONTROLLER_STYLES`); panels
sit in a grid of at most :data:`MAX_COLUMNS` columns; the N axis has a tick at every N of the data,
labelled with the plain number; an axis is logarithmic only where the data span more than a decade
(:func:`fit_axis`), otherwise linear and fitted to the data. Each function builds a
``matplotlib.figure.Figure`` and saves it; the builders are public so that tests can read the
figures they save.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

CONTROLLER_STYLES: dict[str, tuple[str, str, str]] = {
    "gnn": ("tab:blue", "o", "-"),
    "mec_flood": ("tab:purple", "s", "-"),
    "mec_flood_forward": ("tab:pink", "v", "--"),
    "centralized_mec": ("tab:olive", "D", "-."),
    "centralized": ("tab:green", "^", ":"),
    "local_consensus": ("tab:red", "X", "-"),
}
"""Controller -> (colour, marker, line style), the same in every figure."""
SPARE_STYLES = [
    ("tab:brown", "P", "-"),
    ("tab:cyan", "*", "--"),
    ("tab:gray", "h", ":"),
    ("black", "<", "-."),
]
MAX_COLUMNS = 3
PANEL_SIZE_IN = (4.6, 3.6)
DPI = 110
CURVE_FLOOR_FACTOR = 10.0
"""The metric-over-time panels show down to threshold / this factor."""
LOG_SPAN = 10.0
"""An axis is logarithmic only when its data span more than this factor."""


def controller_style(controller: str, others: Sequence[str] = ()) -> tuple[str, str, str]:
    """(colour, marker, line style) of a controller; one not in :data:`CONTROLLER_STYLES` takes a
    spare style by its place in ``others``."""
    if controller in CONTROLLER_STYLES:
        return CONTROLLER_STYLES[controller]
    unknown = [name for name in others if name not in CONTROLLER_STYLES]
    index = unknown.index(controller) if controller in unknown else 0
    return SPARE_STYLES[index % len(SPARE_STYLES)]


def controller_label(controller: str) -> str:
    return "model (gnn)" if controller == "gnn" else controller.replace("_", " ")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def panel_grid(count: int, panel_width_in: float = PANEL_SIZE_IN[0]):
    """A figure with ``count`` panels in rows of at most :data:`MAX_COLUMNS` (panels wider than 6 in:
    one a row up to two panels, else two a row); unused panels hidden."""
    plt = _pyplot()
    wide_columns = 1 if count <= 2 else 2
    columns = min(MAX_COLUMNS if panel_width_in <= 6 else wide_columns, max(1, count))
    rows = math.ceil(count / columns)
    fig, axes = plt.subplots(
        rows,
        columns,
        figsize=(panel_width_in * columns, PANEL_SIZE_IN[1] * rows + 0.6),
        dpi=DPI,
        squeeze=False,
        layout="constrained",
    )
    flat = list(axes.flat)
    for ax in flat[count:]:
        ax.set_visible(False)
    return fig, flat[:count]


def fit_axis(ax, values: Sequence[float] | np.ndarray, axis: str = "y", floor: float | None = None) -> None:
    """Log scale when the finite positive ``values`` span more than :data:`LOG_SPAN`, else linear;
    limits fitted to the data with a margin (``floor``: a value that must stay in view, e.g. 1.0 for
    a ratio to a lower bound)."""
    data = np.asarray([v for v in np.ravel(values) if v is not None and np.isfinite(v) and v > 0], float)
    if floor is not None:
        data = np.append(data, floor)
    if not len(data):
        return
    low, high = float(data.min()), float(data.max())
    if high / low > LOG_SPAN:
        from matplotlib.ticker import NullFormatter

        getattr(ax, f"set_{axis}scale")("log")
        getattr(ax, f"set_{axis}lim")(low / 1.2, high * 1.2)
        which = ax.yaxis if axis == "y" else ax.xaxis
        which.set_major_formatter(lambda value, _: f"{value:g}")  # 100, not 10^2
        which.set_minor_formatter(NullFormatter())
    else:
        margin = 0.08 * (high - low) or 0.05 * high
        getattr(ax, f"set_{axis}lim")(max(0.0, low - margin) if low >= 0 else low - margin, high + margin)


def ticks_at_sizes(ax, sizes: Sequence[int]) -> None:
    """An N axis: log scale, a tick labelled with the plain number at every N of the data, no others."""
    from matplotlib.ticker import FixedLocator, NullLocator

    sizes = sorted(set(int(n) for n in sizes))
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(FixedLocator(sizes))
    ax.xaxis.set_major_formatter(lambda value, _: f"{value:g}")
    ax.xaxis.set_minor_locator(NullLocator())
    if len(sizes) > 1:
        ax.set_xlim(sizes[0] / 1.15, sizes[-1] * 1.15)


def sweep_time_figure(rows: list[dict]):
    """Median convergence time against N, one panel per topology (one curve per controller), and, when
    local consensus ran on cycles or lines, a panel of its time against 1/lambda2."""
    controllers = list(dict.fromkeys(row["controller"] for row in rows))
    topologies = list(dict.fromkeys(row["topology"] for row in rows))
    lambda_rows = [
        r for r in rows if r["controller"] == "local_consensus" and r["topology"] in ("cycle", "line")
    ]
    fig, axes = panel_grid(len(topologies) + (1 if lambda_rows else 0))
    for ax, topology in zip(axes, topologies, strict=False):
        values = []
        for controller in controllers:
            chosen = sorted(
                (r for r in rows if r["topology"] == topology and r["controller"] == controller),
                key=lambda r: r["robots"],
            )
            sizes = [r["robots"] for r in chosen]
            medians = [np.nan if r["median_time_s"] is None else r["median_time_s"] for r in chosen]
            colour, marker, line = controller_style(controller, controllers)
            ax.plot(sizes, medians, color=colour, marker=marker, ls=line, label=controller_label(controller))
            values += medians
        ticks_at_sizes(ax, [r["robots"] for r in rows if r["topology"] == topology])
        fit_axis(ax, values)
        ax.set(xlabel="robots N", ylabel="median convergence time (s)", title=topology)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    if lambda_rows:
        ax = axes[-1]
        colour, marker, line = controller_style("local_consensus")
        values, inverses = [], []
        for topology, fill in (("cycle", "full"), ("line", "none")):
            chosen = sorted((r for r in lambda_rows if r["topology"] == topology), key=lambda r: r["robots"])
            if not chosen:
                continue
            inverse = [1.0 / r["median_lambda2"] for r in chosen]
            medians = [np.nan if r["median_time_s"] is None else r["median_time_s"] for r in chosen]
            ax.plot(inverse, medians, color=colour, marker=marker, ls=line, fillstyle=fill, label=topology)
            values += medians
            inverses += inverse
        fit_axis(ax, values)
        fit_axis(ax, inverses, axis="x")
        ax.set(xlabel="1 / lambda2", ylabel="median convergence time (s)")
        ax.set_title("local consensus: time against 1/lambda2")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("median convergence time against swarm size")
    return fig


def sweep_ratio_figure(cells: list[dict]):
    """Distribution of convergence time / lower bound per (topology, N), one panel per controller."""
    controllers = list(dict.fromkeys(cell["controller"] for cell in cells))
    boxes = max((sum(c["controller"] == name for c in cells) for name in controllers), default=1)
    fig, axes = panel_grid(len(controllers), panel_width_in=max(PANEL_SIZE_IN[0], 0.3 * boxes))
    for ax, controller in zip(axes, controllers, strict=True):
        chosen = sorted(
            (c for c in cells if c["controller"] == controller), key=lambda c: (c["topology"], c["robots"])
        )
        labels, data = [], []
        for cell in chosen:
            lower = np.asarray(cell["lower_bound_s"])
            times = np.asarray(cell["times_s"])
            ratio = times[lower > 0] / lower[lower > 0]
            data.append(ratio[~np.isnan(ratio)])
            labels.append(f"{cell['topology']} {cell['robots']}")
        colour, _, _ = controller_style(controller, controllers)
        ax.boxplot(
            data,
            whis=(1, 99),
            showfliers=False,
            patch_artist=True,
            boxprops={"facecolor": colour, "alpha": 0.35},
            medianprops={"color": "black"},
        )
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=60, ha="right", fontsize=8)
        ax.axhline(1.0, color="black", lw=1, ls="-.", label="lower bound")
        spread = [np.percentile(d, [1, 99]) for d in data if len(d)]
        fit_axis(ax, np.ravel(spread) if spread else [], floor=1.0)
        ax.set(ylabel="convergence time / lower bound", title=controller_label(controller))
        ax.grid(True, which="both", axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("convergence time / lower bound: box 25-75 %, whiskers 1-99 %")
    return fig


def curves_figure(
    curves: dict[str, dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]],
    count: int,
    threshold_m: float,
    title: str,
):
    """Median and 10-90 % band of the metric over time: ``curves[topology][controller] = (times_s, low,
    median, high)``, one panel per topology."""
    topologies = list(curves)
    controllers = list(dict.fromkeys(c for per in curves.values() for c in per))
    fig, axes = panel_grid(len(topologies))
    for ax, topology in zip(axes, topologies, strict=True):
        values = [threshold_m]
        for controller, (times, low, median, high) in curves[topology].items():
            colour, marker, line = controller_style(controller, controllers)
            ax.plot(
                times,
                median,
                color=colour,
                marker=marker,
                ls=line,
                markevery=max(1, len(times) // 8),
                label=controller_label(controller),
            )
            ax.fill_between(times, low, high, color=colour, alpha=0.15, lw=0)
            values += [float(np.nanmin(low)), float(np.nanmax(high))]
        ax.axhline(threshold_m, color="grey", ls="--", lw=1, label=f"threshold {threshold_m:g} m")
        # below a tenth of the threshold the swarm has gathered: exact controllers reach 1e-8 m there,
        # which would spend most of the axis on what no reader needs
        fit_axis(ax, [max(value, threshold_m / CURVE_FLOOR_FACTOR) for value in values])
        ax.set_ylim(bottom=max(ax.get_ylim()[0], threshold_m / CURVE_FLOOR_FACTOR / 1.2))
        ax.set(xlabel="time (s)", ylabel="max pairwise distance (m)", title=f"{topology}, N = {count}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return fig


def save(fig, path: Path) -> Path:
    fig.savefig(path)
    _pyplot().close(fig)
    return path
