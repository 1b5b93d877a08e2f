"""``swarm sweep --task TASK``: a task's controllers over graphs, sizes and seeded starts, batched.

The rendezvous sweep (``swarm.scenarios.sweep``) judges one metric against a threshold; this one asks
the task registry (``swarm.core.tasks``) for everything it judges, so that a task with a ``sweep``
entry (:class:`swarm.core.tasks.registry.SweepCells`) is measured by the same command:

1. **Cells.** Every (topology, N, packet loss, controller); controllers default to the task's experts
   and decentralized baselines. A central controller hears no links, so it has no lossy cells.
2. **Starts.** ``seeds`` starts per (topology, N), drawn by the task (``SweepCells.starts``) from a
   generator seeded with ``(seed, topology, N)``: every controller of a cell runs the same starts.
   A random graph is one connected G(N, p) per start; on a disk graph (radius ``disk_radius_m``) a
   start whose graph is not connected is drawn again. There a Voronoi cell is cut at half the radius,
   the distance within which a robot hears every robot that could share its cell (Cortes, Martinez and
   Bullo 2005; read only by ``lloyd_local``).
3. **Runs.** Chunks of ``chunk_starts`` starts in the kinematic engine (chunk c draws its packet
   losses from seed c), for the task's ``duration_s`` or until every start has held the task's
   success rule for ``hold_s`` (``SweepCells.held``). Positions every ``sample_every_ticks`` ticks.
   With ``workers`` (``--workers``) the chunks run in that many processes; a chunk's result depends
   only on its starts and its seed, so every cell file is the one a single process writes.
4. **Judging.** The task's own ``outcome`` on each start's trajectory (what ``swarm run`` reports for
   one run): success, its time, the bound or reference, the task's metrics.
5. **Tables and plot.** ``sweep.csv`` / ``sweep.md``: success and the median and p95 over the starts of
   each of the task's ``columns``; ``sweep.png``: the first column against N per topology;
   ``cells/*.json``: every start's outcome.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import signal
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from swarm.core import graphs, topologies
from swarm.core.faults import LinkFaults
from swarm.core.files import write_atomically
from swarm.core.robot import RobotParams
from swarm.core.tasks import registry
from swarm.scenarios.blas import blas_kernel, coretype_setting
from swarm.scenarios.scenario import ScenarioError
from swarm.sim.controller_kinds import CONTROLLER_KINDS, ControllerArgs, batched_controller, controller_kind
from swarm.sim.kinematic import KinematicSim

log = logging.getLogger(__name__)

GRAPHS = ("complete", "cycle", "line", "random", "disk")
DISK_ATTEMPTS = 200
"""Draws of ``seeds`` starts after which a disk cell with too few connected starts is refused."""


def sweep_tasks() -> tuple[str, ...]:
    """Tasks that ``swarm sweep --task`` measures (a ``sweep`` entry in the registry)."""
    return tuple(name for name in registry.names() if registry.get(name).sweep is not None)


@dataclass(frozen=True)
class TaskSweepConfig:
    """Every setting of a task sweep; a YAML ``--config`` may give any of them."""

    task: str
    topologies: list[str] = field(default_factory=lambda: list(GRAPHS))
    sizes: list[int] = field(default_factory=lambda: [6, 12, 24])
    seeds: int = 20  # starts per (topology, N)
    controllers: list[str] | None = None  # None: the task's experts and baselines
    packet_losses: list[float] = field(default_factory=lambda: [0.0])
    v_max_mps: float = 0.5
    control_period_s: float = 0.05
    duration_s: float | None = None  # None: the task's (SweepCells.duration_s)
    disk_radius_m: float = 2.0
    seed: int = 0
    chunk_starts: int = 50
    model: str | None = None  # the policy file of the task's learned kind (None: the shipped one)

    @classmethod
    def from_mapping(cls, data: dict, source: str = "<config>") -> TaskSweepConfig:
        known = {item.name for item in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ScenarioError(f"{source}: {unknown[0]}: unknown key of a task sweep")
        if "task" not in data:
            raise ScenarioError(f"{source}: task: missing (one of {', '.join(sweep_tasks())})")
        config = cls(task=str(data["task"]))
        return config.with_overrides({k: v for k, v in data.items() if k != "task"}, source)

    def with_overrides(self, overrides: dict, source: str = "command line") -> TaskSweepConfig:
        config = replace(self, **overrides)
        config.check(source)
        return config

    @property
    def cells(self) -> registry.SweepCells:
        sweep = registry.get(self.task).sweep
        assert sweep is not None  # check() refused such a task
        return sweep

    @property
    def chosen_controllers(self) -> list[str]:
        task = registry.get(self.task)
        if self.controllers is not None:
            return list(self.controllers)
        return [*task.experts, *task.baselines, *task.learned]

    @property
    def run_duration_s(self) -> float:
        return self.duration_s if self.duration_s is not None else self.cells.duration_s

    def check(self, source: str) -> None:
        if self.task not in sweep_tasks():
            raise ScenarioError(
                f"{source}: task: '{self.task}' is not swept; choose from {', '.join(sweep_tasks())}"
            )
        task = registry.get(self.task)
        for controller in self.chosen_controllers:
            kind = CONTROLLER_KINDS.get(controller)
            if kind is None or kind.task != self.task:
                raise ScenarioError(
                    f"{source}: controllers: '{controller}' does not do task {self.task}"
                    f" (choose from {', '.join(task.controllers)})"
                )
        for topology in self.topologies:
            if topology not in topologies.kinds(grid=True):
                raise ScenarioError(f"{source}: topologies: unknown topology '{topology}'")
        if any(size < 2 for size in self.sizes):
            raise ScenarioError(f"{source}: sizes: every N must be at least 2")
        if any(not 0.0 <= p < 1.0 for p in self.packet_losses):
            raise ScenarioError(f"{source}: packet_losses: each must be in [0, 1)")
        for name in ("seeds", "v_max_mps", "control_period_s", "disk_radius_m", "chunk_starts"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"{source}: {name}: must be positive")
        if self.duration_s is not None and not self.duration_s > 0:
            raise ScenarioError(f"{source}: duration_s: must be positive")
        if self.model is not None:
            if not Path(self.model).is_file():
                raise ScenarioError(f"{source}: model: {self.model}: no such policy file")
            if not any("model" in CONTROLLER_KINDS[name].options for name in self.chosen_controllers):
                raise ScenarioError(
                    f"{source}: model: none of the controllers takes one"
                    f" (the task's learned kinds: {', '.join(task.learned) or 'none'})"
                )


# ---------------------------------------------------------------------------------------------- starts
def cell_starts(config: TaskSweepConfig, topology: str, count: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``(B, N, 3)`` starts and ``(B, N, N)`` graphs (None on a proximity graph) of a (topology, N)."""
    index = topologies.grid_index(topology)
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, index, count]))
    kind = topologies.get(topology)
    if not kind.proximity:
        poses = config.cells.starts(rng, config.seeds, count)
        drawn = [topologies.draw(topology, count, rng) for _ in range(config.seeds)]
        return poses, np.stack([graph for graph in drawn if graph is not None])  # a fixed kind: never None
    chosen: list[np.ndarray] = []
    for _ in range(DISK_ATTEMPTS):
        for pose in config.cells.starts(rng, config.seeds, count):
            if graphs.is_connected(graphs.disk(pose[:, :2], config.disk_radius_m)):
                chosen.append(pose)
        if len(chosen) >= config.seeds:
            return np.stack(chosen[: config.seeds]), None
    raise ScenarioError(
        f"disk_radius_m: {config.disk_radius_m:g} m connects too few starts of {count} robots"
        f" ({len(chosen)} in {DISK_ATTEMPTS * config.seeds} draws); give a larger radius"
    )


