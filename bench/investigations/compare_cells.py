"""Per-start convergence times of the same cells in two sweep output directories, side by side.

Checks that a code change leaves a policy's results as they were (or says where and by how much
they moved): for every cell file name present in both ``DIR/cells/``, the number of starts whose
time differs, the largest difference and both medians of the ratio to the lower bound.

    python bench/investigations/compare_cells.py \\
        --before docs/results/flood/eval_a docs/results/flood/eval_b \\
        --after docs/results/flood/eval_recheck --out docs/results/flood/recheck.md
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
from pathlib import Path

import numpy as np


def cells(directories: list[str]) -> dict[str, Path]:
    return {
        path.name: path for directory in directories for path in sorted(Path(directory).glob("cells/*.npz"))
    }


def median_ratio(times: np.ndarray, lower: np.ndarray) -> float:
    ratio = times[lower > 0] / lower[lower > 0]
    return float(np.median(np.where(np.isnan(ratio), np.inf, ratio)))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", nargs="+", required=True, help="sweep output directories (their cells/)")
    parser.add_argument("--after", nargs="+", required=True, help="sweep output directories (their cells/)")
    parser.add_argument("--out", required=True, help="markdown file written")
    args = parser.parse_args(argv)
    before, after = cells(args.before), cells(args.after)
    common = sorted(set(before) & set(after))
    if not common:
        print(f"{args.after[0]}: no cell in common with {args.before[0]}")
        return 1
    lines = [
        f"Per-start times of the same cells: before = {' '.join(args.before)},",
        f"after = {' '.join(args.after)}.",
        "Command: `python bench/investigations/compare_cells.py` (its docstring).",
        "",
        "| cell | starts | starts that differ | largest difference (s) | median ratio before | after |",
        "|---|---|---|---|---|---|",
    ]
    for name in common:
        with np.load(before[name]) as old, np.load(after[name]) as new:
            t0, t1, lower = old["times_s"], new["times_s"], new["lower_bound_s"]
            np.testing.assert_array_equal(old["lower_bound_s"], lower)  # the same starts
            differ = ~((t0 == t1) | (np.isnan(t0) & np.isnan(t1)))
            largest = float(np.nanmax(np.abs(t1 - t0))) if differ.any() else 0.0
            lines.append(
                f"| {name[:-4]} | {len(t0)} | {int(differ.sum())} | {largest:.2f} "
                f"| {median_ratio(t0, lower):.4f} | {median_ratio(t1, lower):.4f} |"
            )
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
