"""Variants of the coverage controllers (another horizon, another policy file) on a sweep's own starts.

A task sweep keeps every start's outcome (``cells/*.json``), so a variant run on the same starts can be
compared with the committed kinds start by start (``bench/task_paired.py``). This runs each
``--kinds`` entry on the first ``--starts`` starts of a sweep's cell, in ``--workers`` processes, and
writes one cell file per kind into ``--out/cells``:

- ``NAME=lloyd_predict:H``: ``lloyd_predict`` with an ``H``-tick horizon (``horizon_ticks``);
- ``NAME=lloyd_predict:step=F``, ``NAME=lloyd_predict:H:step=F``, ``NAME=lloyd_flood:step=F``: the kind
  with a step fraction ``F`` (``step_fraction``: a fraction ``F`` of the way to its centroid a tick);
- ``NAME=lloyd_predict:age=K``: ``lloyd_predict`` with a step damped by the age of what the robot knows
  of its nearest robots (:class:`AgeDampedPredict`, an investigation only);
- ``NAME=gnn:PATH``: ``lloyd_gnn`` with the policy file ``PATH`` (on the horizon the file names);
- ``NAME=gnn:PATH:H``: that readout run on an ``H``-tick cell instead (a diagnosis: it was trained on
  its own);
- ``NAME=KIND``: a registered kind (``lloyd_predict``, ``lloyd_gnn``, ...) as the sweep runs it.

``--sweep DIR`` names the sweep whose starts are used (its ``sweep_config.json``: seed, starts per
cell, every setting) and whose cells are copied, cut to the first ``--starts``, for the kinds it has
(``--reference``); ``--seed 1`` instead draws other starts (validation starts, which no committed table
uses), and then every kind runs. ``--packet-loss p``: the sweep's cells of that loss (chunk c draws its
losses from seed c, as ``swarm sweep`` does, so a kind rerun here gives the sweep's outcomes). Cells
already in ``--out/cells`` are read, not run (resumable).
The comparison: each ``--reference`` kind against every kind after it, on ``first_within_s`` and
``ratio_at_s.10/20/40`` (``--out/paired-<column>.md``).

    python bench/investigations/coverage_variants.py --sweep docs/results/tasks/coverage-100-1000 \\
        --cells cycle:100 line:100 --starts 300 --reference lloyd_predict lloyd_gnn \\
        --kinds predict_h3=lloyd_predict:3 --out bench/results/coverage_variants_n100
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # bench/, for task_paired

import task_paired

from swarm.core.robot import RobotParams
from swarm.scenarios.task_sweep import (
    TaskSweepConfig,
    _worker_init,
    cell_chunks,
    cell_file_name,
    cell_record,
    cell_starts,
    chunk_outcomes,
)
from swarm.sim.coverage_controllers import LloydFlood, LloydGnn, LloydPredict
from swarm.sim.coverage_gnn import CoverageGnnWeights
from swarm.sim.coverage_onboard import HORIZON_TICKS

NEAREST_FOR_AGE = 6
"""``lloyd_predict:age=K``: how many of the nearest known robots' entry ages set a robot's gain (about a
Voronoi cell's neighbours in the plane)."""


class AgeDampedPredict(LloydPredict):
    """``lloyd_predict`` whose step toward its centroid ``c`` shrinks with what it knows of its nearest
    robots: target ``x + g (c - x)``, ``g = min(1, K / (1 + a))``, ``a`` the mean age in ticks of the
    entries of the ``NEAREST_FOR_AGE`` known robots nearest to it (at their predicted positions). An
    investigation only (not a kind): does a step damped by the age of what a robot knows stop the swings
    under loss (docs/tasks.md, "The starts that fail under loss")?"""

    def __init__(self, *args, age_gain: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.age_gain = float(age_gain)

    def act(self, poses, points, inbox, heard):
        batch, count = poses.shape[:2]
        memory = self.update_targets(poses, inbox, heard)
        known = memory[..., 0] > 0.0
        known[:, np.arange(count), np.arange(count)] = False
        gap_m = np.linalg.norm(self.known_positions(memory) - poses[:, :, None, :2], axis=-1)
        nearest = np.argsort(np.where(known, gap_m, np.inf), axis=-1, kind="stable")[..., :NEAREST_FOR_AGE]
        ages = np.take_along_axis(np.maximum(memory[..., 0] - 1.0, 0.0), nearest, axis=-1)
        counted = np.take_along_axis(known, nearest, axis=-1)
        mean_age = np.where(counted, ages, 0.0).sum(-1) / np.maximum(counted.sum(-1), 1)
        gain = np.minimum(1.0, self.age_gain / (1.0 + mean_age))
        targets = poses[..., :2] + gain[..., None] * (self._targets - poses[..., :2])
        return self.drive(poses, targets), memory.reshape(batch, count, self.fields * count)


COLUMNS = ("first_within_s", "ratio_at_s.10", "ratio_at_s.20", "ratio_at_s.40")


def build(spec: str, config: TaskSweepConfig, count: int):
    """The batched controller of a ``--kinds`` spec (a registered kind's name is passed through)."""
    kind, _, rest = spec.partition(":")
    if not rest:
        return kind
    section = config.cells.section(count)
    robot = RobotParams(v_max_mps=config.v_max_mps)
    parts = rest.split(":")
    steps = [float(part[5:]) for part in parts if part.startswith("step=")]
    step_fraction = steps[-1] if steps else 1.0
    ages = [float(part[4:]) for part in parts if part.startswith("age=")]
    parts = [part for part in parts if not part.startswith(("step=", "age="))]
    if kind == "lloyd_predict" and ages and not parts and not steps:
        return AgeDampedPredict(robot, config.control_period_s, section, count, age_gain=ages[-1])
    if kind == "lloyd_predict" and len(parts) <= 1:
        horizon = float(parts[0]) if parts else HORIZON_TICKS
        return LloydPredict(
            robot, config.control_period_s, section, count, horizon_ticks=horizon, step_fraction=step_fraction
        )
    if kind == "lloyd_flood" and not parts:
        return LloydFlood(robot, config.control_period_s, section, count, step_fraction=step_fraction)
    if kind == "gnn" and parts and not steps:
        path, horizon = parts[0], parts[1] if len(parts) > 1 else ""
        weights = CoverageGnnWeights.load(path)
        if horizon:
            weights = replace(weights, meta={**weights.meta, "horizon_ticks": float(horizon)})
        return LloydGnn(robot, config.control_period_s, section, count, weights)
    raise SystemExit(
        f"--kinds: {spec}: not lloyd_predict[:H][:step=F], lloyd_predict:age=K, lloyd_flood:step=F,"
        " gnn:PATH[:H] or a kind's name"
    )


def _chunk(job: tuple) -> tuple[Path, int, list[dict]]:
    path, index, spec, config, count, loss, poses, adjacency = job
    controller = build(spec, config, count)
    return path, index, chunk_outcomes(config, count, controller, loss, index, poses, adjacency)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=Path, required=True, help="a coverage sweep's --out: its starts")
    parser.add_argument("--cells", nargs="+", required=True, help="graph:N")
    parser.add_argument("--starts", type=int, default=300, help="the first this many starts of a cell")
    parser.add_argument("--seed", type=int, help="draw the starts with this seed instead of the sweep's")
    parser.add_argument(
        "--packet-loss",
        type=float,
        default=0.0,
        help="the cells' packet loss (chunk c draws it from seed c, as the sweep does)",
    )
    parser.add_argument("--reference", nargs="+", default=["lloyd_predict"], help="the sweep's kinds")
    parser.add_argument("--kinds", nargs="+", default=[], help="NAME=SPEC (module docstring)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    saved = json.loads((args.sweep / "sweep_config.json").read_text())
    known = {item.name for item in fields(TaskSweepConfig)}
    config = TaskSweepConfig.from_mapping({k: v for k, v in saved.items() if k in known}, str(args.sweep))
    reuse = args.seed is None or args.seed == config.seed
    if args.seed is not None:
        config = replace(config, seed=args.seed)
    if args.starts > config.seeds:
        parser.error(f"--starts: the sweep has {config.seeds} starts a cell")
    specs = {name: name for name in args.reference}
    for entry in args.kinds:
        name, equals, spec = entry.partition("=")
        if not equals:
            parser.error(f"--kinds: {entry}: give NAME=SPEC")
        specs[name] = spec
    cells_dir = args.out / "cells"
    cells_dir.mkdir(parents=True, exist_ok=True)
    (args.out / "sweep_config.json").write_text(json.dumps({"task": "coverage", "seed": config.seed}))
    jobs: list[tuple] = []
    parts: dict[Path, list[list[dict] | None]] = {}
    records: dict[Path, tuple[str, int, str]] = {}
    for cell_spec in args.cells:  # -- what to copy and what to run
        graph, count = cell_spec.split(":")[0], int(cell_spec.split(":")[1])
        poses, adjacency = cell_starts(config, graph, count)
        poses = poses[: args.starts]
        adjacency = None if adjacency is None else adjacency[: args.starts]
        for name, spec in specs.items():
            file_name = cell_file_name(graph, count, name, args.packet_loss)
            path = cells_dir / file_name
            if path.is_file():
                continue
            committed = args.sweep / "cells" / file_name
            if reuse and name == spec and committed.is_file():
                cell = json.loads(committed.read_text())
                path.write_text(json.dumps(cell | {"starts": cell["starts"][: args.starts]}) + "\n")
                continue
            chunks = cell_chunks(config, len(poses))
            parts[path] = [None] * len(chunks)
            records[path] = (graph, count, name)
            for index, chunk in enumerate(chunks):
                graph_chunk = None if adjacency is None else adjacency[chunk]
                jobs.append((path, index, spec, config, count, args.packet_loss, poses[chunk], graph_chunk))
    if jobs:  # -- the runs, chunk by chunk; a cell's file when its last chunk is in
        from multiprocessing import get_context

        began = time.monotonic()
        with get_context("spawn").Pool(min(args.workers, len(jobs)), initializer=_worker_init) as pool:
            for done, (path, index, outcomes) in enumerate(pool.imap_unordered(_chunk, jobs), 1):
                parts[path][index] = outcomes
                left_s = (time.monotonic() - began) / done * (len(jobs) - done)
                print(f"{done}/{len(jobs)} chunks, about {left_s / 60:.0f} min left", flush=True)
                if all(part is not None for part in parts[path]):
                    graph, count, name = records[path]
                    every = [outcome for part in parts[path] if part is not None for outcome in part]
                    cell = cell_record(graph, count, name, args.packet_loss, every)
                    path.write_text(json.dumps(cell) + "\n")
    made = " ".join(["python bench/investigations/coverage_variants.py", *(argv or sys.argv[1:])])
    note = (
        f"Made by `{made}`: the first {args.starts} starts a cell, seed {config.seed}; kinds {specs};"
        " with every other cell of these kinds that the folder holds (earlier runs into the same --out)."
    )
    for column in COLUMNS:  # -- the comparison: each reference kind against every later kind
        table = args.out / f"paired-{column}.md"
        parts_text = [note]
        for place, first in enumerate(args.reference):
            others = list(specs)[place + 1 :]
            if not others:
                continue
            part = args.out / f".paired-{column}-{first}.md"
            code = task_paired.main(
                [str(args.out), "--kind", first, "--against", *others, "--column", column, "--out", str(part)]
            )
            if code != 0:
                return code
            parts_text.append(part.read_text())
            part.unlink()
        table.write_text("\n\n".join(parts_text))
    medians = {
        path.stem: float(np.median(task_paired.start_values(json.loads(path.read_text()), "first_within_s")))
        for path in sorted(cells_dir.glob("*.json"))
    }
    print(json.dumps(medians, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