# ---------------------------------------------------------------------------------------------- runs
def run_chunk(
    config: TaskSweepConfig,
    section: Any,
    controller: str | Any,
    poses: np.ndarray,
    adjacency: np.ndarray | None,
    loss: float,
    loss_seed: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(T,)`` and axle positions ``(T, B, N, 2)`` of one chunk of starts (``controller``: a kind's
    name, or a batched controller already built, as training's closed-loop check passes)."""
    cells, count = config.cells, poses.shape[1]
    robot = RobotParams(v_max_mps=config.v_max_mps)
    proximity = adjacency is None
    takes_model = isinstance(controller, str) and "model" in CONTROLLER_KINDS[controller].options
    args = ControllerArgs(
        robot=robot,
        control_period_s=config.control_period_s,
        robot_count=count,
        task=section,
        cell_radius_m=config.disk_radius_m / 2 if proximity else None,
        policy=config.model if takes_model else None,
    )
    faults = None
    if loss > 0:
        faults = LinkFaults.packet_loss(loss, config.control_period_s, seed=loss_seed)
    sim = KinematicSim(
        robot,
        batched_controller(controller, args) if isinstance(controller, str) else controller,
        config.control_period_s,
        poses,
        adjacency=adjacency,
        disk_radius_m=config.disk_radius_m if proximity else None,
        link_faults=faults,
    )
    dt, every = config.control_period_s, cells.sample_every_ticks
    max_ticks = round(config.run_duration_s / dt)
    hold_ticks = max(1, round(section.hold_s / dt))
    last_failed = np.full(len(poses), -1)  # the last tick each start's success rule did not hold
    frames, ticks = [sim.poses[..., :2].copy()], [0]
    for tick in range(1, max_ticks + 1):
        sim.step()
        stop = False
        if cells.held is not None:
            last_failed[~cells.held(sim.poses[..., :2], section)] = tick
            stop = bool(np.all(tick - last_failed > hold_ticks))  # held hold_s past its settle tick
        if tick % every == 0 or stop or tick == max_ticks:
            frames.append(sim.poses[..., :2].copy())
            ticks.append(tick)
        if stop:
            break
    return np.asarray(ticks) * dt, np.stack(frames)


def chunk_outcomes(
    config: TaskSweepConfig,
    count: int,
    controller: str | Any,
    loss: float,
    loss_seed: int,
    poses: np.ndarray,
    adjacency: np.ndarray | None,
) -> list[dict]:
    """The task's own ``outcome`` of every start of one chunk (chunk ``loss_seed`` of its cell), the
    numbers and the kept keys only: what a cell file holds."""
    task = registry.get(config.task)
    assert task.outcome is not None
    section = config.cells.section(count)
    times, positions = run_chunk(config, section, controller, poses, adjacency, loss, loss_seed)
    outcomes = []
    for b in range(len(poses)):
        outcome = task.outcome(times, positions[:, b], section, config.v_max_mps)
        outcomes.append({key: value for key, value in outcome.items() if key in _KEPT or _is_number(value)})
    return outcomes


def cell_chunks(config: TaskSweepConfig, starts: int) -> list[np.ndarray]:
    """The start indices of each chunk of a cell (chunk c draws its packet losses from seed c)."""
    return np.array_split(np.arange(starts), math.ceil(starts / config.chunk_starts))


def run_cell(
    config: TaskSweepConfig,
    topology: str,
    count: int,
    controller: str,
    loss: float,
    on_progress: Callable[[int], None] | None = None,
    starts: tuple[np.ndarray, np.ndarray | None] | None = None,
) -> dict:
    """Every start's ``outcome`` (the task's own) for one cell."""
    poses, adjacency = starts if starts is not None else cell_starts(config, topology, count)
    outcomes: list[dict] = []
    for loss_seed, chunk in enumerate(cell_chunks(config, len(poses))):
        chunk_adjacency = None if adjacency is None else adjacency[chunk]
        outcomes += chunk_outcomes(config, count, controller, loss, loss_seed, poses[chunk], chunk_adjacency)
        if on_progress is not None:
            on_progress(len(outcomes))
    return cell_record(topology, count, controller, loss, outcomes)


def cell_file_name(topology: str, count: int, controller: str, loss: float) -> str:
    """A cell's file below ``--out/cells`` (what ``--resume`` and the investigations look it up by)."""
    return f"{topology}-N{count}-{controller}-loss{loss:g}.json"


def cell_record(topology: str, count: int, controller: str, loss: float, outcomes: list[dict]) -> dict:
    """What a cell file holds; ``blas``: the kernel its matrix products ran on (:mod:`swarm.scenarios.blas`;
    cells written before 2026-12-07 lack it)."""
    return {
        "topology": topology,
        "robots": count,
        "controller": controller,
        "packet_loss": loss,
        "blas": blas_kernel(),
        "starts": outcomes,
    }


def other_kernels(out_dir: Path) -> dict[str, str]:
    """The cells below ``out_dir`` that ran on another BLAS kernel than this process: ``{file: kernel}``
    (a cell that records none is left out)."""
    here = blas_kernel()
    held = {
        path.name: json.loads(path.read_text()).get("blas") for path in sorted(out_dir.glob("cells/*.json"))
    }
    return {name: kernel for name, kernel in held.items() if kernel is not None and kernel != here}


def kernels_note(kernels: list[str | None]) -> str:
    """The tables' line on the BLAS kernels the cells ran on (how many cells each; None: not recorded)."""
    counts = Counter("not recorded" if kernel is None else kernel for kernel in kernels)
    listed = ", ".join(f"{kernel} ({number})" for kernel, number in sorted(counts.items()))
    return f"BLAS kernel of the cells' matrix products (cells): {listed}."


_KEPT = ("converged", "ratio_at_s")


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def column_value(outcome: dict, column: str) -> float | None:
    """One start's value of a column (``a.b``: key b of mapping a); None where the start has none."""
    value: Any = outcome
    for part in column.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return None if value is None else float(value)


def column_values(outcomes: list[dict], column: str) -> np.ndarray:
    """One column of the starts' outcomes (:func:`column_value`); starts without it left out."""
    values = [column_value(outcome, column) for outcome in outcomes]
    return np.asarray([value for value in values if value is not None], dtype=np.float64)


def summarize_cell(cell: dict, columns: tuple[str, ...]) -> dict:
    """The cell's row: success rate, then median, p95 and worst of each column over the starts."""
    outcomes = cell["starts"]
    row: dict = {key: cell[key] for key in ("topology", "robots", "controller", "packet_loss")}
    row["starts"] = len(outcomes)
    row["success_rate"] = float(np.mean([bool(o["converged"]) for o in outcomes]))
    for column in columns:
        values = column_values(outcomes, column)
        row[f"{column}.median"] = float(np.median(values)) if len(values) else None
        row[f"{column}.p95"] = float(np.percentile(values, 95)) if len(values) else None
        row[f"{column}.max"] = float(values.max()) if len(values) else None
        row[f"{column}.of"] = len(values)
    return row


# The lists that choose which cells run. A cell's starts, graphs and loss seeds depend on its own
# (topology, N, controller, loss) and the other settings only (cell_starts, run_cell), so sweeps that
# differ in these lists alone share every cell they both have.
CELL_LISTS = ("topologies", "sizes", "controllers", "packet_losses")


def reusable_cells(config: TaskSweepConfig, out_dir: Path) -> bool:
    """``out_dir`` holds cells of a sweep with this config but for the cells it chose (``--resume``):
    its ``sweep_config.json`` equals this one in every setting but :data:`CELL_LISTS`, so a cell file
    there is the cell this sweep would run."""
    path = out_dir / "sweep_config.json"
    if not path.is_file():
        return False
    current = json.loads(json.dumps(asdict(config)))
    defaults = json.loads(json.dumps(asdict(TaskSweepConfig(task=config.task))))
    stored = {**defaults, **json.loads(path.read_text())}  # a setting added since: its default
    return {k: v for k, v in stored.items() if k not in CELL_LISTS} == {
        k: v for k, v in current.items() if k not in CELL_LISTS
    }


def cell_names(config: TaskSweepConfig) -> dict[str, tuple[str, int, str, float]]:
    """Every cell of a sweep's lists: its file name -> ``(topology, N, controller, loss)``, the small
    swarms of every graph first (an interrupted sweep has whole tables for them); a central kind runs
    without loss only."""
    return {
        cell_file_name(topology, count, controller, loss): (topology, count, controller, loss)
        for loss in config.packet_losses
        for count in config.sizes
        for topology in config.topologies
        for controller in config.chosen_controllers
        if not (loss > 0 and controller_kind(controller).central)
    }


def run_task_sweep(
    config: TaskSweepConfig,
    out_dir: Path,
    progress: bool = True,
    resume: bool = False,
    workers: int = 1,
    tables_only: bool = False,
) -> list[dict]:
    """Run every cell, write ``sweep.csv``, ``sweep.md``, ``sweep.png`` and ``cells/``; the rows.
    ``resume``: a cell whose file ``out_dir`` already holds from a sweep of the same settings
    (:func:`reusable_cells`; other lists of graphs, sizes, controllers or losses allowed) is read, not
    run again; with other settings there, ScenarioError. ``tables_only``: ``resume`` that runs no cell:
    the tables of the cells of the lists that ``out_dir`` holds, with a line naming those it lacks
    (the caller compares the rows with :func:`cell_names`); ScenarioError (nothing written) where it
    holds none.
    ``workers`` > 1: the cells' chunks of starts run in that many processes (one numba thread each);
    every cell file is the same as with one."""
    if workers < 1:
        raise ScenarioError(f"workers: must be at least 1, not {workers}")
    resume = resume or tables_only
    flag = "--tables-only" if tables_only else "--resume"
    reuse = resume and reusable_cells(config, out_dir)
    if resume and not reuse:  # nothing there to read: refused where cells would be run over
        if (out_dir / "sweep_config.json").is_file():
            raise ScenarioError(
                f"{flag}: {out_dir / 'sweep_config.json'} has other settings than this sweep (only"
                " the topologies, sizes, controllers and packet losses may differ); give another --out"
            )
        held = sorted((out_dir / "cells").glob("*.json"))
        if held:  # cells whose settings nothing tells: neither read nor overwritten
            raise ScenarioError(
                f"{flag}: {out_dir / 'cells'} holds {len(held)} cell files (e.g. {held[0].name}) but there"
                f" is no {out_dir / 'sweep_config.json'} to tell their settings; copy the sweep_config.json"
                " of the sweep that wrote them beside cells/, or give another --out"
            )
        if tables_only:  # neither settings nor cells there
            raise ScenarioError(
                f"--tables-only: no {out_dir / 'sweep_config.json'}: no sweep's cells to read"
            )
    todo = cell_names(config)
    missing = [name for name in todo if not (out_dir / "cells" / name).is_file()] if reuse else []
    lacking = ""  # --tables-only with cells missing: the tables of the others, and a line naming those
    if tables_only and missing:
        if len(missing) == len(todo):
            raise ScenarioError(
                f"--tables-only: {out_dir / 'cells'} holds none of the {len(todo)} cells of these lists"
                f" ({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}); run them with --resume"
            )
        lacking = (
            f"Tables of {len(todo) - len(missing)} of the {len(todo)} cells of these lists; not run yet:"
            f" {', '.join(missing)} (`--resume` runs them)."
        )
        todo = {name: cell for name, cell in todo.items() if name not in missing}
    other = other_kernels(out_dir) if missing and not tables_only else {}
    if other:  # a learned kind's new cells would leave theirs by rounding: said, not refused
        elsewhere = sorted(set(other.values()))
        log.warning(
            "--resume: %d of the cells in %s ran on %s (e.g. %s), this process on %s: a learned"
            " kind's new cells differ from what that kernel gives by rounding; to match them set"
            " %s before the run where the CPU has it (swarm/scenarios/blas.py)",
            len(other),
            out_dir / "cells",
            " and ".join(elsewhere),
            next(iter(other)),
            blas_kernel(),
            coretype_setting(elsewhere[0]),
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "cells").mkdir(exist_ok=True)
    # drawn once, before any run: starts that cannot be drawn are bad input, refused before any work
    starts = (
        {}
        if tables_only
        else {(t, n): cell_starts(config, t, n) for t in config.topologies for n in config.sizes}
    )
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), unit="cell", desc=f"sweep {config.task}")
    rows: dict[str, dict] = {}  # by cell file name, in the order finished
    kernels: dict[str, str | None] = {}  # by cell file name: the BLAS kernel it ran on
    finished: tuple[str, dict] | None = None  # the cell whose file is being written

    def record(name: str, cell: dict) -> None:  # a written cell's row and kernel
        rows[name] = summarize_cell(cell, config.cells.columns)
        kernels[name] = cell.get("blas")

    def add(name: str, cell: dict, write: bool) -> None:
        nonlocal finished
        finished = (name, cell)
        if write:
            write_atomically(out_dir / "cells" / name, json.dumps(cell) + "\n")
        record(name, cell)
        finished = None
        if bar is not None:
            bar.update()

    def in_order() -> list[dict]:
        return [rows[name] for name in todo if name in rows]

    def kernels_line() -> str:
        held = kernels_note([kernels.get(name) for name in todo if name in rows])
        return f"{lacking} {held}" if lacking else held

    try:
        if workers > 1 and not tables_only:
            _run_in_workers(config, todo, starts, out_dir if reuse else None, workers, add, bar)
        for name, (topology, count, controller, loss) in todo.items():
            if name in rows:
                continue
            if reuse and (out_dir / "cells" / name).is_file():
                add(name, json.loads((out_dir / "cells" / name).read_text()), write=False)
                continue
            on_progress = None
            if bar is not None:
                bar.set_description(
                    f"{topology} N={count} {controller}" + (f" loss {loss:g}" if loss else "")
                )

                def on_progress(done: int, bar=bar) -> None:
                    bar.set_postfix_str(f"{done}/{config.seeds} starts")

            cell = run_cell(config, topology, count, controller, loss, on_progress, starts[topology, count])
            add(name, cell, write=True)
    except KeyboardInterrupt:  # keep what is done: the tables of the finished cells, then exit 130
        # a Ctrl-C between a cell's file and its row: the file is there, so is its row
        if finished is not None and finished[0] not in rows and (out_dir / "cells" / finished[0]).is_file():
            record(*finished)
        if rows:
            note = f"Interrupted after {len(rows)} of {len(todo)} cells. {kernels_line()}"
            write_tables(out_dir, config, in_order(), note=note)
        raise
    finally:
        if bar is not None:
            bar.close()
    ordered = in_order()
    write_tables(out_dir, config, ordered, note=kernels_line())
    plot_task_sweep(out_dir / "sweep.png", config, ordered)
    return ordered


