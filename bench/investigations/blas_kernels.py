"""A committed task-sweep cell rerun on each of several OpenBLAS kernels, compared start by start.

numpy's matrix products go to OpenBLAS, which picks its kernels by CPU: the AVX2 ones (``Haswell``; AMD's
``Zen`` are the same code) on most x86-64 machines, the AVX-512 ones (``SkylakeX``) on newer Xeons. The
two round some small products differently (a (B N, 32) x (32, 3) layer of a learned readout, for
one), so a learned kind's trajectory on one kernel leaves the other's by about 1e-10 m within seconds.
This says what that does to a cell: each ``--cells`` entry ``topology:N:controller`` of ``--sweep``'s
loss-free cells is rerun on its first ``--starts`` starts (the sweep's chunks, so the products have
the sweep's shapes), once per ``--kernels`` entry, each in a child process started with
``OPENBLAS_CORETYPE`` set (OpenBLAS reads it when numpy loads it), and compared with the committed
file: starts whose every number is the same, and the cell's row (median / p95 of each column, with how
many starts moved in it and by how much at most; success) per kernel beside the committed one.

    python bench/investigations/blas_kernels.py --sweep docs/results/tasks/coverage-1000-12 \\
        --cells cycle:12:lloyd_gnn --starts 1000 --kernels Haswell SkylakeX \\
        --out bench/results/blas_kernels_coverage.md

A kernel the CPU lacks (``SkylakeX`` without AVX-512) stops the child with an illegal instruction:
run it where the CPU has it. Exit 0 when every rerun is done (whatever it found), 2 on bad input.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def child(sweep: Path, cell: str, starts: int, out: Path) -> None:
    """Run the cell's first ``starts`` starts in the sweep's chunks; write their outcomes to ``out``."""
    from swarm.scenarios import task_sweep

    config = task_sweep.TaskSweepConfig.from_mapping(json.loads((sweep / "sweep_config.json").read_text()))
    topology, count, controller = cell.split(":")
    poses, adjacency = task_sweep.cell_starts(config, topology, int(count))
    outcomes: list[dict] = []
    for index, chunk in enumerate(task_sweep.cell_chunks(config, len(poses))):
        if len(outcomes) >= starts:
            break
        graph = None if adjacency is None else adjacency[chunk]
        outcomes += task_sweep.chunk_outcomes(config, int(count), controller, 0.0, index, poses[chunk], graph)
    out.write_text(json.dumps(outcomes[:starts]) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweep", type=Path, required=True, help="a task sweep's --out (its cells/)")
    parser.add_argument("--cells", nargs="+", required=True, help="topology:N:controller (loss 0)")
    parser.add_argument("--starts", type=int, default=200, help="the cell's first starts (whole chunks)")
    parser.add_argument(
        "--kernels", nargs="+", default=["Haswell", "SkylakeX"], help="OPENBLAS_CORETYPE values"
    )
    parser.add_argument("--out", type=Path, required=True, help="markdown file written")
    parser.add_argument("--child", nargs=2, metavar=("CELL", "JSON"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args.sweep, args.child[0], args.starts, Path(args.child[1]))
        return 0

    from swarm.scenarios import task_sweep

    if not (args.sweep / "sweep_config.json").is_file():
        parser.error(f"--sweep {args.sweep}: no sweep_config.json there")
    config = task_sweep.TaskSweepConfig.from_mapping(
        json.loads((args.sweep / "sweep_config.json").read_text())
    )
    columns = config.cells.columns
    lines = [
        f"Committed cells of `{args.sweep}` rerun on OpenBLAS kernels (`OPENBLAS_CORETYPE`), first"
        f" {args.starts} starts each. Written by `python bench/investigations/blas_kernels.py"
        f" {' '.join(argv if argv is not None else sys.argv[1:])}`.",
        "",
        "| cell | kernel | starts with every number the same | "
        + " | ".join(f"{column}, median / p95" for column in columns)
        + " | success |",
        "|---|---|---|" + "---|" * len(columns) + "---|",
    ]
    for cell in args.cells:
        parts = cell.split(":")
        if len(parts) != 3 or not parts[1].isdigit():
            parser.error(f"--cells {cell!r}: want topology:N:controller")
        topology, count, controller = parts[0], int(parts[1]), parts[2]
        path = args.sweep / "cells" / task_sweep.cell_file_name(topology, count, controller, 0.0)
        if not path.is_file():
            parser.error(f"--cells {cell!r}: {path} does not exist")
        committed = json.loads(path.read_text())["starts"][: args.starts]

        def row(name: str, outcomes: list[dict], same: str, moved: dict[str, str], cell=cell) -> str:
            topology, count, controller = cell.split(":")
            record = task_sweep.cell_record(topology, int(count), controller, 0.0, outcomes)
            summary = task_sweep.summarize_cell(record, columns)
            values = []
            for column in columns:
                of = summary[column + ".of"]
                text = f"{summary[column + '.median']:.4g} / {summary[column + '.p95']:.4g}" if of else "-"
                text += "" if of == len(outcomes) else f" ({of})"
                values.append(text + moved.get(column, ""))
            success = f"{round(summary['success_rate'] * len(outcomes))} of {len(outcomes)}"
            return f"| {cell} | {name} | {same} | " + " | ".join(values) + f" | {success} |"

        lines.append(row("committed", committed, "-", {}))
        for kernel in args.kernels:
            with tempfile.TemporaryDirectory() as scratch:
                result = Path(scratch) / "outcomes.json"
                command = [sys.executable, __file__, "--sweep", str(args.sweep), "--starts", str(args.starts)]
                command += ["--cells", cell, "--out", str(args.out), "--child", cell, str(result)]
                environment = os.environ | {"OPENBLAS_CORETYPE": kernel}
                done = subprocess.run(command, env=environment, check=False)
                if done.returncode != 0:
                    lines.append(
                        f"| {cell} | {kernel} | failed (exit {done.returncode}) |" + " |" * (len(columns) + 1)
                    )
                    continue
                rerun = json.loads(result.read_text())
            rerun = json.loads(json.dumps(rerun))  # the file's floats, as the committed cell holds them
            same = sum(a == b for a, b in zip(rerun, committed, strict=True))
            moved = {}
            for column in columns:
                pairs = [
                    (task_sweep.column_value(a, column), task_sweep.column_value(b, column))
                    for a, b in zip(rerun, committed, strict=True)
                ]
                differ = [(a, b) for a, b in pairs if a != b]
                largest = max((abs(a - b) for a, b in differ if a is not None and b is not None), default=0.0)
                moved[column] = (
                    f" ({len(differ)} moved, at most {largest:.2g})" if differ else " (none moved)"
                )
            lines.append(row(kernel, rerun, f"{same} of {len(committed)}", moved))
            print(lines[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
