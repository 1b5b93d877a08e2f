"""``swarm evaluate``: a policy file beside the baselines (``CONTROLLER_ORDER``), as ratio to the bound.

Built on ``swarm.scenarios.sweep``: the same starts, graphs, stopping rule and per-cell cache, so the
local-consensus and centralized cells are shared with ``swarm sweep`` run with the same settings
(``--reuse`` reads another results directory's cells, e.g. ``docs/results/consensus_sweep``); the
model's cells are cached under the policy file's hash. ``--limit N:STARTS`` runs only the first
STARTS starts at N (every controller; cached full cells are cut to those starts), for sizes where
the full count is too slow; ``--limit TOPOLOGY:N:STARTS`` does so for one topology only. Writes
``evaluation.csv`` / ``.md`` (the ratio to local consensus is
the median over starts of the per-start time ratio, on starts where both converged), the sweep
plots, ``max_pairwise`` over time (median and 10-90 % band over starts, one figure per N of
``curve_sizes``, as the thesis's Figures 4.2-4.6) and, on disk graphs, how often the
communication graph disconnected during the run.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from swarm.core import metrics, topologies
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import (
    SweepConfig,
    cached_cell,
    cell_starts,
    find_cached_cell,
    make_controller,
    plot_sweep,
    summarize_cell,
)
from swarm.sim.kinematic import KinematicSim

CONTROLLER_ORDER = (
    "gnn",
    "mec_flood",
    "mec_flood_forward",
    "centralized_mec",
    "centralized",
    "local_consensus",
)
"""The model beside the strongest baselines: ``mec_flood`` with and without reversing, the
time-optimal ``centralized_mec``, the thesis's ``centralized`` expert and local consensus."""
CENTRAL_CONTROLLERS = ("centralized_mec", "centralized")  # ignore links: not run under packet loss


@dataclass(frozen=True)
class EvaluateConfig:
    model: str
    out: str = "runs/evaluate"
    topologies: list[str] = field(default_factory=lambda: list(topologies.kinds(default_grid=True)))
    sizes: list[int] = field(default_factory=lambda: [6, 12, 24])
    seeds: int = 1000
    limits: dict[int | str, int] = field(default_factory=dict)  # N or "topology:N" -> first starts
    max_duration_s: float = 20_000.0
    reuse: list[str] = field(default_factory=list)
    curve_sizes: list[int] = field(default_factory=lambda: [6, 24])
    curve_starts: int = 100
    curve_horizon_s: float = 600.0  # longest simulated time of a max_pairwise curve
    workers: int = 1  # processes a cell's starts are split over
    packet_losses: list[float] = field(default_factory=lambda: [0.0])  # every cell at each of these


def sweep_config(
    config: EvaluateConfig, count: int, topology: str | None = None, packet_loss: float = 0.0
) -> SweepConfig:
    limit = config.limits.get(f"{topology}:{count}", config.limits.get(count))
    return SweepConfig(
        topologies=config.topologies,
        sizes=[count],
        seeds=config.seeds,
        controllers=list(CONTROLLER_ORDER),
        max_duration_s=config.max_duration_s,
        model=config.model,
        first_starts=limit if limit is not None and limit < config.seeds else None,
        workers=config.workers,
        packet_loss=packet_loss,
    )


def evaluation_cell(
    config: EvaluateConfig,
    topology: str,
    count: int,
    controller: str,
    on_progress=None,
    packet_loss: float = 0.0,
) -> dict:
    """A cell from the cache (a full cell cut to ``first_starts`` if that is all there is) or run."""
    sweep = sweep_config(config, count, topology, packet_loss)
    out, reuse = Path(config.out), tuple(Path(d) for d in config.reuse)
    if sweep.first_starts is not None:
        full = find_cached_cell(out, replace(sweep, first_starts=None), topology, count, controller, reuse)
        if full is not None:
            cut = slice(0, sweep.first_starts)
            return {
                key: value[cut] if isinstance(value, np.ndarray) and value.ndim else value
                for key, value in full.items()
            }
    return cached_cell(out, sweep, topology, count, controller, on_progress, reuse)


def ratio_to(times: np.ndarray, reference: np.ndarray) -> float | None:
    both = ~np.isnan(times) & ~np.isnan(reference)
    return float(np.median(times[both] / reference[both])) if both.any() else None


def metric_curves(
    config: EvaluateConfig, topology: str, count: int, controller: str, horizon_s: float
) -> np.ndarray:
    """``max_pairwise`` ``(T, B)`` over the first ``curve_starts`` starts of a cell."""
    sweep = replace(sweep_config(config, count), first_starts=min(config.curve_starts, config.seeds))
    poses, adjacency, radius = cell_starts(sweep, topology, count)
    robot = RobotParams(v_max_mps=sweep.v_max_mps)
    controller_object = make_controller(controller, robot, sweep.gain, sweep.model, count)
    sim = KinematicSim(robot, controller_object, sweep.control_period_s, poses, adjacency, radius)
    ticks = round(horizon_s / sweep.control_period_s)
    values = np.empty((ticks + 1, len(poses)))
    values[0] = metrics.max_pairwise(sim.poses[..., :2])
    for tick in range(1, ticks + 1):
        sim.step()
        values[tick] = metrics.max_pairwise(sim.poses[..., :2])
    return values