def _worker_init() -> None:
    """A sweep worker: one numba thread (the processes share the cores); Ctrl-C is the parent's, which
    ends the pool."""
    import numba

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    numba.set_num_threads(1)


def _worker_chunk(job: tuple[str, int, tuple]) -> tuple[str, int, list[dict]]:
    name, index, args = job
    return name, index, chunk_outcomes(*args)


def _run_in_workers(
    config: TaskSweepConfig,
    todo: dict[str, tuple[str, int, str, float]],
    starts: dict[tuple[str, int], tuple[np.ndarray, np.ndarray | None]],
    reuse_dir: Path | None,
    workers: int,
    add: Callable[[str, dict, bool], None],
    bar: Any,
) -> None:
    """Every chunk of every cell still to run, over ``workers`` processes, the earlier cells' chunks
    first; a cell is added (its file written) when its last chunk is in. Cells whose file ``reuse_dir``
    holds are left to the caller."""
    from multiprocessing import get_context

    jobs: list[tuple[str, int, tuple]] = []
    parts: dict[str, list[list[dict] | None]] = {}
    for name, (topology, count, controller, loss) in todo.items():
        if reuse_dir is not None and (reuse_dir / "cells" / name).is_file():
            continue
        poses, adjacency = starts[topology, count]
        chunks = cell_chunks(config, len(poses))
        parts[name] = [None] * len(chunks)
        for index, chunk in enumerate(chunks):
            graph = None if adjacency is None else adjacency[chunk]
            jobs.append((name, index, (config, count, controller, loss, index, poses[chunk], graph)))
    if not jobs:
        return
    if bar is not None:
        bar.set_description(f"{len(parts)} cells in {workers} processes")
    # Ctrl-C is the parent's: the workers are born with SIGINT blocked (a process inherits its mask
    # across exec, so one still importing cannot print a traceback) and ignore it from their initializer;
    # one that lands while they start is held and delivered to this process after.
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pool = get_context("spawn").Pool(min(workers, len(jobs)), initializer=_worker_init)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
    began_s = time.monotonic()
    with pool:  # left by an exception (Ctrl-C included), the pool is terminated: no worker outlives it
        for done, (name, index, outcomes) in enumerate(pool.imap_unordered(_worker_chunk, jobs), 1):
            parts[name][index] = outcomes
            if bar is not None:  # the time left if the chunks still to run cost what the done ones did
                left_s = (time.monotonic() - began_s) / done * (len(jobs) - done)
                bar.set_postfix_str(f"{done}/{len(jobs)} chunks, about {bar.format_interval(left_s)} left")
            done_parts = [part for part in parts[name] if part is not None]
            if len(done_parts) == len(parts[name]):
                topology, count, controller, loss = todo[name]
                every = [outcome for part in done_parts for outcome in part]
                add(name, cell_record(topology, count, controller, loss, every), True)


