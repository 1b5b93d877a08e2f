"""The learned max-flooding GNN against the lower bound, the old shipped GNN and ``mec_flood``, per cell.

Reads ``sweep.csv`` files (``swarm sweep`` / ``swarm evaluate`` outputs) and writes one markdown
table: median and p95 ratio to the lower bound, success, and the done-criteria of the learned
model (median <= 1.12 at N = 6, <= 1.06 at N = 24, <= 1.05 at N = 50 and 100; p95 <= 1.10 at
N >= 24; 100% success; <= 1.10 under 50% loss), plus whether the new model is at least as good as
the old one (median ratio no higher) on every cell both have.

    python bench/flood_table.py \
        --new docs/results/flood/eval/sweep.csv docs/results/flood/eval_loss50/sweep.csv \
        --old docs/results/gnn_eval/default/evaluation.csv docs/results/gnn_eval/disk/evaluation.csv \
        --baselines docs/results/baselines/sweep.csv --out docs/results/flood/comparison.md
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

MEDIAN_TARGET = {6: 1.12, 24: 1.06, 50: 1.05, 100: 1.05}
P95_TARGET = 1.10
LOSS_TARGET = 1.10
ORDER = ("complete", "cycle", "line", "star", "random", "disk", "line_sorted")


def read(paths: list[str], controller: str | None = None) -> dict[tuple, dict]:
    rows = {}
    for path in paths:
        if not Path(path).is_file():
            continue
        with open(path) as file:
            for row in csv.DictReader(file):
                if controller is not None and row["controller"] != controller:
                    continue
                loss = float(row.get("packet_loss") or 0.0)
                rows[row["topology"], int(row["robots"]), loss, row["controller"]] = row
    return rows


def read_cells(directories: list[str], controller: str) -> dict[tuple, dict]:
    """Rows like ``sweep.csv``'s from the per-cell caches ``DIR/cells/*.npz`` (also of sweeps still
    running or stopped: every finished cell is there)."""
    import json

    import numpy as np

    rows = {}
    for directory in directories:
        for path in sorted(Path(directory).glob("cells/*.npz")):
            name = path.stem.split("-")[0]
            topology, count, kind = (
                name.rsplit("_", 2)[0],
                int(name.rsplit("_", 2)[1]),
                name.rsplit("_", 2)[2],
            )
            if not name.endswith(controller) or "_first" in path.stem:
                continue
            with np.load(path) as cell:
                times, lower = cell["times_s"], cell["lower_bound_s"]
                loss = float(json.loads(str(cell["settings"])).get("packet_loss", 0.0))
            ratio = times[lower > 0] / lower[lower > 0]
            ratio = ratio[~np.isnan(ratio)]
            rows[topology, count, loss, controller] = {
                "starts": len(times),
                "success_rate": float(np.mean(~np.isnan(times))),
                "median_ratio_to_lower_bound": float(np.median(ratio)) if len(ratio) else None,
                "p95_ratio_to_lower_bound": float(np.percentile(ratio, 95)) if len(ratio) else None,
            }
            del kind
    return rows


def number(row: dict | None, key: str) -> float | None:
    if row is None or row.get(key) in (None, ""):
        return None
    return float(row[key])


def fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--new", nargs="*", default=[], help="sweep.csv files with the new model (gnn)")
    parser.add_argument("--new-cells", nargs="*", default=[], help="sweep output directories (their cells/)")
    parser.add_argument("--old", nargs="*", default=[], help="csv files with the old model (gnn)")
    parser.add_argument("--baselines", nargs="*", default=[], help="csv files with mec_flood")
    parser.add_argument("--model", default="the new model")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    new = {**read_cells(args.new_cells, "gnn"), **read(args.new, "gnn")}
    old = read(args.old, "gnn")
    base = read(args.baselines, "mec_flood")
    keys = sorted(new, key=lambda k: (k[2], ORDER.index(k[0]) if k[0] in ORDER else 99, k[1]))
    lines = [
        f"Learned model: {args.model}. Ratio to the lower bound (median / p95) over the starts of each "
        "cell (1000 unless said), kinematic engine, the settings of `swarm sweep`. `meets`: the done-"
        "criteria of the learned model for that cell (median <= 1.12 at N = 6, <= 1.06 at N = 24, <= 1.05 "
        "at N = 50 and 100; p95 <= 1.10 at N >= 24; 100% success; <= 1.10 under 50% loss). `vs old`: "
        "median ratio of the new model minus the old shipped GNN's (negative: the new one is faster).",
        "",
        "| graph | N | loss | starts | success | new median | new p95 | mec_flood median | mec_flood p95 "
        "| old GNN median | vs old | meets |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    failures, losses = [], []
    for key in keys:
        topology, count, loss, _ = key
        row = new[key]
        median, p95 = number(row, "median_ratio_to_lower_bound"), number(row, "p95_ratio_to_lower_bound")
        success = float(row["success_rate"])
        reference = base.get((topology, count, loss, "mec_flood"))
        previous = old.get((topology, count, loss, "gnn")) if loss == 0 else None
        old_median = number(previous, "median_ratio_to_lower_bound")
        delta = None if old_median is None or median is None else median - old_median
        meets = success == 1.0 and median is not None
        if loss == 0 and count in MEDIAN_TARGET:
            meets = meets and median <= MEDIAN_TARGET[count]
        if loss == 0 and count >= 24 and p95 is not None:
            meets = meets and p95 <= P95_TARGET
        if loss >= 0.5:
            meets = meets and median <= LOSS_TARGET
        checked = loss >= 0.5 or (loss == 0 and count in MEDIAN_TARGET)
        if checked and not meets:
            failures.append(f"{topology} N={count} loss={loss:g}")
        if delta is not None and delta > 0:
            losses.append(f"{topology} N={count} (+{delta:.3f})")
        lines.append(
            f"| {topology} | {count} | {loss:.0%} | {row['starts']} | {success:.1%} "
            f"| {fmt(median)} | {fmt(p95)} "
            f"| {fmt(number(reference, 'median_ratio_to_lower_bound'))} "
            f"| {fmt(number(reference, 'p95_ratio_to_lower_bound'))} | {fmt(old_median)} "
            f"| {fmt(delta)} | {('yes' if meets else 'NO') if checked else '-'} |"
        )
    lines += [
        "",
        f"Cells failing the done-criteria: {', '.join(failures) if failures else 'none'}.",
        "Cells where the new model is slower than the old (median): "
        f"{', '.join(losses) if losses else 'none'}.",
    ]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
