"""Do the controllers pack the bodies? ``scenarios/compact/`` on the PyBullet runtime.

Runs every scenario of ``scenarios/compact/`` (six robots on the thesis starts, complete / cycle /
line / random graphs, and twenty on a cycle; controllers ``mec_flood``, ``local_consensus`` and the
shipped ``gnn``) with ``swarm run`` (sim server + one process per robot, lockstep), and tables
max_pairwise at the end of each run against the packing limit of N bumpers of radius r:

- N = 6: ``2 sin 72 deg x 2 r`` (a regular pentagon of touching robots around a sixth: the smallest
  diameter of six points at least ``2 r`` apart, a classical result; our own search below finds it);
- N = 20 (no closed form): between the isodiametric bound ``2 r (sqrt N - 1)`` (N disjoint discs of
  area ``pi r^2`` lie in a set of diameter ``D + 2 r``, whose area is at most ``pi (D + 2 r)^2 / 4``)
  and the best N points of the hexagonal lattice of spacing ``2 r`` (a packing that exists).

A run that does not pack below its threshold exits 1: that is a result, not an error.

    nice -n 10 python bench/bench_compact.py --out docs/results/compact
    nice -n 10 python bench/bench_compact.py --out docs/results/compact --keep \
        --scenarios scenarios/compact/*-gnn.yaml          # re-run the GNN's rows only (a new model)
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def lattice_packing_diameter(count: int, spacing_m: float, grid: int = 40) -> float:
    """Smallest diameter of ``count`` points of the hexagonal lattice of ``spacing_m`` (the points
    nearest to a centre, over a grid of centres in one lattice cell): a packing that exists."""
    k = np.arange(-10, 11)
    a, b = np.meshgrid(k, k)
    lattice = np.stack([a + 0.5 * b, b * math.sqrt(3) / 2], axis=-1).reshape(-1, 2)
    best = math.inf
    for u in np.linspace(0.0, 1.0, grid):
        for v in np.linspace(0.0, math.sqrt(3) / 2, grid):
            distance = np.linalg.norm(lattice - (u, v), axis=1)
            chosen = lattice[np.argsort(distance, kind="stable")[:count]]
            best = min(best, float(np.max(np.linalg.norm(chosen[:, None] - chosen[None], axis=-1))))
    return best * spacing_m


def packing_limit(count: int, radius_m: float) -> dict:
    """Bounds on the smallest max_pairwise of ``count`` non-overlapping discs of ``radius_m``."""
    spacing = 2.0 * radius_m
    lower = spacing * (math.sqrt(count) - 1.0)
    upper = lattice_packing_diameter(count, spacing)
    exact = {2: spacing, 3: spacing, 4: spacing * math.sqrt(2), 5: spacing * (1 + math.sqrt(5)) / 2}
    exact[6] = spacing * 2 * math.sin(math.radians(72))
    exact[7] = 2 * spacing
    if count in exact:
        return {
            "limit_m": exact[count],
            "lower_m": exact[count],
            "upper_m": exact[count],
            "how": "known optimum",
        }
    return {
        "limit_m": None,
        "lower_m": lower,
        "upper_m": upper,
        "how": "isodiametric lower bound / best hexagonal-lattice subset",
    }


def run_one(scenario: Path, out: Path) -> dict:
    started = time.monotonic()
    process = subprocess.run(
        [
            sys.executable,
            "-m",
            "swarm.cli",
            "run",
            str(scenario),
            "--engine",
            "pybullet",
            "--out",
            str(out),
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").is_file() else {}
    return {
        "scenario": scenario.stem,
        "exit_code": process.returncode,
        "wall_s": round(time.monotonic() - started, 1),
        "robots": metrics.get("robots"),
        "controller": metrics.get("controller"),
        "threshold_m": metrics.get("threshold"),
        "converged": metrics.get("converged"),
        "convergence_time_s": metrics.get("convergence_time_s"),
        "ratio_to_lower_bound": metrics.get("ratio_to_lower_bound"),
        "final_max_pairwise_m": metrics.get("final_metric"),
        "error": process.stderr.strip().splitlines()[-1]
        if process.returncode not in (0, 1) and process.stderr
        else None,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/compact")
    parser.add_argument("--scenarios", nargs="*", help="default: every scenarios/compact/*.yaml")
    parser.add_argument(
        "--keep",
        action="store_true",
        help="keep the other scenarios' rows of --out/compact.json (re-run these)",
    )
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from swarm.scenarios.scenario import load_scenario

    paths = (
        [Path(p) for p in args.scenarios]
        if args.scenarios
        else sorted((ROOT / "scenarios/compact").glob("*.yaml"))
    )
    rows, limits = [], {}
    if args.keep and (out / "compact.json").is_file():
        kept = json.loads((out / "compact.json").read_text())
        rerun = {path.stem for path in paths}
        rows = [row for row in kept["rows"] if row["scenario"] not in rerun]
        limits = {int(count): limit for count, limit in kept["packing_limits"].items()}
    for path in paths:
        scenario = load_scenario(path)
        count, radius = scenario.robots.count, scenario.robot.body_radius_m
        if count not in limits:
            limits[count] = packing_limit(count, radius)
        print(f"running {path.name}", file=sys.stderr, flush=True)
        row = run_one(path, out / "runs" / path.stem)
        row["topology"] = scenario.topology.kind
        rows = sorted([*rows, row], key=lambda kept: kept["scenario"])
        write(out, rows, limits)
    return 0


def write(out: Path, rows: list[dict], limits: dict) -> None:
    (out / "compact.json").write_text(json.dumps({"rows": rows, "packing_limits": limits}, indent=2) + "\n")

    def limit_text(count: int) -> str:
        limit = limits[count]
        if limit["limit_m"] is not None:
            return f"{limit['limit_m']:.3f}"
        return f"{limit['lower_m']:.3f}-{limit['upper_m']:.3f}"

    lines = [
        "PyBullet runtime (sim server + one agent process per robot, lockstep), bumper radius 0.12 m.",
        "max_pairwise at the end of the run against the packing limit of N bumpers",
        "(`bench/bench_compact.py`: N = 6 the known optimum 2 sin 72 deg x 0.24 m; N = 20 between the",
        "isodiametric bound and the best hexagonal-lattice subset). Exit 1: the robots did not stay under",
        "the threshold (an honest result).",
        "",
        "| scenario | graph | N | controller | threshold (m) | final max_pairwise (m) | packing limit (m) "
        "| final / limit | converged at (s) | t / LB | exit |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        count = row["robots"] or 0
        final = row["final_max_pairwise_m"]
        limit = limits.get(count, {})
        reference = limit.get("limit_m") or limit.get("upper_m")
        over = f"{final / reference:.2f}" if final is not None and reference else "-"

        def fmt(value, digits=2):
            return "-" if value is None else f"{value:.{digits}f}"

        lines.append(
            f"| {row['scenario']} | {row['topology']} | {count} | {row['controller']} "
            f"| {fmt(row['threshold_m'])} "
            f"| {fmt(final, 3)} | {limit_text(count) if count in limits else '-'} | {over} "
            f"| {fmt(row['convergence_time_s'])} | {fmt(row['ratio_to_lower_bound'])} | {row['exit_code']} |"
        )
    (out / "compact.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