def write_tables(out_dir: Path, config: TaskSweepConfig, rows: list[dict], note: str = "") -> None:
    with open(out_dir / "sweep.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (out_dir / "sweep_config.json").write_text(json.dumps(asdict(config), indent=2) + "\n")
    task = registry.get(config.task)

    def pair(row: dict, column: str) -> str:
        median, p95 = row[f"{column}.median"], row[f"{column}.p95"]
        if median is None:
            return "-"
        shown = f"{median:.3f} / {p95:.3f}"
        return shown if row[f"{column}.of"] == row["starts"] else f"{shown} ({row[f'{column}.of']})"

    columns = config.cells.columns
    header = "| topology | N | loss | controller | starts | success | " + " | ".join(columns) + " |"
    bound = "lower bound" if task.bound == "lower_bound" else "reference (not a bound)"
    lines = [
        f"Task {config.task} ({task.summary}): {config.seeds} starts per cell,"
        f" v_max {config.v_max_mps:g} m/s,"
        f" control period {config.control_period_s:g} s, at most {config.run_duration_s:g} s simulated,"
        f" kinematic engine; disk graphs of radius {config.disk_radius_m:g} m.",
        f"Metric: {task.metric}. Success: {task.success}. Compared with: the {bound}.",
        "Each column: median / p95 over the starts that have it (how many, where not all).",
        *([f"The learned kinds' policy: {config.model}."] if config.model else []),
        *([note] if note else []),
        "",
        header,
        "|" + "---|" * (header.count("|") - 1),
    ]
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['packet_loss']:.0%} | {row['controller']}"
            f" | {row['starts']} | {row['success_rate']:.0%} | "
            + " | ".join(pair(row, column) for column in columns)
            + " |"
        )
    (out_dir / "sweep.md").write_text("\n".join(lines) + "\n")


