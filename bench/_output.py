"""Where a benchmark writes its results, and its progress bar.

Every benchmark writes to ``--out DIR`` (default ``runs/bench/``, outside the tracked tree); the
committed result files (``bench/results/``, or the script's docs folder) are rewritten only with
``--update-results``. ``--quiet`` turns the progress bar off.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
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
