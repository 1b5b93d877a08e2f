"""Every scenario under ``scenarios/`` with the barrier filter on, in both engines: contacts and clearance.

    .venv/bin/python bench/safety_every_scenario.py [--engines kinematic pybullet] [--update-results]

For each scenario file, the scenario as it is plus ``safety: {kind: barrier}`` (a scenario that has its
own ``safety`` keeps it; where the defaults do not fit the robot and control period, the sensing radius
is raised to 1.2x its least value and the gain lowered to ``1 / control_period_s``, as the scenario
check demands), run with ``swarm run --engine E`` as a user would (one process per robot on PyBullet).
A run the runner refuses (exit 2: e.g. a disk graph on PyBullet, a ROS 2 scenario) is listed with its
one-line reason; nothing is skipped silently. Reported per run: exit status, contact ticks (PyBullet:
its own contact points at every substep; kinematic: overlaps), the smallest clearance, the filter's
changed, infeasible and (PyBullet) missing-reading robot-ticks.

Writes ``safety_every_scenario.json`` and ``.md`` to ``--out`` (default ``runs/bench/``) or
``bench/results/``. Exit status 0 when every run that ran had 0 contact ticks and a non-negative
clearance, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _output import ROOT, add_output_arguments, output_dir, progress

from swarm.core.safety import SafetyParams, min_sensing_radius_m
from swarm.scenarios.scenario import ScenarioError, parse_scenario, resolve_model_path

SCENARIOS = ROOT / "scenarios"
RUN_TIMEOUT_S = 1800


def filtered(data: dict) -> dict:
    """The scenario with the barrier filter on, its settings fitted to the robot and control period."""
    if data.get("safety") is not None:
        return data
    base = parse_scenario(data)
    period_s = base.sim.control_period_s
    least = min_sensing_radius_m(base.robot, SafetyParams(), period_s)
    safety: dict = {"kind": "barrier"}
    if SafetyParams().sensing_radius_m < least:
        safety["sensing_radius_m"] = round(1.2 * least, 3)
    if SafetyParams().gain_per_s * period_s > 1.0:
        safety["gain_per_s"] = 1.0 / period_s
    return {**data, "safety": safety}


def run_one(path: Path, engine: str, work: Path) -> dict:
    name = str(path.relative_to(SCENARIOS))
    row: dict = {"scenario": name, "engine": engine}
    try:
        data = filtered(yaml.safe_load(path.read_text()))
        model = (data.get("controller") or {}).get("model")
        if model is not None and not Path(model).is_absolute():  # the copy lives elsewhere
            resolved = resolve_model_path(model, path)
            data = {**data, "controller": {**data["controller"], "model": str(resolved.resolve())}}
    except ScenarioError as error:
        return {**row, "exit": 2, "reason": str(error).splitlines()[0]}
    scenario_file = work / f"{name.replace('/', '__')}-{engine}.yaml"
    scenario_file.write_text(yaml.safe_dump(data, sort_keys=False))
    out = work / f"{name.replace('/', '__')}-{engine}"
    command = [sys.executable, "-m", "swarm.cli", "run", str(scenario_file), "--engine", engine]
    command += ["--out", str(out), "--force", "--quiet"]
    started_s = time.perf_counter()
    try:
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {**row, "exit": None, "reason": f"no result within {RUN_TIMEOUT_S} s"}
    row.update(exit=done.returncode, wall_s=round(time.perf_counter() - started_s, 1))
    try:
        metrics = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        lines = (done.stderr or done.stdout).strip().splitlines()
        return {**row, "reason": lines[-1] if lines else "no metrics.json"}
    counts = metrics.get("safety_filter") or {}
    row.update(
        robots=data["robots"]["count"],
        converged=metrics.get("converged"),
        contact_ticks=metrics["contacts"]["ticks"],
        robot_robot=metrics["contacts"]["robot_robot"],
        robot_obstacle=metrics["contacts"]["robot_obstacle"],
        min_clearance_m=metrics.get("min_clearance_m"),
        interventions=counts.get("interventions"),
        infeasible=counts.get("infeasible"),
        missing=counts.get("missing"),
    )
    return row


def write(out: Path, rows: list[dict], command: str) -> None:
    (out / "safety_every_scenario.json").write_text(json.dumps({"command": command, "runs": rows}, indent=2))
    ran = [row for row in rows if "contact_ticks" in row]
    clean = [row for row in ran if row["contact_ticks"] == 0 and (row["min_clearance_m"] or 0) >= 0]
    lines = [
        "# The barrier filter on every scenario",
        "",
        f"`{command}` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). Every scenario under",
        "`scenarios/` with `safety: {kind: barrier}` added, in each engine",
        "(`bench/safety_every_scenario.py`).",
        f"{len(ran)} runs ran, {len(clean)} of them with 0 contact ticks and a non-negative clearance;",
        f"{len(rows) - len(ran)} refused or failed (their reason below).",
        "",
        "| scenario | engine | N | exit | converged | contact ticks | min clearance (m) | changed"
        " | infeasible | missing readings | wall (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        if "contact_ticks" not in row:
            lines.append(
                f"| {row['scenario']} | {row['engine']} | | {row['exit']} | not run: {row.get('reason', '')}"
                " | | | | | | |"
            )
            continue
        clearance, missing = row["min_clearance_m"], row["missing"]
        lines.append(
            f"| {row['scenario']} | {row['engine']} | {row['robots']} | {row['exit']} | {row['converged']}"
            f" | {row['contact_ticks']} | {'' if clearance is None else f'{clearance:.3f}'}"
            f" | {row['interventions']} | {row['infeasible']} | {'' if missing is None else missing}"
            f" | {row['wall_s']} |"
        )
    (out / "safety_every_scenario.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--engines", nargs="*", default=["kinematic", "pybullet"], choices=["kinematic", "pybullet"]
    )
    parser.add_argument("--only", nargs="*", help="scenario folders or files under scenarios/ (default: all)")
    add_output_arguments(parser)
    args = parser.parse_args(argv)
    out = output_dir(args)
    paths = sorted(SCENARIOS.rglob("*.yaml"))
    if args.only:
        paths = [p for p in paths if any(str(p.relative_to(SCENARIOS)).startswith(o) for o in args.only)]
    jobs = [(path, engine) for path in paths for engine in args.engines]
    command = "python bench/safety_every_scenario.py " + " ".join(argv if argv is not None else sys.argv[1:])
    rows = []
    with tempfile.TemporaryDirectory(prefix="safety-every-") as work:
        for path, engine in progress(jobs, args, desc="runs", unit="run"):
            rows.append(run_one(path, engine, Path(work)))
            write(out, rows, command.strip())
    ran = [row for row in rows if "contact_ticks" in row]
    dirty = [row for row in ran if row["contact_ticks"] or (row["min_clearance_m"] or 0) < 0]
    print(f"{len(ran)} runs, {len(dirty)} with contacts; {len(rows) - len(ran)} not run: {out}")
    return 1 if dirty else 0


if __name__ == "__main__":
    sys.exit(main())
