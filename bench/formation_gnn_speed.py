"""Why ``capt_gnn`` drives at full speed: the same DAgger imitation with the expert's speed imitated too.

``swarm train --algo formation`` fits eq. (1)'s direction to ``capt``'s and drives at v_max (``speed:
full``, the shipped ``models/formation/capt_gnn.npz``). This trains the other choice (``speed:
imitated``: the expert's time-synchronized speed ``v_max d_i / D`` fitted as well) with the same seed
and data, and runs both and ``capt_flood`` on the same cells as ``swarm sweep --config
docs/results/tasks/formation.yaml`` (its starts: ``task_sweep.cell_starts``). Writes
``bench/results/formation_gnn_speed.md``.

``python bench/formation_gnn_speed.py`` (about 3 min on 2 cores).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarm.core.robot import RobotParams  # noqa: E402
from swarm.core.tasks import formation  # noqa: E402
from swarm.learn.train import formation as train_formation  # noqa: E402
from swarm.scenarios.task_sweep import TaskSweepConfig, cell_starts, run_chunk  # noqa: E402
from swarm.sim.formation_controllers import CaptGnn  # noqa: E402
from swarm.sim.formation_gnn import FormationGnnWeights  # noqa: E402

CELLS = (("complete", 50), ("cycle", 50), ("line", 24), ("line", 50))


def ratios(config: TaskSweepConfig, topology: str, count: int, controller) -> list[float]:
    """Time / lower bound of every start of the cell (inf where a start fails or has a conflict)."""
    poses, adjacency = cell_starts(config, topology, count)
    section = formation.sweep_section(count)
    if isinstance(controller, FormationGnnWeights):
        controller = CaptGnn(
            RobotParams(v_max_mps=config.v_max_mps), config.control_period_s, section, count, controller
        )
    times, frames = run_chunk(config, section, controller, poses, adjacency, 0.0, 0)
    out = []
    for b in range(len(poses)):
        result = formation.outcome(times, frames[:, b], section, config.v_max_mps)
        good = result.get("converged") and result.get("conflicts") == 0
        out.append(result["ratio_to_lower_bound"] if good else float("inf"))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "formation_gnn_speed.md")
    args = parser.parse_args(argv)
    sweep = TaskSweepConfig.from_mapping(
        yaml.safe_load((ROOT / "docs/results/tasks/formation.yaml").read_text())
    )
    shipped = FormationGnnWeights.load(ROOT / "models" / "formation" / "capt_gnn.npz")
    with tempfile.TemporaryDirectory() as work:
        config = replace(train_formation.make_config(), out=work, speed="imitated", progress=False)
        imitated = FormationGnnWeights.load(train_formation.train(config))
    lines = [
        "# capt_gnn: the expert's speed imitated, or full speed",
        "",
        f"`python bench/formation_gnn_speed.py`: `swarm sweep --config docs/results/tasks/formation.yaml`'s"
        f" starts ({sweep.seeds} a cell), v_max {sweep.v_max_mps} m/s. `capt_gnn` full speed: the shipped"
        " `models/formation/capt_gnn.npz`; imitated speed: the same training (seed 0)"
        " with `speed: imitated`.",
        "Median / p95 of time / lower bound (inf: a start that failed).",
        "",
        "| graph | N | capt_flood | capt_gnn (full speed, shipped) | capt_gnn (imitated speed) |",
        "|---|---|---|---|---|",
    ]
    for topology, count in CELLS:
        cells = [ratios(sweep, topology, count, c) for c in ("capt_flood", shipped, imitated)]
        text = [f"{np.median(r):.3f} / {np.percentile(r, 95):.3f}" for r in cells]
        lines.append(f"| {topology} | {count} | " + " | ".join(text) + " |")
        print(lines[-1], flush=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
