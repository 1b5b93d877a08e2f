"""Does capping the age ``lloyd_predict`` extrapolates over take the better of it and ``lloyd_flood``?

``lloyd_predict`` (``swarm.sim.coverage_controllers.LloydPredict``) beats ``lloyd_flood`` where flooded
positions are a few ticks old and loses where they are tens of ticks old (cycle and line of 24-50,
``docs/tasks.md``): a target that old is itself stale. ``capped`` extrapolates an entry toward its
target over at most ``cap`` ticks (``cap`` 0 is ``lloyd_flood``'s cell; ``no cap`` extrapolates over the
whole age, as ``lloyd_predict`` did before this measurement made 5 ticks its default ``horizon_ticks``).
Same starts and judging as the coverage sweep (``swarm.scenarios.task_sweep``, 60 s):

    python bench/investigations/coverage_prediction_cap.py --out bench/results/coverage_prediction_cap.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from coverage_prediction import sweep_cell, time_and_end  # this folder

from swarm.core.robot import RobotParams
from swarm.scenarios.task_sweep import run_cell
from swarm.sim.coverage_controllers import LloydPredict

DEFAULT_CELLS = ("cycle:50", "line:50", "line:24", "random:50", "complete:100")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=list(DEFAULT_CELLS), help="graph:N")
    parser.add_argument("--caps", nargs="+", type=int, default=[2, 5, 10], help="ticks")
    parser.add_argument("--starts", type=int, default=8, help="the coverage sweep's starts per cell")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    kinds = ["lloyd_flood", *(f"cap {cap}" for cap in args.caps), "no cap"]
    lines = [
        "# Coverage: lloyd_predict with its extrapolation capped at a few ticks",
        "",
        f"`python bench/investigations/coverage_prediction_cap.py --cells {' '.join(args.cells)} --caps"
        f" {' '.join(map(str, args.caps))} --starts {args.starts} --out {args.out}` (the coverage sweep's"
        f" first {args.starts} starts per cell, 60 s). Median time to within 1.05 H_ref (s; how many starts"
        " got there) and median H / H_ref at the end.",
        "",
        "| cell | " + " | ".join(f"`{kind}`" if kind.startswith("lloyd") else kind for kind in kinds) + " |",
        "|---|" + "---|" * len(kinds),
    ]
    for spec in args.cells:
        graph, count_text = spec.split(":")
        count = int(count_text)
        config, starts = sweep_cell(graph, count, args.starts)
        section = config.cells.section(count)
        robot = RobotParams(v_max_mps=config.v_max_mps)
        row = [f"{graph} of {count}"]
        began = time.perf_counter()
        for kind in kinds:
            controller: str | LloydPredict = kind
            if kind != "lloyd_flood":
                horizon_ticks = math.inf if kind == "no cap" else float(kind.split()[1])
                controller = LloydPredict(
                    robot, config.control_period_s, section, count, horizon_ticks=horizon_ticks
                )
            cell = run_cell(config, graph, count, controller, 0.0, starts=starts)
            row.append(time_and_end(cell))
        lines.append("| " + " | ".join(row) + " |")
        print(lines[-1], f"({time.perf_counter() - began:.0f} s)", flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
