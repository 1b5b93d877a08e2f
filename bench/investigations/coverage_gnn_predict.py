"""Does the learned coverage steering add anything over ``lloyd_predict`` when it is given its information?

``lloyd_gnn`` steers from ``lloyd_flood``'s cell (the Voronoi cell among the flooded positions, as old as
their hops). ``lloyd_predict`` floods each robot's target too and computes the cell among the positions
extrapolated by their age, which beats both on dense graphs (``docs/tasks.md``). Here the same learned
readout (``swarm.sim.coverage_gnn``: features, MLP, DAgger imitation of the central ``lloyd`` on
N = 4-12, ``swarm train --algo coverage``'s default settings and seed) is trained on top of
``lloyd_predict``'s cell instead (``PredictGnn``), and all four kinds run on the coverage sweep's starts
of the cells given (``swarm.scenarios.task_sweep``: the same starts for every kind, 60 s):

    python bench/investigations/coverage_gnn_predict.py --out bench/results/coverage_gnn_predict.md

It is an investigation, not a controller kind: the weights it trains are written beside the table
(``--weights``), not shipped.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import swarm.learn.train.coverage as coverage_training
from swarm.core.robot import RobotParams
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_cell
from swarm.sim.coverage_controllers import LloydGnn, LloydPredict
from swarm.sim.coverage_gnn import CoverageGnnWeights

DEFAULT_CELLS = ("complete:24", "line:24", "cycle:50", "line:50", "random:50", "disk:50", "complete:100")


class PredictGnn(LloydGnn):
    """``lloyd_gnn``'s learned steering on ``lloyd_predict``'s tables and cell."""

    fields = LloydPredict.fields
    update_targets = LloydPredict.update_targets


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=list(DEFAULT_CELLS), help="graph:N")
    parser.add_argument("--starts", type=int, default=8, help="the coverage sweep's starts per cell")
    parser.add_argument("--weights", type=Path, default=Path("runs/coverage_gnn_predict"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    # -- train: swarm train --algo coverage's defaults, the learner on lloyd_predict's cell
    coverage_training.LloydGnn = PredictGnn  # type: ignore[misc]  # what episode() and closed_loop() build
    began = time.perf_counter()
    policy = coverage_training.train(coverage_training.make_config(overrides={"out": str(args.weights)}))
    weights = CoverageGnnWeights.load(policy)
    print(f"trained {policy} in {time.perf_counter() - began:.0f} s", flush=True)

    # -- evaluate: the four kinds on the sweep's starts of every cell
    lines = [
        "# Coverage: the learned steering on lloyd_predict's cell (`predict_gnn`)",
        "",
        f"`python bench/investigations/coverage_gnn_predict.py --cells {' '.join(args.cells)} --starts"
        f" {args.starts} --out {args.out}`: `predict_gnn` trained as `swarm train --algo coverage` trains"
        " `lloyd_gnn` (same settings and seed; weights in"
        f" `{args.weights}`), then every kind on the coverage sweep's first {args.starts} starts of each"
        " cell (60 s, the same starts for every kind). Time to within 1.05 H_ref (s: median over the starts"
        " that got there, how many did) and H / H_ref at the end (median).",
        "",
        "| graph | N | `lloyd` | `lloyd_flood` | `lloyd_predict` | `lloyd_gnn` | `predict_gnn` |",
        "|---|---|---|---|---|---|---|",
    ]
    for spec in args.cells:
        graph, count_text = spec.split(":")
        count = int(count_text)
        config = TaskSweepConfig(
            task="coverage", topologies=[graph], sizes=[count], seeds=args.starts, chunk_starts=args.starts
        )
        starts = cell_starts(config, graph, count)
        section = config.cells.section(count)
        robot = RobotParams(v_max_mps=config.v_max_mps)
        row = [graph, str(count)]
        for name in ("lloyd", "lloyd_flood", "lloyd_predict", "lloyd_gnn", "predict_gnn"):
            controller = (
                PredictGnn(robot, config.control_period_s, section, count, weights)
                if name == "predict_gnn"
                else name
            )
            cell = run_cell(config, graph, count, controller, 0.0, starts=starts)
            reached = [s["first_within_s"] for s in cell["starts"] if s.get("first_within_s") is not None]
            final = np.median([s["final_metric"] for s in cell["starts"]])
            timing = f"{np.median(reached):.2f} s ({len(reached)})" if reached else "- (0)"
            row.append(f"{timing}, {final:.3f}")
        lines.append("| " + " | ".join(row) + " |")
        print(lines[-1], flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
