"""The baseline tables: every controller as ratio to the lower bound, on the sweep's starts.

Runs (or reads from the cell caches) the cells of ``swarm.scenarios.sweep`` for ``mec_flood`` (reverse on and
off), ``centralized_mec``, the thesis's ``centralized`` expert and ``local_consensus`` on complete,
cycle, line, star, random and disk graphs at N = 6, 12, 24, 50, 100 (1000 starts each); under 20 %
and 50 % packet loss on cycles and lines at N = 24 and 100; and on the line whose indices follow
space (``line_sorted``). A policy file's cells (controller ``gnn``) are shown where a cache holds
them (``--model``; ``--run-model`` runs the missing ones). Writes ``baselines.md`` / ``.csv``, the
plot ``ratio_vs_n.png`` (median ratio against N per graph, one line per controller) and the
done-criteria check of ``mec_flood`` to ``--out``; each cell's per-start times to ``--out/cells``.

    nice -n 10 python bench/baselines.py --out docs/results/baselines \\
        --reuse docs/results/consensus_sweep docs/results/gnn_eval/default docs/results/gnn_eval/disk \\
        --model models/gnn_default.npz

Local consensus under packet loss runs the first ``--loss-consensus-starts`` (100) starts only: on a
line of 100 it needs hundreds of times the lower bound, and the faulty path is numpy, not numba.
Centralized controllers ignore links, so loss does not touch them (not run under loss).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from swarm.scenarios.sweep import SweepConfig, cached_cell, find_cached_cell, summarize_cell

BASELINES = ("mec_flood", "mec_flood_forward", "centralized_mec", "centralized", "local_consensus")
LABELS = {
    "gnn": "GNN (model)",
    "mec_flood": "mec_flood + reverse",
    "mec_flood_forward": "mec_flood, forward only",
    "centralized_mec": "centralized_mec",
    "centralized": "centralized (thesis eq. 3.1)",
    "local_consensus": "local consensus",
}
GRAPHS = ("complete", "cycle", "line", "star", "random", "disk", "line_sorted")
SIZES = (6, 12, 24, 50, 100)
LOSSES = (0.2, 0.5)
LOSS_GRAPHS, LOSS_SIZES = ("cycle", "line"), (24, 100)
CENTRAL = ("centralized_mec", "centralized")


def cells_to_run(args) -> list[tuple[str, int, float, str, int | None]]:
    """(graph, N, packet loss, controller, first starts or None), cheapest controllers first."""
    todo = []
    for controller in (*BASELINES, "gnn"):
        for graph in GRAPHS:
            for count in SIZES:
                todo.append((graph, count, 0.0, controller, None))
        if controller in CENTRAL:
            continue
        for loss in LOSSES:
            for graph in LOSS_GRAPHS:
                for count in LOSS_SIZES:
                    first = args.loss_consensus_starts if controller == "local_consensus" else None
                    todo.append((graph, count, loss, controller, first))
    return todo


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/baselines")
    parser.add_argument("--reuse", nargs="*", default=[], help="results directories whose cells are read")
    parser.add_argument("--model", help="policy file shown as controller gnn where its cells are cached")
    parser.add_argument("--run-model", action="store_true", help="run the model's missing cells too")
    parser.add_argument("--seeds", type=int, default=1000)
    parser.add_argument("--loss-consensus-starts", type=int, default=100)
    parser.add_argument("--only", nargs="*", help="run only these controllers (the tables read every cache)")
    parser.add_argument(
        "--graphs", nargs="*", help="run only cells on these graphs (the tables read every cache)"
    )
    parser.add_argument("--skip", nargs="*", default=[], help="do not run these GRAPH:N:CONTROLLER cells")
    parser.add_argument("--tables-only", action="store_true", help="write the tables from cached cells only")
    args = parser.parse_args(argv)
    out, reuse = Path(args.out), tuple(Path(d) for d in args.reuse)
    base = SweepConfig(seeds=args.seeds, model=args.model)
    cells = {}
    for graph, count, loss, controller, first in cells_to_run(args):
        if controller == "gnn" and args.model is None:
            continue
        config = replace(base, packet_loss=loss, first_starts=first)
        cell = find_cached_cell(out, config, graph, count, controller, reuse)
        if cell is None and first is not None:  # a full cell cut to the first starts
            full = find_cached_cell(out, replace(config, first_starts=None), graph, count, controller, reuse)
            if full is not None:
                cell = {k: v[:first] if isinstance(v, np.ndarray) and v.ndim else v for k, v in full.items()}
        runnable = not args.tables_only and (controller != "gnn" or args.run_model)
        runnable = runnable and (args.only is None or controller in args.only)
        runnable = runnable and (args.graphs is None or graph in args.graphs)
        runnable = runnable and f"{graph}:{count}:{controller}" not in args.skip
        if cell is None and runnable:
            print(f"running {graph} N={count} loss={loss:g} {controller}", file=sys.stderr, flush=True)
            cell = cached_cell(out, config, graph, count, controller, None, reuse)
        if cell is not None:
            cells[graph, count, loss, controller] = cell
    rows = [summarize_cell(cell) for cell in cells.values()]
    write_tables(out, rows, args)
    plot(out, rows)
    criteria = check_criteria(rows)
    (out / "criteria.json").write_text(json.dumps(criteria, indent=2) + "\n")
    print(json.dumps(criteria["summary"], indent=2))
    return 0


def _row(rows, graph, count, loss, controller):
    for row in rows:
        key = (row["topology"], row["robots"], row["packet_loss"], row["controller"])
        if key == (graph, count, loss, controller):
            return row
    return None


def write_tables(out: Path, rows: list[dict], args) -> None:
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "baselines.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    controllers = [c for c in ("gnn", *BASELINES) if any(r["controller"] == c for r in rows)]

    def cell_text(row: dict | None) -> str:
        if row is None or row["median_ratio_to_lower_bound"] is None:
            return "-"
        text = f"{row['median_ratio_to_lower_bound']:.3f} / {row['p95_ratio_to_lower_bound']:.3f}"
        if row["success_rate"] < 1.0:
            text += f" ({row['success_rate']:.1%} ok)"
        if row["starts"] != args.seeds:
            text += f" [{row['starts']}]"
        return text

    header = "| graph | N | loss | " + " | ".join(LABELS[c] for c in controllers) + " |"
    lines = [
        "Convergence time over the lower bound `max(0, R_mec - threshold/sqrt 3) / v_max`, median / p95",
        f"over {args.seeds} random starts per cell (`swarm.scenarios.sweep.cell_starts`, seed 0),"
        " kinematic engine,",
        "threshold 0.2 m held 5 s, v_max 0.5 m/s, control period 0.05 s. Every cell converged on 100 %",
        "of its starts unless marked `(x % ok)`; `[n]`: only the first n starts were run.",
        "Loss: probability that a message is lost (`packet_loss` on every link; lockstep timing: a lost",
        "message is not replaced by an older one); centralized controllers ignore links and are not run",
        "under loss. `line_sorted`: the line's starts with the robots numbered by increasing x, so the",
        "far end is N - 1 hops away in space too.",
        f"Command: `bench/baselines.py` (its docstring); model: `{args.model}`.",
        "",
        header,
        "|" + "---|" * (header.count("|") - 1),
    ]
    keys = sorted({(r["topology"], r["robots"], r["packet_loss"]) for r in rows}, key=_order)
    for graph, count, loss in keys:
        texts = [cell_text(_row(rows, graph, count, loss, c)) for c in controllers]
        lines.append(f"| {graph} | {count} | {loss:.0%} | " + " | ".join(texts) + " |")
    (out / "baselines.md").write_text("\n".join(lines) + "\n")


def _order(key):
    graph, count, loss = key
    return (loss, GRAPHS.index(graph), count)


def plot(out: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 4, figsize=(18, 8), dpi=100)
    for ax, graph in zip(axes.flat, GRAPHS, strict=False):
        for controller in ("gnn", *BASELINES):
            chosen = sorted(
                (
                    r
                    for r in rows
                    if r["topology"] == graph and r["controller"] == controller and r["packet_loss"] == 0
                ),
                key=lambda r: r["robots"],
            )
            if not chosen:
                continue
            sizes = [r["robots"] for r in chosen]
            ratio = [r["median_ratio_to_lower_bound"] or np.nan for r in chosen]
            ax.plot(sizes, ratio, marker="o", label=LABELS[controller])
        ax.set(xscale="log", yscale="log", xlabel="robots N", ylabel="median time / lower bound", title=graph)
        ax.axhline(1.0, color="grey", lw=1, ls="--")
        ax.grid(True, which="both", alpha=0.3)
    axes.flat[0].legend(fontsize=7)
    axes.flat[-1].axis("off")
    fig.tight_layout()
    fig.savefig(out / "ratio_vs_n.png")
    plt.close(fig)


def check_criteria(rows: list[dict]) -> dict:
    """The done-criteria of ``mec_flood`` with reversing: median <= 1.10 at N = 6, <= 1.045 at 24,
    <= 1.02 at 100 on every graph; 100 % success; 50 % loss within 0.01 of lossless at N = 100."""
    limits = {6: 1.10, 24: 1.045, 100: 1.02}
    checks = []
    for row in rows:
        if row["controller"] != "mec_flood":
            continue
        median = row["median_ratio_to_lower_bound"]
        where = f"{row['topology']} N={row['robots']} loss={row['packet_loss']:g}"
        checks.append(
            {"check": f"success {where}", "value": row["success_rate"], "ok": row["success_rate"] == 1.0}
        )
        if row["packet_loss"] == 0 and row["robots"] in limits:
            limit = limits[row["robots"]]
            checks.append({"check": f"median <= {limit} {where}", "value": median, "ok": median <= limit})
        if row["packet_loss"] == 0.5 and row["robots"] == 100:
            lossless = _row(rows, row["topology"], 100, 0.0, "mec_flood")
            if lossless is not None:
                gap = median - lossless["median_ratio_to_lower_bound"]
                checks.append(
                    {"check": f"50% loss - lossless <= 0.01 {where}", "value": gap, "ok": gap <= 0.01}
                )
    failed = [c for c in checks if not c["ok"]]
    return {
        "summary": {"checks": len(checks), "failed": [f"{c['check']}: {c['value']:.4f}" for c in failed]},
        "checks": checks,
    }


if __name__ == "__main__":
    sys.exit(main())
