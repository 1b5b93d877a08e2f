"""Ctrl-C while ``swarm run`` starts up: at any moment one line, exit 130, and once the scenario is
read a results directory with the scenario and partial metrics marked incomplete (no tick yet).

The real console script runs in a subprocess (a real SIGINT, real imports, a real PyBullet start-up).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SCENARIO = PROJECT_ROOT / "scenarios" / "thesis" / "cycle-local_consensus.yaml"
SWARM = str(Path(sysconfig.get_path("scripts")) / "swarm")


def default_sigint() -> None:
    """In the child: SIGINT's default action. A suite started in the background (``cmd &``) ignores
    SIGINT, and an ignored signal is inherited: a Ctrl-C test would see nothing happen."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [SWARM, "run", str(SCENARIO), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
        preexec_fn=default_sigint,  # SIGINT as from a terminal, even when the suite runs in the background
    )


@pytest.mark.runtime
def test_ctrl_c_before_the_first_tick_leaves_the_scenario_and_partial_metrics(tmp_path):
    out = tmp_path / "run"
    process = start(out)
    deadline = time.monotonic() + 60
    while not (out / "scenario.yaml").is_file():  # the scenario is read; the processes start now
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.01)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, (stdout, stderr)
    assert stderr.strip().splitlines() == ["swarm run: interrupted"], stderr
    assert not (out / "trajectory.jsonl").is_file() or (out / "trajectory.jsonl").stat().st_size == 0
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["partial"] is True and outcome["ticks"] == 0 and outcome["converged"] is False
    assert "before the first tick" in outcome["incomplete"]
    assert outcome["scenario"] == "thesis-cycle-6-local_consensus" and outcome["robots"] == 6
    assert outcome["lower_bound_s"] > 0  # what the initial poses tell
    assert "PARTIAL: interrupted (Ctrl-C) during start-up" in stdout


ENTRY = "import sys; print('up', flush=True); from swarm.cli import main; sys.exit(main(sys.argv[1:]))"
"""The console script's code with a mark when the interpreter is up: a signal before that lands in
Python's own start-up (its site module), which no program can catch."""


@pytest.mark.runtime
@pytest.mark.parametrize("after_s", [0.2, 0.6, 1.2])
def test_ctrl_c_during_the_imports_is_one_line_and_130(tmp_path, after_s):
    process = subprocess.Popen(
        [sys.executable, "-c", ENTRY, "run", str(SCENARIO), "--out", str(tmp_path / "run"), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
        preexec_fn=default_sigint,  # SIGINT as from a terminal, even when the suite runs in the background
    )
    assert process.stdout is not None and process.stdout.readline() == "up\n"
    time.sleep(after_s)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, (stdout, stderr)
    assert "Traceback" not in stderr, stderr
    assert stderr.strip().splitlines() == ["swarm run: interrupted"], stderr
