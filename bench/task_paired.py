"""Paired comparison of one controller against others on a task sweep's cells: the same starts.

``swarm sweep --task`` runs every controller of a cell on the same seeded starts and keeps every
start's outcome (``cells/*.json``). Medians of two columns of a table are two samples' medians; this
compares the controllers start by start and says whether a difference of medians is more than the
starts' noise:

- per start: the share of starts where ``--kind`` is faster (lower), equal and slower, and the median
  of the per-start ratio;
- the difference of the medians (``--kind`` minus the other) and its 95% interval from a paired
  bootstrap over the starts (``--resamples`` resamples of the start indices, seeded ``--seed``: the
  same starts drawn for both controllers, so the pairing is kept).

A start where a controller never got there (the column is missing: e.g. ``first_within_s`` of a start
that never came within 1.05 H_ref) counts as slower than every time.

    python bench/task_paired.py docs/results/tasks/coverage-1000-50 --kind lloyd_gnn \\
        --against lloyd_flood lloyd_predict --column first_within_s \\
        --out docs/results/tasks/coverage-1000-50/paired.md

With ``--out``, a plot beside the table (``paired.png``): one row per cell, each difference of the
medians as a point with its interval, one colour per controller compared against, a line at 0 (left
of it ``--kind`` is faster); a difference that is undefined (a median that never got there) is named at
the row's right instead of drawn.

The column defaults to the task's first in ``sweep.md`` (coverage ``ratio_at_s.5``, formation
``ratio_to_lower_bound``); ``a.b`` is key ``b`` of mapping ``a`` (``ratio_at_s.20``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from swarm.core.tasks import registry
from swarm.scenarios.task_sweep import column_value

EXIT_BAD_INPUT = 2


def start_values(cell: dict, column: str) -> np.ndarray:
    """``(starts,)`` the column of every start of a cell file, ``inf`` where a start has none."""
    values = [column_value(outcome, column) for outcome in cell["starts"]]
    return np.asarray([np.inf if value is None else value for value in values])


def paired_row(mine: np.ndarray, other: np.ndarray, resamples: int, seed: int) -> dict:
    """One comparison: per-start shares, the medians and the bootstrap interval of their difference."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(mine), size=(resamples, len(mine)))
    differences = np.median(mine[picks], axis=1) - np.median(other[picks], axis=1)
    finite = np.isfinite(mine) & np.isfinite(other)
    ratio = np.median(mine[finite] / other[finite]) if finite.any() else float("nan")
    low, high = np.percentile(differences, [2.5, 97.5]) if np.all(np.isfinite(differences)) else (np.nan,) * 2
    return {
        "starts": len(mine),
        "median": float(np.median(mine)),
        "other_median": float(np.median(other)),
        "difference": float(np.median(mine) - np.median(other)),
        "low": float(low),
        "high": float(high),
        "faster": float(np.mean(mine < other)),
        "equal": float(np.mean(mine == other)),
        "slower": float(np.mean(mine > other)),
        "ratio": float(ratio),
    }


def compare(
    cells_dir: Path, kind: str, against: list[str], column: str, resamples: int, seed: int
) -> list[dict]:
    """Every (topology, N, loss) of ``cells_dir`` that has ``kind`` and some of ``against``, ordered by
    topology name, then N and loss as numbers (not as the file names sort: 100 before 12)."""
    rows = []
    for path in sorted(cells_dir.glob(f"*-{kind}-loss*.json")):
        cell = json.loads(path.read_text())
        mine = start_values(cell, column)
        for other_kind in against:
            other_path = path.with_name(path.name.replace(f"-{kind}-loss", f"-{other_kind}-loss"))
            if not other_path.is_file():
                continue
            other = start_values(json.loads(other_path.read_text()), column)
            if len(other) != len(mine):
                raise ValueError(f"{other_path}: {len(other)} starts, {path.name} has {len(mine)}")
            row = {key: cell[key] for key in ("topology", "robots", "packet_loss")}
            rows.append({**row, "against": other_kind, **paired_row(mine, other, resamples, seed)})
    return sorted(rows, key=lambda row: (row["topology"], row["robots"], row["packet_loss"]))


def _number(value: float, form: str) -> str:
    """``value`` as ``form``; ``never`` for a median over starts most of which never got there (inf), and
    ``-`` for what is then undefined (a difference or interval from an infinite median, a ratio of no
    start where both got there)."""
    if value == np.inf:
        return "never"
    return format(value, form) if np.isfinite(value) else "-"


def _interval(row: dict) -> str:
    """The difference of the medians and its interval, or ``-`` where a median is infinite."""
    if not np.isfinite(row["difference"]):
        return "-"
    return f"{row['difference']:+.3f} [{_number(row['low'], '+.3f')}, {_number(row['high'], '+.3f')}]"


def _undefined(rows: list[dict]) -> bool:
    """Whether some row shows ``never`` or ``-`` (the caption then says how they read)."""
    keys = ("median", "other_median", "low", "high", "ratio")
    return any(not np.isfinite(row[key]) for row in rows for key in keys)


