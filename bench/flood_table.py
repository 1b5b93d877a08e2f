"""The learned max-flooding GNN against the lower bound, the old shipped GNN and ``mec_flood``, per cell.

Reads the per-cell caches of ``swarm sweep`` (``--new-cells``: only the cells of the ``--model``
file, by its hash) or ``sweep.csv`` files and writes one markdown table: median and p95 ratio to
the lower bound, success, and the done-criteria of the learned model (median <= 1.12 at N = 6,
<= 1.06 at N = 24, <= 1.05 at N = 50 and 100; p95 <= 1.10 at N >= 24; 100% success; <= 1.10 under
50% loss), beside ``mec_flood``, the previous flooding model (``--previous-model``, its cells from
the same directories) and the old graph-filter GNN, and whether the model is at least as good as
each (median ratio no higher) on every cell both have. The command: ``docs/results/flood/evaluate.sh``.
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


def read_cells(directories: list[str], controller: str, model: str | None = None) -> dict[tuple, dict]:
    """Rows like ``sweep.csv``'s from the per-cell caches ``DIR/cells/*.npz`` (also of sweeps still
    running or stopped: every finished cell is there); with ``model``, only that policy file's cells."""
    import json

    import numpy as np

    from swarm.scenarios.sweep import file_hash

    tag = None if model is None else f"-{file_hash(model)[:12]}"
    rows = {}
    for directory in directories:
        for path in sorted(Path(directory).glob("cells/*.npz")):
            if tag is not None and tag not in path.stem:
                continue
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
    parser.add_argument("--model", required=True, help="the policy file whose cells are read")
    parser.add_argument("--previous-model", help="an earlier policy file (cells: the same dirs)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    new = {**read_cells(args.new_cells, "gnn", args.model), **read(args.new, "gnn")}
    before = read_cells(args.new_cells, "gnn", args.previous_model) if args.previous_model else {}
    old = read(args.old, "gnn")
    base = read(args.baselines, "mec_flood")
    keys = sorted(new, key=lambda k: (k[2], ORDER.index(k[0]) if k[0] in ORDER else 99, k[1]))
    lines = [
        f"Learned model: {args.model}. Ratio to the lower bound (median / p95) over the starts of each "
        "cell (1000 unless said), kinematic engine, the settings of `swarm sweep`. `meets`: the done-"
        "criteria of the learned model for that cell (median <= 1.12 at N = 6, <= 1.06 at N = 24, <= 1.05 "
        "at N = 50 and 100; p95 <= 1.10 at N >= 24; 100% success; <= 1.10 under 50% loss). `vs old`: "
        "median ratio of the new model minus the old shipped GNN's (negative: the new one is faster). "
        f"`previous`: the earlier flooding model `{args.previous_model}`; `vs mec`: median minus "
        "mec_flood's. Command: `docs/results/flood/evaluate.sh`.",
        "",
        "| graph | N | loss | starts | success | new median | new p95 | mec_flood median | mec_flood p95 "
        "| vs mec | previous median | old GNN median | vs old | meets |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    failures, losses, regressions, behind_mec = [], [], [], []
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
        earlier = number(before.get(key), "median_ratio_to_lower_bound")
        if earlier is not None and median is not None and median > earlier:
            regressions.append(f"{topology} N={count} loss={loss:g} (+{median - earlier:.4f})")
        mec_median = number(reference, "median_ratio_to_lower_bound")
        vs_mec = None if mec_median is None or median is None else median - mec_median
        if vs_mec is not None and vs_mec > 0:
            behind_mec.append(f"{topology} N={count} loss={loss:g} (+{vs_mec:.3f})")
        lines.append(
            f"| {topology} | {count} | {loss:.0%} | {row['starts']} | {success:.1%} "
            f"| {fmt(median)} | {fmt(p95)} "
            f"| {fmt(mec_median)} | {fmt(number(reference, 'p95_ratio_to_lower_bound'))} | {fmt(vs_mec)} "
            f"| {fmt(earlier)} | {fmt(old_median)} "
            f"| {fmt(delta)} | {('yes' if meets else 'NO') if checked else '-'} |"
        )
    lines += [
        "",
        f"Cells failing the done-criteria: {', '.join(failures) if failures else 'none'}.",
        "Cells where the new model is slower than the old graph filter (median): "
        f"{', '.join(losses) if losses else 'none'}.",
    ]
    if args.previous_model:
        lines.append(
            "Cells where it is slower than the previous flooding model (median): "
            f"{', '.join(regressions) if regressions else 'none'}."
        )
    lines.append(
        "Cells where it is slower than mec_flood (median): "
        f"{', '.join(behind_mec) if behind_mec else 'none'}."
    )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
