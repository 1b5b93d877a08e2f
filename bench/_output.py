"""Where a benchmark writes its results, and its progress bar.

Every benchmark writes to ``--out DIR`` (default ``runs/bench/``, outside the tracked tree); the
committed result files (``bench/results/``, or the script's docs folder) are rewritten only with
``--update-results``. ``--quiet`` turns the progress bar off.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable, Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"
DEFAULT_OUT = ROOT / "runs" / "bench"


def add_output_arguments(parser: argparse.ArgumentParser, committed: Path = RESULTS) -> None:
    """``--out``, ``--update-results`` and ``--quiet``."""
    where = committed.relative_to(ROOT) if committed.is_relative_to(ROOT) else committed
    parser.add_argument(
        "--out", type=Path, help=f"output directory (default: {DEFAULT_OUT.relative_to(ROOT)}/)"
    )
    parser.add_argument(
        "--update-results",
        action="store_true",
        help=f"write into the committed results, {where}/, instead",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def output_dir(args: argparse.Namespace, committed: Path = RESULTS) -> Path:
    """The directory the benchmark writes to (created)."""
    if args.update_results and args.out is not None:
        raise SystemExit("error: give --out or --update-results, not both")
    out = committed if args.update_results else (args.out or DEFAULT_OUT)
    out.mkdir(parents=True, exist_ok=True)
    return out


def progress(iterable: Iterable, args: argparse.Namespace, **options):
    """``iterable`` with a tqdm bar, unless ``--quiet``."""
    from tqdm import tqdm

    return tqdm(iterable, disable=bool(getattr(args, "quiet", False)), **options)


def best_time_s(function: Callable[[], object], repeats: int) -> float:
    """Least wall time of ``repeats`` calls of ``function`` (one untimed call first, to compile)."""
    function()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def write_kernel_result(
    out_dir: Path,
    name: str,
    script: str,
    argv: list[str] | None,
    load_before: tuple[float, float, float],
    rows: list[dict],
    caption: str,
    columns: list[tuple[str, str]],
) -> int:
    """A kernel-against-reference benchmark's ``name.json`` and ``name.md``, the table printed.

    ``caption`` opens the Markdown; the load average (before, and now) and the script follow it, then
    the table, one line a row: ``columns`` are (header, format string of the row's keys), e.g.
    ``("N", "{robots}")``. Every row carries ``same_bits``: the exit code is 0 when every kernel gave
    its reference's bits, 1 otherwise.
    """
    script_name = Path(script).name
    load_after, cpus = os.getloadavg(), os.cpu_count()
    result = {
        "command": f"python bench/{script_name} " + " ".join(argv or []),
        "load_before": load_before,
        "load_after": load_after,
        "cpus": cpus,
        "rows": rows,
    }
    (out_dir / f"{name}.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        f"{caption} Load average {load_before[0]:.1f} before, {load_after[0]:.1f} after,"
        f" {cpus} CPUs. Written by `bench/{script_name}`.",
        "",
        "| " + " | ".join(head for head, _ in columns) + " |",
        "|" + "---|" * len(columns),
    ]
    lines += ["| " + " | ".join(cell.format(**row) for _, cell in columns) + " |" for row in rows]
    (out_dir / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if all(row["same_bits"] for row in rows) else 1
