"""Sweeps: topologies x swarm sizes x random starts x controllers in the batched simulator.

Every cell runs all its random starts as one batch. An environment leaves the batch
once its metric has stayed at or under the threshold for ``hold_s``; its convergence
time is the first time after which the metric never rose above the threshold again
(up to where it was simulated). Starts still above the threshold at ``max_duration_s``
count as failures. Controller ``gnn`` runs the policy file ``model`` (default: the shipped one;
its cells are cached under the file's hash); on disk graphs every cell also records whether the
graph ever disconnected.
"""

from __future__ import annotations

import csv
import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from swarm.core import graphs, metrics, topologies
from swarm.core.faults import LinkFaults
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams
from swarm.scenarios.scenario import ScenarioError, default_model_path
from swarm.sim import kernels
from swarm.sim.controller_kinds import CONTROLLER_KINDS, ControllerArgs, batched_controller, controller_kind
from swarm.sim.controllers import BatchedController
from swarm.sim.kinematic import KinematicSim

SORTED_LINE = "line_sorted"
"""A sweep-only topology: the starts of ``line`` with each start's robots renumbered by increasing x,
so that graph hops follow space (the two ends of the line are the two extreme robots)."""

SWEEP_CONTROLLERS: dict[str, tuple[str, dict]] = {
    "local_consensus": ("local_consensus", {}),
    "centralized": ("centralized", {}),
    "gnn": ("gnn", {}),
    "mec_flood": ("mec_flood", {}),
    "mec_flood_forward": ("mec_flood", {"reverse": False}),
    "centralized_mec": ("centralized_mec", {}),
}
"""Sweep controller names -> (``swarm.sim.controller_kinds`` kind, options): ``mec_flood_forward`` is
``mec_flood`` without reversing."""
CONTROLLERS = tuple(SWEEP_CONTROLLERS)
LOSS_CHUNK_STARTS = 50
"""Under packet loss, a cell's starts run in chunks of this many, chunk c with loss seed c: the
loss draws (``swarm.core.faults``) are the same in every environment of one simulator."""


