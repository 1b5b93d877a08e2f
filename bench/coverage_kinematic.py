"""Coverage: the expert ``lloyd`` against the decentralized ``lloyd_local`` and ``lloyd_flood``.

Per graph (complete, cycle, line, random, disk of radius 2 m) and N in {6, 12, 24, 50, 100}:
``--starts`` random starts per cell, every robot in the lower-left quadrant of a square of side
``0.9 sqrt(N)`` m (a deployment from one corner; 0.3 m apart), the density uniform or (``--density
gaussian``) two Gaussians (at (-0.2, 0.25) and (0.25, -0.15) of the side, sigma 0.15 and 0.2 of it,
weights 1 and 1.5), a 48-cell quadrature grid, v_max 0.5 m/s, control period 0.05 s, kinematic
engine. ``lloyd_local`` on the disk graph cuts its cells at half the radius (Cortes, Martinez and Bullo
2005). All three controllers run on the same starts; ``--loss`` adds cells of the decentralized
kinds on the cycle and the line under that packet loss.

Reported per cell and controller: ``H / H_ref`` (the locational cost over the best of 16 centralized
Lloyd restarts, ``swarm.core.tasks.coverage.reference``: a reference, not a bound) at 5, 10 and 20 s and
at the end (median and p95 over the starts), the share of starts within 1.05 H_ref held 2 s at the end,
and the median and p95 time at which H first comes within 1.05 H_ref (a start that never does counts as
the run's duration, and the table says how many did not).

    python bench/coverage_kinematic.py --out bench/results --starts 20
    python bench/coverage_kinematic.py --out bench/results --starts 20 --density gaussian
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from swarm.core import tasks, topologies
from swarm.core.faults import LinkFaults
from swarm.core.initial_poses import random_poses
from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.core.tasks.registry import settle_time
from swarm.sim.controller_kinds import ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim

GRAPHS = ("complete", "cycle", "line", "random", "disk")
SIZES = (6, 12, 24, 50, 100)
CONTROLLERS = ("lloyd", "lloyd_local", "lloyd_flood")
DISK_RADIUS_M = 2.0
CONTROL_PERIOD_S = 0.05
SAMPLE_EVERY_TICKS = 5
REPORT_TIMES_S = (5.0, 10.0, 20.0)
WITHIN = 1.05


def side_m(count: int) -> float:
    return 0.9 * math.sqrt(count)


def section_for(count: int, density: str) -> coverage.CoverageSection:
    half = side_m(count) / 2
    region = [[-half, -half], [half, -half], [half, half], [-half, half]]
    gaussians = []
    if density == "gaussian":
        side = side_m(count)
        gaussians = [
            {"mean": [-0.2 * side, 0.25 * side], "sigma_m": 0.15 * side, "weight": 1.0},
            {"mean": [0.25 * side, -0.15 * side], "sigma_m": 0.2 * side, "weight": 1.5},
        ]
    return tasks.parse_section(
        {"kind": "coverage", "region": region, "gaussians": gaussians, "tolerance": WITHIN - 1.0}
    )


def starts(count: int, number: int, seed: int) -> np.ndarray:
    half = side_m(count) / 2
    return random_poses(np.random.default_rng(seed), number, count, (-half, 0.0), (-half, 0.0), 0.3)


def graphs_for(graph: str, count: int, number: int, seed: int) -> dict:
    if graph == "disk":
        return {"disk_radius_m": DISK_RADIUS_M}
    rng = np.random.default_rng(seed)
    return {"adjacency": np.stack([topologies.draw(graph, count, rng) for _ in range(number)])}


def run_cell(
    graph: str, count: int, poses: np.ndarray, controller: str, density: str, duration_s: float, loss: float
) -> dict:
    robot = RobotParams()
    section = section_for(count, density)
    points, weights = section.quadrature()
    h_ref = coverage.reference_cost(section, count)
    cell_radius = DISK_RADIUS_M / 2 if (graph == "disk" and controller == "lloyd_local") else None
    args = ControllerArgs(
        robot=robot,
        control_period_s=CONTROL_PERIOD_S,
        robot_count=count,
        task=section,
        cell_radius_m=cell_radius,
    )
    faults = LinkFaults.packet_loss(loss, CONTROL_PERIOD_S, seed=count) if loss else None
    sim = KinematicSim(
        robot,
        batched_controller(controller, args),
        CONTROL_PERIOD_S,
        poses,
        link_faults=faults,
        **graphs_for(graph, count, len(poses), seed=count),
    )
    ticks = round(duration_s / CONTROL_PERIOD_S)
    began = time.perf_counter()
    samples = [coverage.locational_cost(sim.poses[..., :2], points, weights)]
    for tick in range(1, ticks + 1):
        sim.step()
        if tick % SAMPLE_EVERY_TICKS == 0:
            samples.append(coverage.locational_cost(sim.poses[..., :2], points, weights))
    wall_s = time.perf_counter() - began
    ratio = np.stack(samples) / h_ref  # (T, B)
    times = np.arange(len(ratio)) * SAMPLE_EVERY_TICKS * CONTROL_PERIOD_S
    within = ratio <= WITHIN
    first = np.where(within.any(axis=0), times[within.argmax(axis=0)], np.nan)
    held = [settle_time(times, within[:, b], section.hold_s) is not None for b in range(len(poses))]

    def stats(values: np.ndarray) -> dict:
        return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95))}

    reached = first[~np.isnan(first)]
    return {
        "graph": graph,
        "robots": count,
        "controller": controller,
        "density": density,
        "loss": loss,
        "starts": len(poses),
        "reference_cost_m2": h_ref,
        "ratio_at_s": {f"{t:g}": stats(ratio[round(t / times[1])]) for t in REPORT_TIMES_S},
        "final_ratio": stats(ratio[-1]),
        "success": float(np.mean(held)),
        "reached": len(reached),
        "first_within_s": stats(np.where(np.isnan(first), duration_s, first)),
        "wall_s": wall_s,
    }


def _fmt(stat: dict) -> str:
    return f"{stat['median']:.3f} / {stat['p95']:.3f}"


def write_tables(rows: list[dict], out: Path, command: str, density: str) -> None:
    stem = f"coverage_{density}"
    (out / f"{stem}.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [
        f"Coverage, {density} density, from one quadrant: `{command}`.",
        "",
        f"H / H_ref, median / p95 over {rows[0]['starts']} starts per cell; H_ref: the best of 16 centralized"
        " Lloyd restarts (a reference, not a bound: a run may end under 1). Success: within 1.05 H_ref,"
        " held 2 s at the end. 'reach 1.05': median / p95 time H first comes within 1.05 H_ref (s; a start"
        " that never does counts as the duration; 'of' says how many did).",
        "",
        "| graph | N | loss | controller | at 5 s | at 10 s | at 20 s | end | success | reach 1.05 (s)"
        " | of |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        at = row["ratio_at_s"]
        lines.append(
            f"| {row['graph']} | {row['robots']} | {row['loss']:.0%} | {row['controller']} | {_fmt(at['5'])}"
            f" | {_fmt(at['10'])} | {_fmt(at['20'])} | {_fmt(row['final_ratio'])} | {row['success']:.0%}"
            f" | {row['first_within_s']['median']:.1f} / {row['first_within_s']['p95']:.1f}"
            f" | {row['reached']}/{row['starts']} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench/results"), help="where the tables go")
    parser.add_argument("--starts", type=int, default=20, help="random starts per cell")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--graphs", nargs="+", default=list(GRAPHS), choices=GRAPHS)
    parser.add_argument("--controllers", nargs="+", default=list(CONTROLLERS), choices=CONTROLLERS)
    parser.add_argument("--density", choices=("uniform", "gaussian"), default="uniform")
    parser.add_argument("--duration-s", type=float, default=60.0, help="simulated time per run")
    parser.add_argument(
        "--loss", type=float, nargs="*", default=[0.2, 0.5], help="packet loss cells (cycle, line)"
    )
    args = parser.parse_args(argv)
    if args.starts < 1 or args.duration_s < 20.0 or any(not 0.0 < p < 1.0 for p in args.loss):
        parser.error("--starts >= 1, --duration-s >= 20 (the 20 s column) and every --loss in (0, 1)")
    command = "python bench/coverage_kinematic.py " + " ".join(argv if argv is not None else sys.argv[1:])
    cells = [(graph, count, 0.0) for graph in args.graphs for count in args.sizes]
    cells += [
        (graph, count, p)
        for p in args.loss
        for graph in ("cycle", "line")
        if graph in args.graphs
        for count in args.sizes
    ]
    rows: list[dict] = []
    args.out.mkdir(parents=True, exist_ok=True)
    try:
        for index, (graph, count, loss) in enumerate(cells):
            poses = starts(count, args.starts, seed=1000 * count + 7)
            for controller in args.controllers:
                if loss and controller == "lloyd":
                    continue  # the central expert hears no links
                row = run_cell(graph, count, poses, controller, args.density, args.duration_s, loss)
                rows.append(row)
                print(
                    f"[{index + 1}/{len(cells)}] {graph} N={count} loss {loss:.0%} {controller}:"
                    f" end {_fmt(row['final_ratio'])}, success {row['success']:.0%}, {row['wall_s']:.0f} s",
                    file=sys.stderr,
                    flush=True,
                )
    except KeyboardInterrupt:
        if rows:
            write_tables(rows, args.out, command + "  (interrupted)", args.density)
        return 130
    write_tables(rows, args.out, command, args.density)
    return 0


if __name__ == "__main__":
    sys.exit(main())