def table(rows: list[dict], kind: str, column: str, command: str, resamples: int) -> str:
    lines = [
        f"# `{kind}` against other controllers, start by start: `{column}`",
        "",
        f"`{command}`",
        "",
        f"Lower is better. Difference of the medians (`{kind}` minus the other) with its 95% interval from"
        f" a paired bootstrap over the starts ({resamples} resamples); the shares of starts where `{kind}`"
        " is faster / equal / slower; the median of the per-start ratio (starts where both got there)."
        + (" `never`: most starts never got there; `-`: undefined then." if _undefined(rows) else ""),
        "",
        f"| graph | N | loss | against | starts | `{kind}` median | other median | difference [95%] |"
        " faster / equal / slower | per-start ratio |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['topology']} | {row['robots']} | {row['packet_loss']:.0%} | `{row['against']}` |"
            f" {row['starts']} | {_number(row['median'], '.3f')} | {_number(row['other_median'], '.3f')} |"
            f" {_interval(row)} |"
            f" {row['faster']:.0%} / {row['equal']:.0%} / {row['slower']:.0%} |"
            f" {_number(row['ratio'], '.3f')} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], kind: str, column: str, path: Path) -> int:
    """A forest plot of ``rows`` at ``path`` (module docstring); the number of differences drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = list(dict.fromkeys((row["topology"], row["robots"], row["packet_loss"]) for row in rows))
    against = list(dict.fromkeys(row["against"] for row in rows))
    figure, axes = plt.subplots(figsize=(7.0, 1.2 + 0.32 * len(cells)))
    offset = {
        other: 0.25 * (j - (len(against) - 1) / 2) / max(1, len(against) - 1)
        for j, other in enumerate(against)
    }
    place = {cell: at for at, cell in enumerate(cells)}
    drawn = 0
    labelled: set[str] = set()
    for row in rows:
        other = row["against"]
        colour = f"C{against.index(other)}"
        at = place[row["topology"], row["robots"], row["packet_loss"]] + offset[other]
        note = ""
        if not np.isfinite(row["difference"]):  # a median that never got there
            note = f"{other}: never got there"
        else:
            bounded = np.isfinite(row["low"]) and np.isfinite(row["high"])
            spread = (
                [[row["difference"] - row["low"]], [row["high"] - row["difference"]]] if bounded else None
            )
            axes.errorbar(
                [row["difference"]],
                [at],
                xerr=spread,
                fmt="o",
                ms=4,
                capsize=2,
                color=colour,
                label=f"against {other}" if other not in labelled else None,
            )
            labelled.add(other)
            drawn += 1
            note = "" if bounded else f"{other}: no interval"
        if note:
            axes.annotate(
                note,
                (1.01, at),
                xycoords=("axes fraction", "data"),
                ha="left",
                va="center",
                fontsize=7,
                color=colour,
            )
    axes.axvline(0.0, color="0.4", lw=0.8)
    axes.set_yticks(
        range(len(cells)), [f"{g} N={n}" + (f" loss {loss:.0%}" if loss else "") for g, n, loss in cells]
    )
    axes.invert_yaxis()
    axes.set_xlabel(
        f"difference of the medians of {column}, {kind} minus the other"
        f"\n(95% paired bootstrap; left of 0: {kind} lower)"
    )
    if labelled:
        axes.legend(
            fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(labelled), frameon=False
        )
    axes.grid(axis="x", alpha=0.3)
    figure.savefig(path, dpi=120, bbox_inches="tight")  # the notes right of the axes included
    plt.close(figure)
    return drawn


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweep", type=Path, help="a task sweep's --out (its cells/ and sweep_config.json)")
    parser.add_argument("--kind", required=True, help="the controller compared")
    parser.add_argument("--against", nargs="+", required=True, help="the controllers it is compared with")
    parser.add_argument("--column", help="the outcome compared (default: the task's first column)")
    parser.add_argument("--resamples", type=int, default=4000, help="bootstrap resamples (default 4000)")
    parser.add_argument("--seed", type=int, default=0, help="the bootstrap's seed (default 0)")
    parser.add_argument(
        "--out",
        type=Path,
        help="write the table here and its plot beside it, .png (default: print the table)",
    )
    args = parser.parse_args(argv)
    config_path = args.sweep / "sweep_config.json"
    if not config_path.is_file() or not (args.sweep / "cells").is_dir():
        print(
            f"task_paired: {args.sweep}: not a task sweep's --out (no sweep_config.json or cells/)",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    task = json.loads(config_path.read_text()).get("task")
    if task not in registry.names() or registry.get(task).sweep is None:
        print(f"task_paired: {config_path}: task: '{task}' is not a swept task", file=sys.stderr)
        return EXIT_BAD_INPUT
    sweep = registry.get(task).sweep
    assert sweep is not None
    column = args.column or sweep.columns[0]
    try:
        rows = compare(args.sweep / "cells", args.kind, args.against, column, args.resamples, args.seed)
    except ValueError as error:
        print(f"task_paired: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not rows:
        print(
            f"task_paired: {args.sweep / 'cells'}: no cell of {args.kind} beside {' '.join(args.against)}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    command = "python bench/task_paired.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = table(rows, args.kind, column, command, args.resamples)
    if args.out:
        args.out.write_text(text)
        figure = args.out.with_suffix(".png")
        plot(rows, args.kind, column, figure)
        print(f"task_paired: {len(rows)} comparisons in {args.out}, plotted in {figure}")
    else:
        print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
