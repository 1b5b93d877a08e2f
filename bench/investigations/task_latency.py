"""Is a flood baseline's gap to its central expert the flood's latency? Measured by shortening it.

On sparse graphs the decentralized baselines trail their central experts: formation's ``capt_flood``
on the line of 50 takes a median 1.14x the lower bound against ``capt``'s 1.03x
(``docs/results/tasks/formation-1000-50``), coverage's ``lloyd_flood`` on the line of 100 reaches
1.05 H_ref in 43 s against ``lloyd``'s 17 s (``docs/results/tasks/coverage``). A robot hears of the
farthest one only after the graph's diameter in ticks (49 and 99 ticks, 2.45 s and 4.95 s). This runs
the baseline on the task sweep's starts of a graph and on its h-th powers (every robot also hears the
robots within h hops: the same flood, ``h`` hops a tick, diameter ``ceil(D / h)``), up to the complete
graph, against the expert on the same starts. If the gap closes as the diameter shrinks, and nothing
else changes between the runs, it is the latency.

    python bench/investigations/task_latency.py --task formation --out bench/results/formation_latency.md
    python bench/investigations/task_latency.py --task coverage --out bench/results/coverage_latency.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarm.core.tasks import registry
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell

HOPS = (1, 2, 3, 5, 10, 25, 49, 99)


@dataclass(frozen=True)
class Measured:
    """What one task's rows compare."""

    expert: str
    baseline: str
    column: str  # the outcome's entry, per start
    meaning: str
    count: int  # N
    starts: int
    disk_radius_m: float  # the sweep file's (no disk graph here; it only keeps the starts the sweep's)


MEASURED = {
    "formation": Measured(
        "capt", "capt_flood", "ratio_to_lower_bound", "time over the lower bound", 50, 200, 3.0
    ),
    "coverage": Measured(
        "lloyd", "lloyd_flood", "first_within_s", "time to within 1.05 H_ref (s)", 100, 8, 2.0
    ),
}


def graph_power(adjacency: np.ndarray, hops: int) -> np.ndarray:
    """``(B, N, N)``: 1 where two robots are within ``hops`` hops of ``adjacency`` (no self loops)."""
    count = adjacency.shape[-1]
    step = (adjacency != 0) | np.eye(count, dtype=bool)
    reach = step.copy()
    for _ in range(hops - 1):
        reach = (reach.astype(np.int64) @ step.astype(np.int64)) > 0
    return (reach & ~np.eye(count, dtype=bool)).astype(np.float64)


def diameter(adjacency: np.ndarray) -> int:
    """Hops of the longest shortest path of a connected graph."""
    from scipy.sparse.csgraph import shortest_path

    return int(shortest_path(adjacency != 0, unweighted=True).max())


def values(config: TaskSweepConfig, graph: str, controller: str, starts, column: str) -> np.ndarray:
    """Every start's ``column`` (nan where the start did not succeed, or left a slot conflict)."""
    cell = run_cell(config, graph, config.sizes[0], controller, 0.0, starts=starts)
    return np.array(
        [
            start[column] if start["converged"] and start.get("conflicts", 0) == 0 else np.nan
            for start in cell["starts"]
        ],
        dtype=float,
    )


def summary(numbers: np.ndarray) -> str:
    done = numbers[~np.isnan(numbers)]
    failed = "" if len(done) == len(numbers) else f" ({len(numbers) - len(done)} did not succeed)"
    return f"{np.median(done):.3f}{failed} | {np.percentile(done, 95):.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=sorted(MEASURED), required=True)
    parser.add_argument("--graphs", nargs="+", default=["line", "cycle"], choices=("line", "cycle"))
    parser.add_argument("--count", type=int, help="N (default: formation 50, coverage 100)")
    parser.add_argument("--starts", type=int, help="the sweep's starts per graph (default 200, 8)")
    parser.add_argument("--out", type=Path, required=True, help="markdown file to write")
    args = parser.parse_args(argv)
    measured = MEASURED[args.task]
    count = args.count or measured.count
    starts = args.starts or measured.starts
    assert registry.get(args.task).sweep is not None
    lines = [
        f"# {args.task}: {measured.baseline}'s gap to {measured.expert} against the flood's latency",
        "",
        f"`python bench/investigations/task_latency.py --task {args.task} --graphs {' '.join(args.graphs)}"
        f" --count {count} --starts {starts} --out {args.out}` (the {args.task} sweep's first {starts}"
        f" starts per graph, N = {count}, control period 0.05 s). `hops` h: every robot also hears the"
        " robots within h hops of the graph (its h-th power), so the same flood crosses the graph in"
        f" `ceil(diameter / h)` ticks. Median / p95 of the {measured.meaning} over the starts that"
        " succeeded (every start did, with 0 slot conflicts, unless the row says otherwise).",
        "",
        "| graph | controller | hops h | flood latency (ticks, s) | median | p95 | median / expert's |",
        "|---|---|---|---|---|---|---|",
    ]
    began = time.perf_counter()
    for graph in args.graphs:
        config = TaskSweepConfig(
            task=args.task,
            topologies=[graph],
            sizes=[count],
            seeds=starts,
            disk_radius_m=measured.disk_radius_m,
        )
        poses, adjacency = cell_starts(config, graph, count)
        assert adjacency is not None
        expert = values(config, graph, measured.expert, (poses, adjacency), measured.column)
        expert_median = float(np.nanmedian(expert))
        lines.append(f"| {graph} | {measured.expert} | - | - | {summary(expert)} | 1.000 |")
        print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
        widest = max(diameter(a) for a in adjacency)
        for hops in [h for h in HOPS if h < widest] + [widest]:  # the last: the complete graph
            powered = graph_power(adjacency, hops)
            numbers = values(config, graph, measured.baseline, (poses, powered), measured.column)
            ticks = math.ceil(widest / hops)
            latency_s = ticks * config.control_period_s
            lines.append(
                f"| {graph} | {measured.baseline} | {hops} | {ticks}, {latency_s:.2f} s |"
                f" {summary(numbers)} | {np.nanmedian(numbers) / expert_median:.3f} |"
            )
            print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
