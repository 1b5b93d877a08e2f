"""The README's test command, run again and again beside busy loops: does the suite pass on a loaded
machine (issue 18: "the README test command passes 5 of 5 runs with two busy loops beside it")?

Each run is ``CI=true .venv/bin/python -m pytest -n 2`` from the project root (what ``.ci/run`` runs
after its set-up), with ``--busy`` processes spinning ``while True: pass`` for the whole of it. The
result names every run: exit status, wall time, the pytest summary line and the failing tests.

Run: ``python bench/loaded_suite.py --runs 5 --busy 2`` (about 15 min a run on 2 cores). Writes
``bench/results/loaded_suite.md`` and ``.json``; exit 0 when every run passed, 1 otherwise, 2 for bad
arguments, 130 when interrupted (the runs so far are written).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import re
import subprocess
import sys
import time
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent
RESULTS = PROJECT_ROOT / "bench" / "results"


def _spin() -> None:
    while True:
        pass


def run_once(index: int, busy: int, log_dir: Path) -> dict:
    """One suite run beside ``busy`` spinning processes; its output goes to ``log_dir``."""
    spinners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(busy)]
    for spinner in spinners:
        spinner.start()
    log = log_dir / f"loaded_suite_run{index}.log"
    started = time.monotonic()
    try:
        with log.open("w") as out:
            code = subprocess.call(
                [str(PROJECT_ROOT / ".venv" / "bin" / "python"), "-m", "pytest", "-n", "2"],
                cwd=PROJECT_ROOT,
                env={**os.environ, "CI": "true"},
                stdout=out,
                stderr=subprocess.STDOUT,
            )
    finally:
        for spinner in spinners:
            spinner.terminate()
            spinner.join()
    wall_s = time.monotonic() - started
    text = log.read_text(errors="replace")
    summary = [line for line in text.splitlines() if re.search(r"\d+ (passed|failed)", line)]
    failed = sorted(set(re.findall(r"^FAILED (\S+)", text, re.MULTILINE)))
    return {
        "run": index,
        "exit": code,
        "wall_s": round(wall_s, 1),
        "summary": summary[-1].strip("= ") if summary else "",
        "failed": failed,
        "load_1min_after": round(os.getloadavg()[0], 2),
    }


def write(runs: list[dict], args: argparse.Namespace, commit: str, out: Path) -> None:
    passed = sum(run["exit"] == 0 for run in runs)
    out.with_suffix(".json").write_text(
        json.dumps({"commit": commit, "busy": args.busy, "runs": runs, "passed": passed}, indent=2) + "\n"
    )
    lines = [
        "# The README's test command on a loaded machine",
        "",
        f"`python bench/loaded_suite.py --runs {args.runs} --busy {args.busy}` at commit {commit}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, on {os.cpu_count()} cores: each run is "
        f"`CI=true .venv/bin/python -m pytest -n 2` beside {args.busy} processes spinning all the time.",
        "",
        "| run | exit | wall time | pytest | failed tests |",
        "|---|---|---|---|---|",
    ]
    for run in runs:
        minutes, seconds = divmod(int(run["wall_s"]), 60)
        lines.append(
            f"| {run['run']} | {run['exit']} | {minutes} min {seconds:02d} s | {run['summary']} | "
            f"{', '.join(run['failed']) or '-'} |"
        )
    lines += ["", f"{passed} of {len(runs)} runs passed.", ""]
    out.with_suffix(".md").write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="how many suite runs (default 5)")
    parser.add_argument("--busy", type=int, default=2, help="spinning processes beside each (default 2)")
    parser.add_argument("--out", type=Path, default=RESULTS / "loaded_suite", help="results, no suffix")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.busy < 0:
        parser.error("--runs must be at least 1 and --busy at least 0")
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=PROJECT_ROOT, capture_output=True, text=True
    ).stdout.strip()
    # its own result files do not make the tree dirty (a second invocation finds the first one's)
    status = [
        "git",
        "status",
        "--porcelain",
        "--untracked-files=no",
        "--",
        ".",
        ":!bench/results/loaded_suite.*",
    ]
    dirty = subprocess.run(status, cwd=PROJECT_ROOT, capture_output=True, text=True).stdout.strip()
    commit += "+changes" if dirty else ""
    args.out.parent.mkdir(parents=True, exist_ok=True)
    log_dir = PROJECT_ROOT / "runs"
    log_dir.mkdir(exist_ok=True)
    runs: list[dict] = []
    try:
        for index in range(1, args.runs + 1):
            runs.append(run_once(index, args.busy, log_dir))
            print(json.dumps(runs[-1]), flush=True)
            write(runs, args, commit, args.out)
    except KeyboardInterrupt:
        write(runs, args, commit, args.out)
        print("interrupted", file=sys.stderr)
        return 130
    return 0 if all(run["exit"] == 0 for run in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
