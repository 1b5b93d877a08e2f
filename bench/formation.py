"""Formation with assignment: the expert ``capt`` and the decentralized baseline ``capt_flood``.

Per graph (complete, cycle, line, disk of radius 2 m) and N in {6, 12, 24, 50}: ``--starts`` random
starts per cell (the sweep's box, ``swarm.core.initial_poses.box_for``; disk starts redrawn until the
start graph is connected), slots on a circle 0.5 m apart (radius at least 1 m), tolerance 0.1 m, held
2 s, v_max 0.5 m/s, control period 0.05 s, kinematic engine. Reports per cell and controller the
median and p95 of success time / lower bound (``swarm.core.tasks.formation.lower_bound_s``), the
success rate and the conflicts at the end. Both controllers run on the same starts.

    python bench/formation.py --out bench/results --starts 20 --loss 0.2 0.5

A random graph is one connected G(N, p) per start (``swarm.core.topologies.draw``); ``--loss`` adds
``capt_flood`` cells on the cycle and the line under that packet loss, on the same starts.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core import graphs, topologies
from swarm.core.faults import LinkFaults
from swarm.core.initial_poses import box_for, random_poses
from swarm.core.robot import RobotParams
from swarm.core.tasks import formation
from swarm.core.tasks.formation import FormationSection
from swarm.sim.formation_controllers import CaptExpert, CaptFlood
from swarm.sim.kinematic import KinematicSim

GRAPHS = ("complete", "cycle", "line", "random", "disk")
SIZES = (6, 12, 24, 50)
DISK_RADIUS_M = 2.0
CONTROL_PERIOD_S = 0.05
MAX_DURATION_S = 120.0


def section_for(count: int) -> FormationSection:
    """The cells' slots: ``swarm sweep --task formation``'s (``formation.sweep_section``)."""
    return formation.sweep_section(count)


def starts(graph: str, count: int, number: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    box = box_for(count)
    chosen: list[np.ndarray] = []
    while len(chosen) < number:
        poses = random_poses(rng, number, count, box, box)
        for pose in poses:
            if graph != "disk" or graphs.is_connected(graphs.disk(pose[:, :2], DISK_RADIUS_M)):
                chosen.append(pose)
    return np.stack(chosen[:number])


def run_cell(graph: str, count: int, poses: np.ndarray, controller_name: str, loss: float = 0.0) -> dict:
    robot = RobotParams()
    section = section_for(count)
    slots = section.slot_positions(count)
    if controller_name == "capt":
        controller: CaptExpert | CaptFlood = CaptExpert(robot, CONTROL_PERIOD_S, section)
    else:
        controller = CaptFlood(robot, CONTROL_PERIOD_S, section, count)
    if graph == "disk":
        graph_args: dict = {"disk_radius_m": DISK_RADIUS_M}
    else:
        rng = np.random.default_rng(count)  # a random kind: one connected graph per start
        graph_args = {"adjacency": np.stack([topologies.draw(graph, count, rng) for _ in range(len(poses))])}
    faults = LinkFaults.packet_loss(loss, CONTROL_PERIOD_S, seed=count) if loss else None
    sim = KinematicSim(robot, controller, CONTROL_PERIOD_S, poses, link_faults=faults, **graph_args)
    hold_ticks = round(section.hold_s / CONTROL_PERIOD_S)
    ok = [formation.occupied(sim.poses[..., :2], slots, section.tolerance_m)]
    began = time.perf_counter()
    while sim.time_s < MAX_DURATION_S:
        sim.step()
        ok.append(formation.occupied(sim.poses[..., :2], slots, section.tolerance_m))
        if len(ok) > hold_ticks and np.all(np.stack(ok[-hold_ticks - 1 :]), axis=0).all():
            break
    wall_s = time.perf_counter() - began
    held = np.stack(ok)  # (T, B)
    times = np.arange(len(held)) * CONTROL_PERIOD_S
    ratios, conflicts = [], []
    for b in range(len(poses)):
        settled = formation.settle_time(times, held[:, b], section.hold_s)
        bound = formation.lower_bound_s(poses[b, :, :2], section, robot.v_max_mps)
        ratios.append(math.nan if settled is None else settled / bound)
        conflicts.append(formation.conflicts(sim.poses[b, :, :2], slots))
    ratios_array = np.array(ratios)
    done = ratios_array[~np.isnan(ratios_array)]
    return {
        "graph": graph,
        "robots": count,
        "controller": controller_name,
        "loss": loss,
        "starts": len(poses),
        "success": float(np.mean(~np.isnan(ratios_array))),
        "median_ratio": float(np.median(done)) if len(done) else None,
        "p95_ratio": float(np.percentile(done, 95)) if len(done) else None,
        "min_ratio": float(done.min()) if len(done) else None,
        "conflicts": int(np.sum(conflicts)),
        "wall_s": wall_s,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument("--starts", type=int, default=20)
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--graphs", nargs="+", default=list(GRAPHS), choices=GRAPHS)
    parser.add_argument("--loss", type=float, nargs="*", default=[], help="capt_flood cells, cycle and line")
    args = parser.parse_args(argv)
    rows = []
    for graph in args.graphs:
        for count in args.sizes:
            poses = starts(graph, count, args.starts, seed=1000 * count + GRAPHS.index(graph))
            for controller_name in ("capt", "capt_flood"):
                row = run_cell(graph, count, poses, controller_name)
                rows.append(row)
                print(json.dumps(row), flush=True)
    lossy = []
    for loss in args.loss:
        for graph in ("cycle", "line"):
            for count in args.sizes:
                poses = starts(graph, count, args.starts, seed=1000 * count + GRAPHS.index(graph))
                row = run_cell(graph, count, poses, "capt_flood", loss)
                lossy.append(row)
                print(json.dumps(row), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "formation.json").write_text(json.dumps(rows + lossy, indent=1) + "\n")
    lines = [
        f"Formation, {args.starts} starts per cell: `python bench/formation.py"
        f" {' '.join(argv if argv is not None else sys.argv[1:])}`."
        " Ratio: success time (held 2 s) / lower bound (B* - tol) / v_max.",
        "",
        "| graph | N | capt median / p95 | capt success | capt_flood median / p95 | capt_flood success"
        " | conflicts (capt, flood) |",
        "|---|---|---|---|---|---|---|",
    ]
    by_key = {(row["graph"], row["robots"], row["controller"]): row for row in rows}
    for graph in args.graphs:
        for count in args.sizes:
            expert, flood = by_key[(graph, count, "capt")], by_key[(graph, count, "capt_flood")]

            def ratio(row: dict) -> str:
                if row["median_ratio"] is None:
                    return "-"
                return f"{row['median_ratio']:.3f} / {row['p95_ratio']:.3f}"

            lines.append(
                f"| {graph} | {count} | {ratio(expert)} | {expert['success']:.0%} | {ratio(flood)}"
                f" | {flood['success']:.0%} | {expert['conflicts']}, {flood['conflicts']} |"
            )
    if lossy:
        lines += ["", "`capt_flood` under packet loss (the same starts):", ""]
        lines += ["| graph | N | loss | median / p95 | success | conflicts |", "|---|---|---|---|---|---|"]
        for row in lossy:
            median = "-"
            if row["median_ratio"] is not None:
                median = f"{row['median_ratio']:.3f} / {row['p95_ratio']:.3f}"
            lines.append(
                f"| {row['graph']} | {row['robots']} | {row['loss']:.0%} | {median} | {row['success']:.0%}"
                f" | {row['conflicts']} |"
            )
    (args.out / "formation.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
