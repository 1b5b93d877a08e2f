"""Which cell should the learned coverage steering read: ``lloyd_flood``'s, ``lloyd_predict``'s, or both?

The learned readout (``swarm.sim.coverage_gnn``: features, MLP, DAgger imitation of the central ``lloyd``
on N = 4-12, ``swarm train --algo coverage``'s default settings and seed) steers from one Voronoi cell.
The shipped ``lloyd_gnn`` reads ``lloyd_predict``'s (flooded positions extrapolated toward their
targets over at most 5 ticks of their age). Here the same readout is trained on ``lloyd_flood``'s cell
(``flood_gnn``: what ``lloyd_gnn`` was before 2026-12-06, file format ``coverage_gnn/1``) and on both
(``both_gnn``: ``lloyd_gnn``'s features and the direction and gate to ``lloyd_flood``'s centroid, so that
it may learn when to trust the prediction). Every kind runs on the coverage sweep's starts of the cells
given (``swarm.scenarios.task_sweep``: the same starts for every kind, 60 s):

    python bench/investigations/coverage_gnn_predict.py --out bench/results/coverage_gnn_predict.md

It is an investigation: the weights it trains are written beside the table (``--weights``), not shipped;
``lloyd_gnn`` runs the shipped ``models/coverage/lloyd_gnn.npz``: in the tables committed before its
3-tick horizon (``bench/results/coverage_gnn_predict.md``, ``coverage_gnn_*50_*.md``) that column is
the 5-tick policy's; ``flood_gnn`` and ``both_gnn`` are trained, as then, on 5 ticks (their files name
no horizon).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
from coverage_prediction import sweep_cell, time_and_end  # this folder

import swarm.learn.train.coverage as coverage_training
from swarm.core.robot import RobotParams
from swarm.learn.train.steering import dagger
from swarm.scenarios.task_sweep import run_cell
from swarm.sim.coverage_controllers import LloydFlood, LloydGnn, centroid_targets
from swarm.sim.coverage_gnn import FEATURES, CoverageGnnWeights
from swarm.sim.links import Links
from swarm.sim.steering_mlp import target_features

KINDS = ("lloyd", "lloyd_flood", "lloyd_predict", "lloyd_gnn", "flood_gnn", "both_gnn")
DEFAULT_CELLS = ("complete:24", "line:24", "cycle:50", "line:50", "random:50", "disk:50", "complete:100")


class FloodGnn(LloydGnn):
    """``lloyd_gnn``'s learned steering on ``lloyd_flood``'s tables and cell (3-float entries, the flooded
    positions as they were sent)."""

    fields = LloydFlood.fields

    def known_positions(self, memory: np.ndarray) -> np.ndarray:
        return LloydFlood.known_positions(self, memory)

    def update_targets(self, poses: np.ndarray, inbox: np.ndarray, heard: Links) -> np.ndarray:
        return LloydFlood.update_targets(self, poses, inbox, heard)


class BothWeights(CoverageGnnWeights):
    """``both_gnn``'s MLP: ``lloyd_gnn``'s features on the predicted cell, then the flooded cell's."""

    FORMAT = "coverage_gnn_both/0"
    FEATURES = (*FEATURES, "flood_dir_x", "flood_dir_y", "flood_near")
    KIND = "both_gnn"


class BothGnn(LloydGnn):
    """The learned steering from both cells: ``lloyd_predict``'s (its features and gate, as
    ``lloyd_gnn``) and ``lloyd_flood``'s (the direction and gate to its centroid)."""

    def features(self, poses: np.ndarray, memory: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        features, gate = super().features(poses, memory)  # on lloyd_predict's cell (lloyd_gnn's)
        count = poses.shape[1]
        valid = memory[..., 0] > 0.0
        valid[:, np.arange(count), np.arange(count)] = False
        flood_targets = centroid_targets(
            self.sums(poses[..., :2], memory[..., 1:3], valid, None), self.fallback
        )
        flood, _ = target_features(poses, flood_targets, self.robot, self.control_period_s)
        return np.concatenate([features, flood], axis=-1), gate


class FloodWeights(CoverageGnnWeights):
    """``flood_gnn``'s MLP: ``lloyd_gnn``'s features on ``lloyd_flood``'s cell."""

    FORMAT = "coverage_gnn/1"
    KIND = "flood_gnn"


LEARNED = {"flood_gnn": (FloodGnn, FloodWeights), "both_gnn": (BothGnn, BothWeights)}


def trained(name: str, out: Path):
    """Train ``name`` as ``swarm train --algo coverage`` trains ``lloyd_gnn`` (its defaults and seed)."""
    controller, weights_class = LEARNED[name]
    coverage_training.LloydGnn = controller  # type: ignore[misc]  # what episode() and closed_loop() build
    coverage_training.FEATURES = weights_class.FEATURES  # type: ignore[misc]  # episode()'s row width
    config = coverage_training.make_config(overrides={"out": str(out / name)})
    meta = {"config": asdict(config), "features": list(weights_class.FEATURES), "speed": "full"}
    began = time.perf_counter()
    policy = dagger(
        config,
        weights_class=weights_class,
        meta=meta,
        episode=coverage_training.episode,
        closed_loop=coverage_training.closed_loop,
        score="median_first_within_s",
        references=("lloyd_flood", "lloyd"),
        imitate_speed=False,
    )
    print(f"trained {policy} in {time.perf_counter() - began:.0f} s", flush=True)
    return weights_class.load(policy)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="+", default=list(DEFAULT_CELLS), help="graph:N")
    parser.add_argument("--starts", type=int, default=8, help="the coverage sweep's starts per cell")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), help=" ".join(KINDS))
    parser.add_argument("--weights", type=Path, default=Path("runs/coverage_gnn_predict"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    # -- train
    weights = {name: trained(name, args.weights) for name in args.kinds if name in LEARNED}

    # -- evaluate: every kind on the sweep's starts of every cell
    lines = [
        "# Coverage: the learned steering on lloyd_predict's cell (`lloyd_gnn`), lloyd_flood's (`flood_gnn`)"
        " and both (`both_gnn`)",
        "",
        f"`python bench/investigations/coverage_gnn_predict.py --cells {' '.join(args.cells)} --starts"
        f" {args.starts} --kinds {' '.join(args.kinds)} --out {args.out}`: `flood_gnn` and `both_gnn`"
        " trained as `swarm train --algo coverage` trains `lloyd_gnn` (same settings and seed; weights in"
        f" `{args.weights}`), then every kind on the coverage sweep's first {args.starts} starts of each"
        " cell (60 s, the same starts for every kind). Time to within 1.05 H_ref (s: median over the starts"
        " that got there, how many did) and H / H_ref at the end (median).",
        "",
        "| graph | N | " + " | ".join(f"`{name}`" for name in args.kinds) + " |",
        "|---|---|" + "---|" * len(args.kinds),
    ]
    for spec in args.cells:
        graph, count_text = spec.split(":")
        count = int(count_text)
        config, starts = sweep_cell(graph, count, args.starts)
        section = config.cells.section(count)
        robot = RobotParams(v_max_mps=config.v_max_mps)
        row = [graph, str(count)]
        for name in args.kinds:
            controller = (
                LEARNED[name][0](robot, config.control_period_s, section, count, weights[name])
                if name in LEARNED
                else name
            )
            cell = run_cell(config, graph, count, controller, 0.0, starts=starts)
            row.append(time_and_end(cell, " s"))
        lines.append("| " + " | ".join(row) + " |")
        print(lines[-1], flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
