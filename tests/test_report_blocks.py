"""``swarm report`` keeps what only the run could measure: the ``processes`` and ``runtime`` blocks of
``metrics.json``, and, for a run interrupted before writing them, reads them back from the processes'
own files (``server_stats.json``, ``logs/agent_<i>.json``). Real runs: sim server, agents, Zenoh."""

from __future__ import annotations

import json
import signal
import subprocess
import sysconfig
import time
from pathlib import Path

import pytest

from swarm.cli import main

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SCENARIO = PROJECT_ROOT / "scenarios" / "thesis" / "cycle-local_consensus.yaml"
SWARM = str(Path(sysconfig.get_path("scripts")) / "swarm")


def default_sigint() -> None:
    """In the child: SIGINT's default action (a suite run in the background ignores it, and an ignored
    signal is inherited: tests/test_interrupt_startup.py)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


@pytest.mark.runtime
def test_report_keeps_the_runtime_and_processes_blocks(tmp_path):
    out = tmp_path / "run"
    assert main(["run", str(SCENARIO), "--duration", "1", "--out", str(out), "--quiet"]) in (0, 1)
    before = metrics(out)
    assert (
        before["runtime"]["command_latency_ms"]["count"] > 0 and len(before["processes"]["agent_pids"]) == 6
    )
    assert main(["report", str(out), "--quiet"]) in (0, 1)
    after = metrics(out)
    assert after["runtime"] == before["runtime"] and after["processes"] == before["processes"]


@pytest.mark.runtime
def test_an_interrupted_run_has_the_blocks_from_the_processes_files(tmp_path):
    out = tmp_path / "run"
    process = subprocess.Popen(
        [SWARM, "run", str(SCENARIO), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
        preexec_fn=default_sigint,  # SIGINT as from a terminal, even when the suite runs in the background
    )
    trajectory, deadline = out / "trajectory.jsonl", time.monotonic() + 120
    while not (trajectory.is_file() and trajectory.read_text().count("\n") > 20):
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()
        time.sleep(0.02)
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=60)
    assert process.returncode == 130
    agents = {i: json.loads((out / "logs" / f"agent_{i}.json").read_text()) for i in range(6)}
    outcome = metrics(out)
    assert outcome["partial"] is True
    assert outcome["processes"]["agent_pids"] == {str(i): agents[i]["pid"] for i in range(6)}
    received = sum(agent["messages"]["received"] for agent in agents.values())
    assert received > 0 and outcome["runtime"]["messages_received"] == received
    assert main(["report", str(out), "--quiet"]) == 1  # incomplete
    assert metrics(out)["runtime"] == outcome["runtime"]
