"""Which prediction horizon should ``lloyd_gnn``'s cell have? Chosen on starts the tables never use.

``lloyd_gnn`` reads ``lloyd_predict``'s cell: every known robot placed where its flooded target takes
it over at most ``horizon_ticks`` of its entry's age. Until 2026-12-06 that was ``lloyd_predict``'s 5
ticks, chosen on the coverage sweep's first 8 starts, where the kinds' medians are a second apart by
chance alone. Here the readout is trained as ``swarm train --algo coverage`` trains it (same settings
and seed) with each horizon asked, and every policy runs on **validation starts**: the coverage sweep's
starts drawn with ``seed`` 1 (the committed tables use seed 0), the same starts for every policy, 60 s.
The table compares the first policy with each other one start by start (``bench/task_paired.py``: the
difference of the medians of the time to 1.05 H_ref with its paired-bootstrap interval):

    python bench/investigations/coverage_gnn_horizon.py --horizons 3 5 --cells cycle:50 line:50 \\
        random:50 complete:50 --starts 300 --out bench/results/coverage_gnn_horizon

Cells already in ``--out/cells`` are read, not run again (the run is resumable); the policies are in
``--out/policies``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # bench/, for task_paired

import task_paired

import swarm.learn.train.coverage as coverage_training
from swarm.core.robot import RobotParams
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell
from swarm.sim.coverage_controllers import LloydGnn
from swarm.sim.coverage_gnn import CoverageGnnWeights

VALIDATION_SEED = 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--horizons", nargs="+", type=int, default=[3, 5], help="ticks; the first is compared with the others"
    )
    parser.add_argument("--cells", nargs="+", default=["cycle:50", "line:50", "random:50", "complete:50"])
    parser.add_argument("--starts", type=int, default=300, help="validation starts per cell")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if len(args.horizons) < 2:
        parser.error("--horizons: give at least two, the first is compared with the others")
    (args.out / "cells").mkdir(parents=True, exist_ok=True)
    (args.out / "sweep_config.json").write_text(json.dumps({"task": "coverage", "seed": VALIDATION_SEED}))
    kinds = {}
    for horizon in args.horizons:  # -- the policies: the shipped training, one horizon each
        policy = args.out / "policies" / f"h{horizon}" / "policy.npz"
        if not policy.is_file():
            config = replace(
                coverage_training.make_config(),
                out=str(policy.parent),
                horizon_ticks=horizon,
                progress=False,
            )
            began = time.perf_counter()
            coverage_training.train(config)
            print(f"trained {policy} in {time.perf_counter() - began:.0f} s", flush=True)
        kinds[f"gnn_h{horizon}"] = CoverageGnnWeights.load(policy)
    for spec in args.cells:  # -- every policy on the validation starts
        graph, count_text = spec.split(":")
        count = int(count_text)
        sweep = TaskSweepConfig(
            task="coverage",
            topologies=[graph],
            sizes=[count],
            seeds=args.starts,
            chunk_starts=args.starts,
            seed=VALIDATION_SEED,
        )
        starts = cell_starts(sweep, graph, count)
        section = sweep.cells.section(count)
        robot = RobotParams(v_max_mps=sweep.v_max_mps)
        for kind, weights in kinds.items():
            path = args.out / "cells" / f"{graph}-N{count}-{kind}-loss0.json"
            if path.is_file():
                continue
            began = time.perf_counter()
            controller = LloydGnn(robot, sweep.control_period_s, section, count, weights)
            cell = run_cell(sweep, graph, count, controller, 0.0, starts=starts) | {"controller": kind}
            path.write_text(json.dumps(cell) + "\n")
            print(f"{spec} {kind}: {time.perf_counter() - began:.0f} s", flush=True)
    first, *others = kinds
    table = args.out / "paired.md"
    paired = [str(args.out), "--kind", first, "--against", *others, "--column", "first_within_s"]
    code = task_paired.main([*paired, "--out", str(table)])
    if code == 0:  # which starts and policies, above the comparison's own header
        made = " ".join(["python bench/investigations/coverage_gnn_horizon.py", *(argv or sys.argv[1:])])
        note = (
            f"Made by `{made}`: `gnn_h<H>` is `lloyd_gnn` trained and run on an H-tick horizon"
            f" (policies in `{args.out / 'policies'}`), on validation starts (seed {VALIDATION_SEED}).\n\n"
        )
        table.write_text(note + table.read_text())
    return code


if __name__ == "__main__":
    sys.exit(main())
