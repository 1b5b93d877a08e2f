"""Formation and coverage in the PyBullet runtime under faults: every scenario of ``scenarios/tasks/``.

Each is run with ``swarm run`` (one agent process per robot, real Zenoh sessions); the table gives its
exit status, whether the task's own rule was met (every slot one robot; H within 1.05 H_ref held 2 s,
every robot's body judged), the final metric, the scheduled faults and the messages lost to them, and
what the run's summary names beside them (agents lost, messages lost outside the schedule).

    python bench/task_faults.py --out bench/results
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def run_one(path: Path, work: Path) -> dict:
    out = work / path.stem
    code = subprocess.call(
        [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(out), "--quiet"],
        cwd=PROJECT_ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    metrics_path = out / "metrics.json"
    if not metrics_path.exists():
        return {"scenario": path.stem, "exit": code, "converged": None}
    metrics = json.loads(metrics_path.read_text())
    faults = metrics.get("faults") or {}
    messages = faults.get("messages") or {}
    return {
        "scenario": path.stem,
        "task": metrics.get("task"),
        "exit": code,
        "converged": metrics.get("converged"),
        "convergence_time_s": metrics.get("convergence_time_s"),
        "final_metric": metrics.get("final_metric"),
        "metric": metrics.get("metric"),
        "conflicts": metrics.get("conflicts"),
        "scheduled": [fault["kind"] for fault in faults.get("scheduled", [])],
        "lost_by_fault": messages.get("lost_by_fault"),
        "dropped_by_fault": messages.get("dropped_by_fault"),
        "lost": messages.get("lost"),
        "agents_lost": faults.get("agents_lost"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=PROJECT_ROOT / "bench" / "results")
    parser.add_argument("scenarios", nargs="*", type=Path, help="default: every scenarios/tasks/*.yaml")
    args = parser.parse_args(argv)
    paths = args.scenarios or sorted((PROJECT_ROOT / "scenarios" / "tasks").glob("*.yaml"))
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for index, path in enumerate(paths):
            row = run_one(path, Path(work))
            rows.append(row)
            print(f"[{index + 1}/{len(paths)}] {json.dumps(row)}", file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "task_faults.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [
        "Formation and coverage on PyBullet under faults: `python bench/task_faults.py --out bench/results`.",
        "",
        "| scenario | exit | met | from (s) | final metric | faults | lost by fault | lost (all)"
        " | agents lost |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        final, metric = row.get("final_metric"), row.get("metric")
        time_s = row.get("convergence_time_s")
        final_text = "-" if final is None else f"{metric} {final:.3f}"
        lines.append(
            f"| {row['scenario']} | {row['exit']} | {row['converged']} | "
            f"{'-' if time_s is None else f'{time_s:.2f}'} | "
            f"{final_text} | "
            f"{', '.join(row.get('scheduled') or [])} | {row.get('lost_by_fault')} | {row.get('lost')} | "
            f"{row.get('agents_lost')} |"
        )
    (args.out / "task_faults.md").write_text("\n".join(lines) + "\n")
    return 0 if all(row["exit"] in (0, 1) for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
