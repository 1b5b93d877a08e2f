"""Gathering bodies with the barrier filter: how close to the packing limit each controller gets.

    .venv/bin/python bench/gathering.py [--engines kinematic pybullet] [--sizes 6 20 50] [--update-results]

Cells: N in ``--sizes`` x start (uniform, two-cluster, strip, ring: ``bench/make_safety_scenarios.py``'s
starts and seeds) x graph (complete, cycle, line, and a disk graph whose radius is 1.05x the longest
edge of the start's minimum spanning tree, so that it starts connected) x controller (``mec_flood`` and
``pack_flood`` with ``safety: {kind: barrier}``, and ``mec_flood`` without it: today's jams), one start
per cell, for ``20 + 1.2 N`` s. Each cell is a scenario file run by ``swarm run --engine E`` (PyBullet:
one process per robot; on a disk graph the sim's radio relays who hears whom).

The packing limit is that of discs ``D_s = 2 (r + l) + margin`` across, the distance the filter keeps
between controlled points: 0.37 m for the default robot on the kinematic engine, 0.39 m on PyBullet
(its default margin is wider: ``swarm.core.safety.ENGINE_MARGIN_M``). It lies in ``[low, high]``
(``swarm.core.packing.packing_limit_m``: exact for N <= 8; above, the Groemer-Oler lower bound and the
hexagonal packing). Reported: the final ``max_pairwise`` over ``low`` (so a ratio r proves the swarm is
within r of the limit), whether it met ``1.3 low`` (N <= 20) or ``1.5 low`` (N = 50), the time it first
met it and held it over the kinematic lower bound of that threshold (``swarm.core.metrics.lower_bound_s``),
contact ticks and the smallest clearance.

Writes ``gathering.json`` and ``.md`` (``gathering_pybullet.*`` for ``--engines pybullet``) to ``--out``
(default ``runs/bench/``) or ``bench/results/``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _output import ROOT, add_output_arguments, output_dir, progress
from make_safety_scenarios import starts

from swarm.core.metrics import lower_bound_s
from swarm.core.packing import packing_limit_m
from swarm.core.robot import RobotParams
from swarm.core.safety import SafetyParams, body_distance_m, with_engine_margin

START_KINDS = ("uniform", "two-cluster", "strip", "ring")
GRAPHS = ("complete", "cycle", "line", "disk")
VARIANTS = (("mec_flood", True), ("pack_flood", True), ("mec_flood", False))
VARIANT_NAMES = {
    f"{controller}:{'on' if filtered else 'off'}": (controller, filtered) for controller, filtered in VARIANTS
}
RUN_TIMEOUT_S = 3600


def target_factor(count: int) -> float:
    return 1.3 if count <= 20 else 1.5


def disk_radius_m(xy: np.ndarray) -> float:
    """1.05x the longest edge of the minimum spanning tree of ``xy`` (Prim): the disk graph starts
    connected."""
    count = len(xy)
    distance = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    inside, best, longest = np.zeros(count, dtype=bool), distance[0].copy(), 0.0
    inside[0] = True
    for _ in range(count - 1):
        candidates = np.where(inside, np.inf, best)
        nxt = int(np.argmin(candidates))
        longest = max(longest, float(candidates[nxt]))
        inside[nxt] = True
        best = np.minimum(best, distance[nxt])
    return 1.05 * longest


def cell_scenario(count: int, kind: str, graph: str, controller: str, filtered: bool, threshold_m: float):
    index = START_KINDS.index(kind)
    poses = starts(kind, count, np.random.default_rng(1000 * count + index))  # make_safety_scenarios' seeds
    topology: dict = {"kind": graph}
    if graph == "disk":
        topology["radius"] = round(disk_radius_m(poses[:, :2]), 4)
    scenario = {
        "name": f"gathering-{kind}-{count}-{graph}-{controller}{'-filtered' if filtered else ''}",
        "robots": {"count": count, "init": {"poses": poses.tolist()}},
        "topology": topology,
        "controller": {"kind": controller},
        "sim": {"control_period_s": 0.05, "duration_s": 20 + 1.2 * count},
        "success": {"metric": "max_pairwise", "threshold": round(threshold_m, 4)},
    }
    if filtered:
        scenario["safety"] = {"kind": "barrier"}
    return scenario, poses


def run_cell(scenario: dict, engine: str, work: Path) -> dict:
    path = work / f"{scenario['name']}-{engine}.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    out = work / f"{scenario['name']}-{engine}"
    command = [sys.executable, "-m", "swarm.cli", "run", str(path), "--engine", engine, "--out", str(out)]
    started_s = time.perf_counter()
    try:
        done = subprocess.run(
            [*command, "--force", "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=RUN_TIMEOUT_S
        )
    except subprocess.TimeoutExpired:
        return {"exit": None, "reason": f"no result within {RUN_TIMEOUT_S} s"}
    row: dict = {"exit": done.returncode, "wall_s": round(time.perf_counter() - started_s, 1)}
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        lines = (done.stderr or done.stdout).strip().splitlines()
        return {**row, "reason": lines[-1] if lines else "no metrics.json"}
    row.update(
        final_max_pairwise_m=metrics.get("final_metric"),
        converged=metrics.get("converged"),
        convergence_time_s=metrics.get("convergence_time_s"),
        contact_ticks=metrics["contacts"]["ticks"],
        min_clearance_m=metrics.get("min_clearance_m"),
        infeasible=(metrics.get("safety_filter") or {}).get("infeasible"),
    )
    return row


def write(out: Path, rows: list[dict], command: str, stem: str = "gathering") -> None:
    (out / f"{stem}.json").write_text(json.dumps({"command": command, "cells": rows}, indent=2) + "\n")
    lines = [
        "# Gathering bodies with the barrier filter",
        "",
        f"`{command}` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; `bench/gathering.py`).",
        "One start per cell. `final / low`: the final max_pairwise over the lower end of the packing limit",
        "of discs `D_s` across (exact for N <= 8). Target: 1.3 (N <= 20), 1.5 (N = 50). `time / bound`: when",
        "the target was first met and held, over the kinematic lower bound of that threshold.",
        "",
    ]
    summary: dict = {}
    for row in rows:
        if "final_max_pairwise_m" in row:
            key = (row["engine"], row["controller"], row["filtered"], row["robots"])
            met, total = summary.get(key, (0, 0))
            summary[key] = (met + bool(row["converged"] and row["contact_ticks"] == 0), total + 1)
    lines += [
        "| engine | controller | filter | N | target met, no contact | cells |",
        "|---|---|---|---|---|---|",
    ]
    for (engine, controller, filtered, count), (met, total) in sorted(summary.items()):
        lines.append(
            f"| {engine} | {controller} | {'on' if filtered else 'off'} | {count} | {met} | {total} |"
        )
    lines += [
        "",
        "| engine | N | start | graph | controller | filter | packing low-high (m) | final (m) | final / low"
        " | met | time / bound | contact ticks | min clearance (m) | infeasible |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        head = (
            f"| {row['engine']} | {row['robots']} | {row['start']} | {row['graph']} | {row['controller']}"
            f" | {'on' if row['filtered'] else 'off'}"
            f" | {row['packing_low_m']:.3f}-{row['packing_high_m']:.3f}"
        )
        if "final_max_pairwise_m" not in row:
            lines.append(f"{head} | not run: {row.get('reason', '')} | | | | | | |")
            continue
        time_s, bound_s = row["convergence_time_s"], row["lower_bound_s"]
        ratio_t = f"{time_s / bound_s:.2f}" if time_s is not None and bound_s > 0 else ""
        clearance, infeasible, final = row["min_clearance_m"], row["infeasible"], row["final_max_pairwise_m"]
        lines.append(
            f"{head} | {final:.3f} | {final / row['packing_low_m']:.2f}"
            f" | {'yes' if row['converged'] else 'no'} | {ratio_t} | {row['contact_ticks']}"
            f" | {'' if clearance is None else f'{clearance:.3f}'}"
            f" | {'' if infeasible is None else infeasible} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")


def cell_key(row: dict) -> tuple:
    return (row["engine"], row["robots"], row["start"], row["graph"], row["controller"], row["filtered"])


def cell_order(row: dict) -> tuple:
    """The order in which ``main`` runs the cells (engine, N, start, graph, variant)."""
    place = (START_KINDS.index(row["start"]), GRAPHS.index(row["graph"]))
    return (row["engine"], row["robots"], *place, VARIANTS.index((row["controller"], row["filtered"])))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engines", nargs="*", default=["kinematic"], choices=["kinematic", "pybullet"])
    parser.add_argument("--sizes", nargs="*", type=int, default=[6, 20, 50])
    parser.add_argument("--starts", nargs="*", default=list(START_KINDS), choices=START_KINDS)
    parser.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=GRAPHS)
    parser.add_argument(
        "--paired",
        action="store_true",
        help="each start on its graph of scenarios/safety/ only (uniform-complete, two-cluster-cycle,"
        " strip-line, ring-disk), not on every graph",
    )
    parser.add_argument(
        "--variants",
        nargs="*",
        default=list(VARIANT_NAMES),
        choices=list(VARIANT_NAMES),
        help="controller:filter variants to run (default: all three)",
    )
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the cells of the existing result file that this run does not measure (its command is"
        " kept beside this one's), instead of starting the file afresh",
    )
    parser.add_argument(
        "--stem",
        default=None,
        help="name of the result files (default: gathering, or gathering_<engines> for other engines)",
    )
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    out = output_dir(args)
    robot, safety = RobotParams(), SafetyParams()
    command = "python bench/gathering.py " + " ".join(argv if argv is not None else sys.argv[1:])
    jobs = [
        (engine, count, kind, graph, controller, filtered)
        for engine in args.engines
        for count in args.sizes
        for kind in args.starts
        for graph in args.graphs
        for controller, filtered in (VARIANT_NAMES[name] for name in args.variants)
        if not args.paired or GRAPHS.index(graph) == START_KINDS.index(kind)
    ]
    default_stem = "gathering" if args.engines == ["kinematic"] else "gathering_" + "_".join(args.engines)
    stem = args.stem or default_stem
    rows, kept = [], []
    if args.merge and (out / f"{stem}.json").exists():
        previous = json.loads((out / f"{stem}.json").read_text())
        measured = set(jobs)
        kept = [row for row in previous["cells"] if cell_key(row) not in measured]
        command = f"{previous['command']}; then {command.strip()} (--merge: cells of both)"
    with tempfile.TemporaryDirectory(prefix="gathering-") as work:
        for engine, count, kind, graph, controller, filtered in progress(
            jobs, args, desc="cells", unit="cell"
        ):
            # the distance the filter keeps on this engine (its default margin: swarm.core.safety)
            spacing_m = body_distance_m(robot, with_engine_margin(safety, engine))
            low, high = packing_limit_m(count, spacing_m)
            threshold_m = target_factor(count) * low
            scenario, poses = cell_scenario(count, kind, graph, controller, filtered, threshold_m)
            row = {
                "engine": engine,
                "robots": count,
                "start": kind,
                "graph": graph,
                "controller": controller,
                "filtered": filtered,
                "packing_low_m": low,
                "packing_high_m": high,
                "threshold_m": threshold_m,
                "lower_bound_s": lower_bound_s(poses[:, :2], threshold_m, robot.v_max_mps),
            }
            row.update(run_cell(scenario, engine, Path(work)))
            rows.append(row)
            write(out, sorted([*kept, *rows], key=cell_order), command.strip(), stem)
    print(f"{len(rows)} cells: {out / (stem + '.md')}")
    return (
        0
        if all(math.isfinite(row.get("final_max_pairwise_m") or math.nan) or "reason" in row for row in rows)
        else 1
    )


if __name__ == "__main__":
    sys.exit(main())