def plot_curves(config: EvaluateConfig, rows: list[dict], count: int, path: Path) -> None:
    """``max_pairwise`` over time at N = ``count``, one panel per topology (``swarm.scenarios.plots``)."""
    from swarm.scenarios import plots

    topologies = [
        t for t in config.topologies if any(r["topology"] == t and r["robots"] == count for r in rows)
    ]
    dt = SweepConfig().control_period_s
    curves: dict[str, dict] = {}
    for topology in topologies:
        cell_rows = [r for r in rows if r["topology"] == topology and r["robots"] == count]
        p90 = [r["p90_time_s"] for r in cell_rows if r["p90_time_s"] is not None]
        horizon = min(config.curve_horizon_s, 1.2 * max(p90)) if p90 else config.curve_horizon_s
        curves[topology] = {}
        for controller in CONTROLLER_ORDER:
            values = metric_curves(config, topology, count, controller, horizon)
            low, median, high = np.percentile(values, [10, 50, 90], axis=1)
            curves[topology][controller] = (np.arange(len(values)) * dt, low, median, high)
    title = f"{Path(config.model).name}: median and 10-90 % over {config.curve_starts} starts"
    plots.save(plots.curves_figure(curves, count, SweepConfig().threshold_m, title), path)


def evaluate(config: EvaluateConfig, progress: bool = True) -> list[dict]:
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    todo = [
        (t, n, c, loss)
        for loss in config.packet_losses
        for t in config.topologies
        for n in config.sizes
        for c in CONTROLLER_ORDER
        if not (loss > 0 and c in CENTRAL_CONTROLLERS)
    ]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="cell", desc="evaluate")
    cells: dict[tuple, dict] = {}
    for topology, count, controller, loss in todo:
        on_progress = None
        if bar is not None:
            bar.set_description(f"{topology} N={count} {controller}" + (f" loss {loss:g}" if loss else ""))

            def on_progress(time_s: float, done: int, bar=bar) -> None:
                bar.set_postfix_str(f"t={time_s:.0f}s done={done}")

        cells[topology, count, controller, loss] = evaluation_cell(
            config, topology, count, controller, on_progress, loss
        )
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    rows = []
    for (topology, count, _, loss), cell in cells.items():
        row = summarize_cell(cell)
        row["median_ratio_to_local_consensus"] = ratio_to(
            cell["times_s"], cells[topology, count, "local_consensus", loss]["times_s"]
        )
        rows.append(row)
    write_tables(config, rows)
    lossless = [key for key in cells if key[3] == 0]
    if lossless:
        plot_sweep(
            out,
            [cells[key] for key in lossless],
            [r for r in rows if r["packet_loss"] == 0],
            sweep_config(config, config.sizes[0]),
        )
    for count in config.curve_sizes:
        if count in config.sizes:
            plot_curves(config, rows, count, out / f"max_pairwise_N{count}.png")
    return rows


def write_tables(config: EvaluateConfig, rows: list[dict]) -> None:
    out = Path(config.out)
    with open(out / "evaluation.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out / "evaluation_config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")

    def fmt(value: object, percent: bool = False) -> str:
        if value is None:
            return "-"
        return f"{value:.1%}" if percent else f"{value:.2f}" if isinstance(value, float) else str(value)

    def ratio(value: float | None) -> str:
        return "-" if value is None else f"{value:.3f}"

    disk = any(row["disconnected_rate"] is not None for row in rows)
    header = (
        "| topology | N | loss | controller | starts | success | median t (s) | p90 t (s) | t / LB "
        "| p95 t / LB | t / LC |"
    )
    header += " disconnected |" if disk else ""
    lines = [
        f"Model `{config.model}`; random starts per cell as given; convergence: max_pairwise <= 0.2 m held "
        "5 s, kinematic engine. t / LB: median ratio to the lower bound of docs/design.md; t / LC: median "
        "over starts of the time ratio to local consensus on the same start (where both converged).",
        "",
        header,
        "|" + "---|" * (header.count("|") - 1),
    ]
    for row in rows:
        line = (
            f"| {row['topology']} | {row['robots']} | {row['packet_loss']:.0%} | {row['controller']} "
            f"| {row['starts']} | {row['success_rate']:.1%} | {fmt(row['median_time_s'])} "
            f"| {fmt(row['p90_time_s'])} | {ratio(row['median_ratio_to_lower_bound'])} "
            f"| {ratio(row['p95_ratio_to_lower_bound'])} | {fmt(row['median_ratio_to_local_consensus'])} |"
        )
        lines.append(line + (f" {fmt(row['disconnected_rate'], percent=True)} |" if disk else ""))
    (out / "evaluation.md").write_text("\n".join(lines) + "\n")
