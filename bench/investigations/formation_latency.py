"""Is ``capt_flood``'s gap to the expert on the line of 50 the flood's latency? Measured by shortening it.

On the line of 50 ``capt_flood``'s median time is 1.14x the lower bound against the expert's 1.03x
(``docs/results/tasks/formation-1000-50``, 1000 starts). A robot learns of the farthest one only after
the graph's diameter in ticks (49 ticks, 2.45 s, on a 7-8 s task) and drives meanwhile toward the CAPT
slot of the robots it knows. This runs ``capt_flood`` on the sweep's starts of a graph and on its h-th
powers (every robot also hears the robots within h hops: the same flood, ``h`` hops a tick, diameter
``ceil(D / h)``), up to the complete graph, against the expert ``capt`` on the same starts. If the gap
closes as the diameter shrinks, and nothing else changes between the runs, it is the latency.

    python bench/investigations/formation_latency.py --out bench/results/formation_latency.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core.tasks import registry
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell

HOPS = (1, 2, 3, 5, 10, 25, 49)


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


def ratios(config: TaskSweepConfig, graph: str, controller: str, starts) -> np.ndarray:
    """Every start's time over the lower bound (nan where it did not succeed or left a conflict)."""
    cell = run_cell(config, graph, config.sizes[0], controller, 0.0, starts=starts)
    return np.array(
        [
            start["ratio_to_lower_bound"] if start["converged"] and start["conflicts"] == 0 else np.nan
            for start in cell["starts"]
        ],
        dtype=float,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graphs", nargs="+", default=["line", "cycle"], choices=("line", "cycle"))
    parser.add_argument("--count", type=int, default=50)
    parser.add_argument("--starts", type=int, default=200, help="the sweep's starts per graph")
    parser.add_argument("--out", type=Path, required=True, help="markdown file to write")
    args = parser.parse_args(argv)
    assert registry.get("formation").sweep is not None
    lines = [
        "# Formation: capt_flood's gap against the flood's latency",
        "",
        f"`python bench/investigations/formation_latency.py --out {args.out}` ({args.starts} starts of the"
        f" formation sweep per graph, N = {args.count}, control period 0.05 s). `hops` h: every robot also"
        " hears the robots within h hops of the graph (its h-th power), so the same flood crosses the"
        " graph in `ceil(diameter / h)` ticks. Time over the lower bound, median / p95; every start of"
        " every row succeeded with 0 conflicts unless the row says how many did not.",
        "",
        "| graph | controller | hops h | flood latency (ticks, s) | median | p95 | median / expert's |",
        "|---|---|---|---|---|---|---|",
    ]
    began = time.perf_counter()
    for graph in args.graphs:
        config = TaskSweepConfig(
            task="formation", topologies=[graph], sizes=[args.count], seeds=args.starts, disk_radius_m=3.0
        )
        poses, adjacency = cell_starts(config, graph, args.count)
        assert adjacency is not None
        expert = ratios(config, graph, "capt", (poses, adjacency))
        expert_median = float(np.median(expert))
        lines.append(
            f"| {graph} | capt | - | - | {expert_median:.3f} | {np.percentile(expert, 95):.3f} | 1.000 |"
        )
        widest = max(diameter(a) for a in adjacency)
        for hops in HOPS:
            if hops > widest:
                break
            powered = graph_power(adjacency, hops)
            values = ratios(config, graph, "capt_flood", (poses, powered))
            done = values[~np.isnan(values)]
            ticks = math.ceil(widest / hops)
            failed = "" if len(done) == len(values) else f" ({len(values) - len(done)} failed)"
            lines.append(
                f"| {graph} | capt_flood | {hops} | {ticks}, {ticks * config.control_period_s:.2f} s |"
                f" {np.median(done):.3f}{failed} | {np.percentile(done, 95):.3f} |"
                f" {np.median(done) / expert_median:.3f} |"
            )
            print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
