"""Is ``lloyd_flood``'s slowness on sparse graphs the age of the positions it uses, and can it be predicted?

``bench/investigations/task_latency.py --task coverage`` shows that ``lloyd_flood`` on the line of 100
stays far from the expert ``lloyd`` even when the flood crosses the graph in a few ticks, and on the
complete graph of 100 (positions one tick old) it takes 22 s against the expert's 17.5 s to 1.05 H_ref
(``docs/results/tasks/coverage``). Every robot drives at full speed toward its cell's centroid, the
whole way in one tick near the end, so a neighbour's position one tick old is where it *was*, and two
robots both move into the gap the other is leaving.

``lloyd_predict`` (``swarm.sim.coverage_controllers.LloydPredict``; this investigation's ``predict``,
made a controller kind) is ``lloyd_flood`` with one more thing in each entry of the flooded table: the
sender's target (its centroid) when it sent its position. A robot places every robot it knows at the
point it would have reached driving straight to that target at ``v_max`` for the entry's age (the
kinematic engine's axle does nearly that), and takes its cell among those points. Same starts and
judging as the coverage sweep (``swarm.scenarios.task_sweep``). The extrapolation here runs over an
entry's whole age (``horizon_ticks`` infinite; the kind's default horizon of 5 ticks came after, from
``coverage_prediction_cap.py``):

    python bench/investigations/coverage_prediction.py --out bench/results/coverage_prediction.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core.robot import RobotParams
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell
from swarm.sim.coverage_controllers import LloydPredict


def sweep_cell(graph: str, count: int, starts: int) -> tuple[TaskSweepConfig, tuple]:
    """The coverage sweep's settings for one cell and its first ``starts`` starts (poses, adjacency),
    which every kind of an investigation runs from."""
    config = TaskSweepConfig(
        task="coverage", topologies=[graph], sizes=[count], seeds=starts, chunk_starts=starts
    )
    return config, cell_starts(config, graph, count)


def time_and_end(cell: dict, unit: str = "") -> str:
    """``"<median time to 1.05 H_ref><unit> (<starts that got there>), <median H / H_ref at the end>"``
    of a ``run_cell`` result (``"- (0)"`` for the time when no start got there)."""
    reached = [s["first_within_s"] for s in cell["starts"] if s.get("first_within_s") is not None]
    final = np.median([s["final_metric"] for s in cell["starts"]])
    timing = f"{np.median(reached):.2f}{unit} ({len(reached)})" if reached else "- (0)"
    return f"{timing}, {final:.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graphs", nargs="+", default=["complete", "line"])
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--starts", type=int, default=8, help="the coverage sweep's starts per graph")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    lines = [
        f"# Coverage: lloyd_flood with predicted positions (N = {args.count})",
        "",
        f"`python bench/investigations/coverage_prediction.py --graphs {' '.join(args.graphs)} --count"
        f" {args.count} --starts {args.starts} --out {args.out}` (the coverage sweep's first {args.starts}"
        " starts per graph, 60 s). Time to within 1.05 H_ref (s) and H / H_ref at the end, median / p95"
        " over the starts (the time over those that got there).",
        "",
        "| graph | controller | reached 1.05 H_ref | time to 1.05 H_ref (s) | H / H_ref at the end |",
        "|---|---|---|---|---|",
    ]
    for graph in args.graphs:
        config, starts = sweep_cell(graph, args.count, args.starts)
        uncapped = LloydPredict(
            RobotParams(v_max_mps=config.v_max_mps),
            config.control_period_s,
            config.cells.section(args.count),
            args.count,
            horizon_ticks=math.inf,
        )
        for name, controller in (("lloyd", "lloyd"), ("lloyd_flood", "lloyd_flood"), ("predict", uncapped)):
            began = time.perf_counter()
            cell = run_cell(config, graph, args.count, controller, 0.0, starts=starts)
            reached = np.array(
                [s["first_within_s"] for s in cell["starts"] if s.get("first_within_s") is not None]
            )
            final = np.array([s["final_metric"] for s in cell["starts"]])
            timing = f"{np.median(reached):.2f} / {np.percentile(reached, 95):.2f}" if len(reached) else "-"
            lines.append(
                f"| {graph} | {name} | {len(reached)} of {len(final)} | {timing} |"
                f" {np.median(final):.3f} / {np.percentile(final, 95):.3f} |"
            )
            print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