@dataclass(frozen=True)
class SweepConfig:
    topologies: list[str] = field(default_factory=lambda: list(topologies.kinds(default_grid=True)))
    sizes: list[int] = field(default_factory=lambda: [6, 12, 24, 50, 100])
    seeds: int = 1000
    controllers: list[str] = field(default_factory=lambda: ["local_consensus", "centralized"])
    gain: float = 1.0
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    threshold_m: float = 0.2
    max_duration_s: float = 20_000.0
    hold_s: float = 5.0
    random_p: float | None = None  # None: 1.5 ln(N) / N, a sparse but usually connected graph
    disk_radius_m: float | None = None  # None: the smallest radius that connects every start
    min_separation_m: float = 0.4
    seed: int = 0
    model: str | None = None  # policy file of controller "gnn"
    first_starts: int | None = None  # run only the first ones of the `seeds` starts (None: all)
    workers: int = 1  # processes a cell's starts are split over (results do not depend on it)
    packet_loss: float = 0.0  # probability that any one message is lost (swarm.core.faults packet_loss)

    @classmethod
    def from_mapping(cls, data: dict, source: str = "<config>") -> SweepConfig:
        known = {item.name for item in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ScenarioError(f"{source}: {unknown[0]}: unknown key")
        return cls().with_overrides(data, source)

    def with_overrides(self, overrides: dict, source: str = "command line") -> SweepConfig:
        """These fields replaced, then checked; controller ``gnn`` without a ``model`` gets the shipped
        ``models/gnn_default.npz``, as ``swarm run`` does."""
        config = replace(self, **overrides)
        if "gnn" in config.controllers and config.model is None:
            config = replace(config, model=str(default_model_path()))
        config.check(source)
        return config

    def check(self, source: str) -> None:
        for topology in self.topologies:
            if topology not in (*topologies.kinds(grid=True), SORTED_LINE):
                raise ScenarioError(f"{source}: topologies: unknown topology '{topology}'")
        for controller in self.controllers:
            if controller not in CONTROLLERS:
                kind = CONTROLLER_KINDS.get(controller)
                if kind is not None and kind.task != "rendezvous":  # another task's: its own sweep
                    raise ScenarioError(
                        f"{source}: controllers: '{controller}' does task {kind.task}; sweep it with"
                        f" swarm sweep --task {kind.task}"
                    )
                raise ScenarioError(f"{source}: controllers: unknown controller '{controller}'")
        if "gnn" in self.controllers:
            if self.model is None:
                raise ScenarioError(f"{source}: model: controller 'gnn' needs a policy file")
            if not Path(self.model).is_file():
                raise ScenarioError(f"{source}: model: no such policy file {self.model}")
        if self.first_starts is not None and not 0 < self.first_starts <= self.seeds:
            raise ScenarioError(f"{source}: first_starts: must be in 1..seeds")
        if not 0.0 <= self.packet_loss < 1.0:
            raise ScenarioError(f"{source}: packet_loss: must be in [0, 1)")
        if self.workers < 1:
            raise ScenarioError(f"{source}: workers: must be at least 1")
        if any(size < 2 for size in self.sizes):
            raise ScenarioError(f"{source}: sizes: every N must be at least 2")
        for name in ("seeds", "gain", "v_max_mps", "control_period_s", "threshold_m", "max_duration_s"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"{source}: {name}: must be positive")


random_edge_probability = topologies.default_edge_probability


def cell_graphs(
    config: SweepConfig, topology: str, count: int, rng: np.random.Generator
) -> np.ndarray | None:
    """``(B, N, N)`` adjacency for one cell (a fresh connected graph per start for a random kind);
    None for proximity graphs."""
    kind = topologies.get(topology)
    if kind.proximity:
        return None
    if kind.random:
        seeds = rng.integers(0, 2**31, size=config.seeds)
        params = [topologies.Params(p=config.random_p, seed=int(seed), connected=True) for seed in seeds]
        return np.stack([kind.fixed(count, one) for one in params])
    return np.broadcast_to(kind.fixed(count), (config.seeds, count, count))


def connecting_radius(positions: np.ndarray) -> float:
    """Smallest disk radius for which every start's disk graph is connected (largest MST edge)."""
    largest = 0.0
    for start in positions:
        distance = np.linalg.norm(start[:, None] - start[None], axis=-1)
        in_tree = np.zeros(len(start), dtype=bool)
        in_tree[0] = True
        best = distance[0].copy()
        for _ in range(len(start) - 1):
            candidate = np.where(in_tree, np.inf, best)
            nearest = int(np.argmin(candidate))
            largest = max(largest, float(candidate[nearest]))
            in_tree[nearest] = True
            best = np.minimum(best, distance[nearest])
    return largest * 1.0001


def make_controller(
    name: str,
    robot: RobotParams,
    gain: float,
    model: str | None = None,
    robot_count: int = 0,
    control_period_s: float = 0.05,
) -> BatchedController:
    """The batched controller of sweep controller ``name`` (``SWEEP_CONTROLLERS``)."""
    kind, options = SWEEP_CONTROLLERS[name]
    args = ControllerArgs(robot, control_period_s, gain, robot_count=robot_count, policy=model, **options)
    return batched_controller(kind, args)


def file_hash(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def connected(adjacency: np.ndarray) -> np.ndarray:
    """``(B, N, N)`` adjacency -> ``(B,)`` bool, every robot reachable from robot 0."""
    reached = np.zeros(adjacency.shape[:2], dtype=np.float64)
    reached[:, 0] = 1.0
    links = adjacency.astype(np.float64)
    for _ in range(adjacency.shape[1]):
        grown = np.minimum(1.0, reached + np.einsum("bij,bj->bi", links, reached))
        if np.array_equal(grown, reached):
            break
        reached = grown
    return reached.min(axis=1) > 0


def links_connected(links) -> np.ndarray:
    """:func:`connected` for ``swarm.sim.links.Links`` (a breadth-first search per environment, numba)."""
    batch, count = links.shape
    reached = np.empty((batch, count), dtype=np.int64)
    result = np.empty(batch, dtype=np.bool_)
    kernels.lists_connected(np.ascontiguousarray(links.index), reached, result)
    return result


def converge_batch(
    sim: KinematicSim,
    threshold_m: float,
    max_duration_s: float,
    hold_s: float,
    on_progress=None,
    disconnected: np.ndarray | None = None,
) -> np.ndarray:
    """Run until every environment has held max_pairwise <= threshold for ``hold_s`` or time runs out.

    Returns the convergence time of each environment (NaN where it never converged). With
    ``disconnected`` (a ``(B,)`` bool array), marks there every environment whose communication
    graph was disconnected at some tick of its run.
    """
    batch = sim.batch_size
    dt = sim.control_period_s
    hold_ticks = max(1, round(hold_s / dt))
    max_ticks = round(max_duration_s / dt)
    active = np.arange(batch)
    last_above = np.full(batch, -1, dtype=np.int64)  # last tick with metric above threshold
    result = np.full(batch, np.nan)
    for tick in range(max_ticks + 1):
        above = _above_threshold(sim.poses, threshold_m)
        last_above[active[above]] = tick
        if disconnected is not None:
            disconnected[active[~links_connected(sim.links())]] = True
        if tick == max_ticks:
            break
        settled = tick - last_above[active] >= hold_ticks
        if settled.any():
            result[active[settled]] = (last_above[active[settled]] + 1) * dt
            active = active[~settled]
            sim.keep(~settled)
            if len(active) == 0:
                break
        sim.step()
        if on_progress is not None and tick % 200 == 0:
            on_progress(tick * dt, batch - len(active))
    if len(active):
        below_at_end = last_above[active] < tick
        result[active[below_at_end]] = (last_above[active[below_at_end]] + 1) * dt
    return result


def _above_threshold(positions: np.ndarray, threshold_m: float) -> np.ndarray:
    """Exact ``max_pairwise > threshold`` per environment (``kernels.diameter_above``); positions or
    poses ``(B, N, >=2)``, only the first two columns are read."""
    above = np.empty(positions.shape[0], dtype=np.bool_)
    kernels.diameter_above(np.ascontiguousarray(positions), threshold_m, above)
    return above


def cell_starts(
    config: SweepConfig, topology: str, count: int
) -> tuple[np.ndarray, np.ndarray | None, float | None]:
    """The starts of a cell: poses ``(B, N, 3)``, adjacency ``(B, N, N)`` (None on disk graphs) and
    the disk radius (None on fixed graphs); the first ``first_starts`` when that is set."""
    sorted_line = topology == SORTED_LINE
    topology = "line" if sorted_line else topology
    cell_seed = np.random.SeedSequence([config.seed, topologies.grid_index(topology), count])
    rng = np.random.default_rng(cell_seed)
    box = box_for(count)
    poses = random_poses(rng, config.seeds, count, box, box, config.min_separation_m)
    if sorted_line:
        order = np.argsort(poses[..., 0], axis=1, kind="stable")
        poses = np.take_along_axis(poses, order[..., None], axis=1)
    adjacency = cell_graphs(config, topology, count, rng)
    disk_radius = None
    if adjacency is None:  # the radius connecting all `seeds` starts, even when running fewer
        disk_radius = config.disk_radius_m or connecting_radius(poses[..., :2])
    if config.first_starts is not None:
        poses = poses[: config.first_starts]
        adjacency = None if adjacency is None else adjacency[: config.first_starts]
    return poses, adjacency, disk_radius


def _converge_starts(
    config: SweepConfig,
    count: int,
    controller: str,
    poses: np.ndarray,
    adjacency: np.ndarray | None,
    disk_radius: float | None,
    on_progress=None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Convergence times of some starts of a cell (and, on disk graphs, which ones disconnected)."""
    robot = RobotParams(v_max_mps=config.v_max_mps)
    if config.packet_loss > 0 and not controller_kind(SWEEP_CONTROLLERS[controller][0]).central:
        chunks = np.array_split(np.arange(len(poses)), -(-len(poses) // LOSS_CHUNK_STARTS))
        times = np.full(len(poses), np.nan)
        disconnected = np.zeros(len(poses), dtype=bool) if adjacency is None else None
        for seed, chunk in enumerate(chunks):
            faults = LinkFaults.packet_loss(config.packet_loss, config.control_period_s, seed)
            part = None if disconnected is None else np.zeros(len(chunk), dtype=bool)
            sim = KinematicSim(
                robot,
                make_controller(controller, robot, config.gain, config.model, count, config.control_period_s),
                config.control_period_s,
                poses[chunk],
                adjacency=None if adjacency is None else adjacency[chunk],
                disk_radius_m=disk_radius,
                link_faults=faults,
            )
            times[chunk] = converge_batch(
                sim, config.threshold_m, config.max_duration_s, config.hold_s, on_progress, part
            )
            if part is not None and disconnected is not None:
                disconnected[chunk] = part
        return times, disconnected
    disconnected = np.zeros(len(poses), dtype=bool) if adjacency is None else None
    sim = KinematicSim(
        robot,
        make_controller(controller, robot, config.gain, config.model, count, config.control_period_s),
        config.control_period_s,
        poses,
        adjacency=adjacency,
        disk_radius_m=disk_radius,
    )
    times = converge_batch(
        sim, config.threshold_m, config.max_duration_s, config.hold_s, on_progress, disconnected
    )
    return times, disconnected


def _one_thread() -> None:
    """Worker initializer: one numba thread per process, the processes share the cores."""
    import numba

    numba.set_num_threads(1)


def _converge_in_workers(
    config: SweepConfig, count: int, controller: str, poses, adjacency, disk_radius, on_progress=None
) -> tuple[np.ndarray, np.ndarray | None]:
    """``_converge_starts`` over ``config.workers`` processes, the starts cut into chunks (four per
    worker, so a slow chunk does not leave the others idle); each start's result is the same."""
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from multiprocessing import get_context

    chunks = np.array_split(np.arange(len(poses)), min(len(poses), 4 * config.workers))
    times = np.full(len(poses), np.nan)
    disconnected = np.zeros(len(poses), dtype=bool) if adjacency is None else None
    with ProcessPoolExecutor(config.workers, get_context("spawn"), initializer=_one_thread) as pool:
        futures = {
            pool.submit(
                _converge_starts,
                config,
                count,
                controller,
                poses[chunk],
                None if adjacency is None else np.ascontiguousarray(adjacency[chunk]),
                disk_radius,
            ): chunk
            for chunk in chunks
        }
        for future in as_completed(futures):
            chunk = futures[future]
            times[chunk], chunk_disconnected = future.result()
            if disconnected is not None:
                disconnected[chunk] = chunk_disconnected
            if on_progress is not None:
                on_progress(float(np.nanmax(times[chunk], initial=0.0)), int(np.sum(~np.isnan(times))))
    return times, disconnected


def run_cell(config: SweepConfig, topology: str, count: int, controller: str, on_progress=None) -> dict:
    """One (topology, N, controller) cell over ``config.seeds`` random starts."""
    poses, adjacency, disk_radius = cell_starts(config, topology, count)
    starts = len(poses)
    workers = config.workers > 1 and starts > 1 and config.packet_loss == 0
    converge = _converge_in_workers if workers else _converge_starts
    times, disconnected = converge(config, count, controller, poses, adjacency, disk_radius, on_progress)
    lower = np.array(
        [metrics.lower_bound_s(start[:, :2], config.threshold_m, config.v_max_mps) for start in poses]
    )
    if adjacency is None:
        assert disk_radius is not None
        lambda2 = np.array(
            [graphs.algebraic_connectivity(graphs.disk(start[:, :2], disk_radius)) for start in poses]
        )
    elif topology != SORTED_LINE and topologies.get(topology).random:
        lambda2 = np.array([graphs.algebraic_connectivity(matrix) for matrix in adjacency])
    else:
        lambda2 = np.full(starts, graphs.algebraic_connectivity(adjacency[0]))
    return {
        "topology": topology,
        "robots": count,
        "controller": controller,
        "times_s": times,
        "lower_bound_s": lower,
        "lambda2": lambda2,
        "disk_radius_m": disk_radius,
        "disconnected": disconnected,
        "packet_loss": config.packet_loss,
    }


def summarize_cell(cell: dict) -> dict:
    times, lower = cell["times_s"], cell["lower_bound_s"]
    converged = ~np.isnan(times)
    ratio = np.where(lower > 0, times / np.where(lower > 0, lower, 1.0), np.nan)

    def stat(values: np.ndarray, function) -> float | None:
        values = values[~np.isnan(values)]
        return float(function(values)) if len(values) else None

    return {
        "topology": cell["topology"],
        "robots": cell["robots"],
        "controller": cell["controller"],
        "packet_loss": cell.get("packet_loss", 0.0),
        "starts": len(times),
        "success_rate": float(converged.mean()),
        "median_time_s": stat(times, np.median),
        "p10_time_s": stat(times, lambda v: np.percentile(v, 10)),
        "p90_time_s": stat(times, lambda v: np.percentile(v, 90)),
        "max_time_s": stat(times, np.max),
        "median_lower_bound_s": float(np.median(lower)),
        "median_ratio_to_lower_bound": stat(ratio, np.median),
        "p95_ratio_to_lower_bound": stat(ratio, lambda v: np.percentile(v, 95)),
        "min_ratio_to_lower_bound": stat(ratio, np.min),
        "median_lambda2": float(np.median(cell["lambda2"])),
        "median_time_x_lambda2": stat(times * cell["lambda2"], np.median),
        "disconnected_rate": None if cell.get("disconnected") is None else float(cell["disconnected"].mean()),
    }


def cell_settings(config: SweepConfig, controller: str) -> dict:
    """What a cached cell must have been run with: every setting but the grid; the model file's hash
    instead of its path (gnn only); ``first_starts`` only when set (older caches lack both)."""
    grid = ("topologies", "sizes", "controllers", "model", "first_starts", "workers", "packet_loss")
    settings = {key: value for key, value in asdict(config).items() if key not in grid}
    if config.first_starts is not None:
        settings["first_starts"] = config.first_starts
    if config.packet_loss > 0:  # older caches are lossless and lack it
        settings["packet_loss"] = config.packet_loss
    if controller == "gnn":
        assert config.model is not None  # SweepConfig.check: gnn needs a model
        settings["model_sha256"] = file_hash(config.model)
    return settings


def cell_path(cells_dir: Path, config: SweepConfig, topology: str, count: int, controller: str) -> Path:
    suffix = f"-{cell_settings(config, controller)['model_sha256'][:12]}" if controller == "gnn" else ""
    limit = f"_first{config.first_starts}" if config.first_starts is not None else ""
    loss = f"_loss{config.packet_loss:g}" if config.packet_loss > 0 else ""
    return cells_dir / f"{topology}_{count}_{controller}{suffix}{loss}{limit}.npz"


def find_cached_cell(
    out_dir: Path,
    config: SweepConfig,
    topology: str,
    count: int,
    controller: str,
    reuse: tuple[Path, ...] = (),
) -> dict | None:
    """The cell from ``out_dir/cells`` or a ``reuse`` directory's cells if run with these settings."""
    settings = cell_settings(config, controller)
    for base in (out_dir, *reuse):
        candidate = cell_path(Path(base) / "cells", config, topology, count, controller)
        if not candidate.is_file():
            continue
        with np.load(candidate) as saved:
            if json.loads(str(saved["settings"])) == settings:
                radius = float(saved["disk_radius_m"])
                return {
                    "topology": topology,
                    "robots": count,
                    "controller": controller,
                    "times_s": saved["times_s"],
                    "lower_bound_s": saved["lower_bound_s"],
                    "lambda2": saved["lambda2"],
                    "disk_radius_m": None if np.isnan(radius) else radius,
                    "disconnected": saved["disconnected"] if "disconnected" in saved.files else None,
                    "packet_loss": config.packet_loss,
                }
    return None


def cached_cell(
    out_dir: Path,
    config: SweepConfig,
    topology: str,
    count: int,
    controller: str,
    on_progress=None,
    reuse: tuple[Path, ...] = (),
) -> dict:
    """``run_cell``, with its raw per-start results kept in ``out_dir/cells/``: a sweep that was
    interrupted, or extended with more sizes or topologies, reuses every cell it already ran with
    the same settings. ``reuse``: more results directories whose cells are read (never written)."""
    cell = find_cached_cell(out_dir, config, topology, count, controller, reuse)
    if cell is not None:
        return cell
    path = cell_path(out_dir / "cells", config, topology, count, controller)
    settings = cell_settings(config, controller)
    cell = run_cell(config, topology, count, controller, on_progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    extra = {} if cell["disconnected"] is None else {"disconnected": cell["disconnected"]}
    np.savez_compressed(
        path,
        settings=json.dumps(settings),
        times_s=cell["times_s"],
        lower_bound_s=cell["lower_bound_s"],
        lambda2=cell["lambda2"],
        disk_radius_m=np.nan if cell["disk_radius_m"] is None else cell["disk_radius_m"],
        **extra,
    )
    return cell


def run_sweep(config: SweepConfig, out_dir: Path, progress: bool = True) -> list[dict]:
    """Run every cell (reusing cached ones), write sweep.csv, sweep.md, the per-start results in
    cells/ and the plots; returns the rows."""
    out_dir.mkdir(parents=True, exist_ok=True)
    cells_todo = [
        (topology, count, controller)
        for topology in config.topologies
        for count in config.sizes
        for controller in config.controllers
    ]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cells_todo), unit="cell", desc="sweep")
    cells, rows = [], []
    for topology, count, controller in cells_todo:
        on_progress: Callable[[float, int], None] | None = None
        if bar is not None:
            bar.set_description(f"{topology} N={count} {controller}")

            def show(time_s: float, done: int, bar=bar) -> None:
                bar.set_postfix_str(f"t={time_s:.0f}s done={done}/{config.seeds}")

            on_progress = show
        cell = cached_cell(out_dir, config, topology, count, controller, on_progress)
        cells.append(cell)
        rows.append(summarize_cell(cell))
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    write_tables(out_dir, config, rows)
    plot_sweep(out_dir, cells, rows, config)
    return rows


def write_tables(out_dir: Path, config: SweepConfig, rows: list[dict]) -> None:
    with open(out_dir / "sweep.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out_dir / "sweep_config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")

    def fmt(value: object, digits: int = 2) -> str:
        if value is None:
            return "-"
        if isinstance(value, float):
            return f"{value:.{digits}f}"
        return str(value)

    header = (
        "| topology | N | controller | starts | success | median t (s) | p90 t (s) | median LB (s) "
        "| median t / LB | min t / LB | lambda2 | median t x lambda2 |"
    )
    lines = [
        f"Sweep: {config.seeds} random starts per cell, gain K = {config.gain:g} 1/s, "
        f"v_max = {config.v_max_mps:g} m/s, control period {config.control_period_s:g} s, "
        f"max_pairwise threshold {config.threshold_m:g} m. LB: lower bound of docs/design.md.",
        "",
        header,
        "|" + "---|" * (header.count("|") - 1),
    ]
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['controller']} | {row['starts']} "
            f"| {row['success_rate']:.1%} | {fmt(row['median_time_s'])} | {fmt(row['p90_time_s'])} "
            f"| {fmt(row['median_lower_bound_s'])} | {fmt(row['median_ratio_to_lower_bound'])} "
            f"| {fmt(row['min_ratio_to_lower_bound'])} | {fmt(row['median_lambda2'], 4)} "
            f"| {fmt(row['median_time_x_lambda2'])} |"
        )
    (out_dir / "sweep.md").write_text("\n".join(lines) + "\n")


def plot_sweep(out_dir: Path, cells: list[dict], rows: list[dict], config: SweepConfig) -> None:
    """``convergence_time.png`` (time against N per topology, and against 1/lambda2) and
    ``ratio_to_lower_bound.png`` (distributions per controller): ``swarm.scenarios.plots``."""
    from swarm.scenarios import plots

    plots.save(plots.sweep_time_figure(rows), out_dir / "convergence_time.png")
    plots.save(plots.sweep_ratio_figure(cells), out_dir / "ratio_to_lower_bound.png")
