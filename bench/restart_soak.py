"""``scenarios/faults/restart-agent.yaml`` many times in a row: does the restarted agent drive again?

Each run is ``python -m swarm.cli run scenarios/faults/restart-agent.yaml`` as a user starts it. A run
*passes* when ``swarm run`` exits 0, ``metrics.json`` names no restarted agent that never came back
(``faults.agents_restarted_never_back`` empty, ``health.failures`` empty), and the record
``logs/agent_0.json`` is the new process's (its pid is the one of the ``restart_agent`` event in
``events.jsonl``) with a first tick after the restart and ticks computed. From the trajectory it also
checks that robot 0's wheels are not zero in the last tenth of the ticks before convergence stops it:
the new agent's commands arrived (it does not judge from the agent's own counters alone).

Run: ``nice -n 10 python bench/restart_soak.py --runs 50 --update-results`` (about 15-25 s a run on a
loaded machine); writes ``restart_soak.json`` (every run: exit status, wall time, what failed) and
prints the count.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from _output import DEFAULT_OUT, ROOT, add_output_arguments, output_dir

SCENARIO = ROOT / "scenarios" / "faults" / "restart-agent.yaml"


def check(out: Path, code: int) -> list[str]:
    """What went wrong in one run (empty: it passed)."""
    problems = []
    if code != 0:
        problems.append(f"exit {code}")
    try:
        metrics = json.loads((out / "metrics.json").read_text())
        record = json.loads((out / "logs" / "agent_0.json").read_text())
        events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]
        lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    except (OSError, ValueError) as error:
        return [*problems, f"unreadable results: {error}"]
    if metrics.get("faults", {}).get("agents_restarted_never_back"):
        problems.append(
            "agents_restarted_never_back: " + str(metrics["faults"]["agents_restarted_never_back"])
        )
    problems += [f"health: {why}" for why in metrics.get("health", {}).get("failures", [])]
    restart = [e for e in events if e.get("kind") == "restart_agent"]
    if len(restart) != 1:
        return [*problems, f"{len(restart)} restart_agent events"]
    if record.get("pid") != restart[0].get("pid"):
        problems.append("logs/agent_0.json is not the new agent's")
    first_tick = record.get("first_tick")
    if not isinstance(first_tick, int) or first_tick < restart[0]["tick"] or not record.get("ticks"):
        problems.append(
            f"new agent: first_tick {first_tick}, ticks {record.get('ticks')}, {record.get('exit_reason')}"
        )
    moving_after = [i for i, line in enumerate(lines) if "wheels" in line and any(line["wheels"][0])]
    if (
        not moving_after or moving_after[-1] <= restart[0]["tick"] + 20
    ):  # past the watchdog of the old command
        problems.append("robot 0 never moved after its restart (trajectory wheels)")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50)
    add_output_arguments(parser)
    args = parser.parse_args()
    out_dir = output_dir(args)
    rows = []
    for index in range(args.runs):
        run_dir = DEFAULT_OUT / "restart_soak_runs" / f"run{index:03d}"  # untracked scratch (runs/)
        start_s = time.perf_counter()
        result = subprocess.run(
            [sys.executable, "-m", "swarm.cli", "run", str(SCENARIO), "--out", str(run_dir), "--quiet"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        problems = check(run_dir, result.returncode)
        if not problems:
            shutil.rmtree(run_dir, ignore_errors=True)  # a failing run's directory is kept to look at
        rows.append(
            {
                "run": index,
                "exit": result.returncode,
                "wall_s": round(time.perf_counter() - start_s, 2),
                "problems": problems,
            }
        )
        passed = sum(not row["problems"] for row in rows)
        if not args.quiet:
            print(
                f"run {index + 1}/{args.runs}: {problems or 'ok'} ({passed} passed)",
                flush=True,
            )
        summary = {
            "command": f"python bench/restart_soak.py --runs {args.runs}",
            "scenario": str(SCENARIO.relative_to(ROOT)),
            "runs": len(rows),
            "passed": passed,
            "rows": rows,
        }
        (out_dir / "restart_soak.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"{passed} of {len(rows)} runs: the restarted agent drove robot 0 again")
    return 0 if passed == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