def plot_task_sweep(path: Path, config: TaskSweepConfig, rows: list[dict]) -> None:
    """The first column's median (marker) and p95 (bar top) against N, one panel per topology and
    packet loss, one line per controller."""
    from swarm.scenarios import plots

    column = config.cells.columns[0]
    panels = [(t, loss) for loss in config.packet_losses for t in config.topologies]
    panels = [
        (t, loss) for t, loss in panels if any(r["topology"] == t and r["packet_loss"] == loss for r in rows)
    ]
    fig, axes = plots.panel_grid(len(panels))
    controllers = config.chosen_controllers
    for ax, (topology, loss) in zip(axes, panels, strict=True):
        values = []
        for controller in controllers:
            mine = [
                r
                for r in rows
                if (r["topology"], r["packet_loss"], r["controller"]) == (topology, loss, controller)
                and r[f"{column}.median"] is not None
            ]
            if not mine:
                continue
            sizes = [r["robots"] for r in mine]
            median = np.array([r[f"{column}.median"] for r in mine])
            p95 = np.array([r[f"{column}.p95"] for r in mine])
            colour, marker, style = plots.controller_style(controller, controllers)
            ax.errorbar(
                sizes,
                median,
                yerr=[np.zeros_like(median), p95 - median],
                color=colour,
                marker=marker,
                linestyle=style,
                capsize=3,
                label=plots.controller_label(controller),
            )
            values += [*median, *p95]
        plots.ticks_at_sizes(ax, config.sizes)
        plots.fit_axis(ax, values, floor=1.0 if column.startswith("ratio") else None)
        ax.set_title(f"{topology}" + (f", {loss:.0%} loss" if loss else ""))
        ax.set_xlabel("robots N")
        ax.set_ylabel(f"{column} (median, p95)")
        ax.grid(alpha=0.3)
        if values:
            ax.legend(fontsize="small")
        else:  # every controller's column undefined here (no start has it): said, not left blank
            ax.text(0.5, 0.5, f"no start has {column}", transform=ax.transAxes, ha="center", va="center")
    fig.suptitle(f"swarm sweep --task {config.task}: {config.seeds} starts per cell")
    plots.save(fig, path)
