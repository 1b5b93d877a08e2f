"""Ticks that cannot be forged forward (swarm/runtime/ticks.py), checked from outside.

A separate process that imports none of the project's code (``tests/outside.py``) joins a real lockstep
run and puts, once each, a genuine sample it received with its tick moved 10^6 ahead: robot 5's pose,
agent 2's message and robot 3's command. It does not hold the run key, so each receiver must count it
as *unauthenticated* (its tag no longer matches: swarm.runtime.wire.RunKey) and go on: the
trajectory (poses and applied wheels, every tick) must equal that of the same run without the forger.
Under access control the forger holds robot 0's real credentials and forges what it may put: its own
message and command keys (a pose on robot 0's key is refused by the router); the trajectory must still
equal the clean run's (access control does not change a lockstep trajectory).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
import swarm_run
import yaml

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out

PROJECT_ROOT = Path(__file__).resolve().parent.parent
OUTSIDE = PROJECT_ROOT / "tests" / "outside.py"
AHEAD = 10**6
COUNT = 6
DURATION_S = 5.0
AT_TICK = 20


def _scenario(tmp_path: Path, acl: bool) -> Path:
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-local_consensus.yaml").read_text())
    data["robots"]["count"] = COUNT
    data["sim"].update(duration=DURATION_S, acl=acl)
    # A deadline no loaded machine misses: a tick then waits only for what never comes (a frozen
    # robot, a cut link), and lockstep trajectories stay comparable.
    data["sim"].update(deadline=3.0, neighbour_deadline=3.0)
    path = tmp_path / f"forged-{'acl' if acl else 'open'}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _run_key_of_the_server(out: Path, timeout_s: float = 120.0) -> str:
    """The run key from the environment of this run's sim server process (what an insider on a
    robot's host can read): found in /proc by its ``--out`` argument."""
    deadline_s = time.monotonic() + timeout_s
    while time.monotonic() < deadline_s:
        for proc in Path("/proc").iterdir():
            try:
                argv = (proc / "cmdline").read_bytes().split(b"\0")
                if b"sim_server" in argv and str(out).encode() in argv:
                    environ = (proc / "environ").read_bytes().split(b"\0")
                    key = next(e for e in environ if e.startswith(b"SWARM_RUN_KEY="))
                    return key.split(b"=", 1)[1].decode()
            except (OSError, StopIteration):
                continue
        time.sleep(0.05)
    raise AssertionError(f"no sim server process for {out}")


def _run(
    scenario: Path, out: Path, forge: list[str] | None, credentials: bool = False, insider: bool = False
) -> tuple[dict, list]:
    run = swarm_run.start(scenario, out)
    sent = None
    try:
        if forge is not None:  # started at once, beside the run: it connects while the agents start
            sent_path = out.parent / f"{out.name}-sent.json"
            command = [
                sys.executable,
                str(OUTSIDE),
                "forge",
                "--server-log",
                str(out / "logs" / "sim_server.log"),
            ]
            command += ["--at-tick", str(AT_TICK), "--ahead", str(AHEAD), *forge]
            if credentials:
                command += ["--credentials", str(out / "credentials" / "robot-0.cred"), "--blind"]
            if insider:
                command += ["--run-key", _run_key_of_the_server(out)]
            forger = subprocess.run(
                [*command, "--out", str(sent_path)], capture_output=True, text=True, timeout=240
            )
            assert forger.returncode == 0, forger.stderr
            sent = json.loads(sent_path.read_text())["sent"]
        _, stderr = run.communicate(timeout=240)
    finally:
        if run.poll() is None:
            run.kill()
    assert run.returncode == 0, stderr
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    return {"sent": sent, "metrics": json.loads((out / "metrics.json").read_text())}, lines


def _records(out: Path) -> dict[int, dict]:
    paths = (out / "logs").glob("agent_*.json")
    return {int(path.stem.split("_")[1]): json.loads(path.read_text()) for path in paths}


def _same_trajectory(a: list, b: list) -> None:
    assert len(a) == len(b) == round(DURATION_S / 0.05) + 1
    for line_a, line_b in zip(a, b, strict=True):
        assert line_a["tick"] == line_b["tick"]
        assert line_a["poses"] == line_b["poses"], line_a["tick"]
        assert line_a.get("wheels") == line_b.get("wheels"), line_a["tick"]


def test_forward_dated_samples_change_nothing_with_and_without_access_control(tmp_path):
    _, clean = _run(_scenario(tmp_path, acl=False), tmp_path / "clean", None)

    out = tmp_path / "forged"
    result, forged = _run(_scenario(tmp_path, acl=False), out, ["--pose", "5", "--msg", "2", "--cmd", "3"])
    assert sorted(result["sent"]) == ["cmd", "msg", "pose"], result["sent"]
    assert all(item["tick"] >= AHEAD for item in result["sent"].values())
    _same_trajectory(clean, forged)
    records = _records(out)
    stats = json.loads((out / "server_stats.json").read_text())
    # The forger does not hold the run key: its samples fail their tag before their tick is read.
    assert records[5]["poses"]["unauthenticated"] == 1 and records[5]["poses"]["jumps"] == 0
    assert [records[i]["messages"]["unauthenticated"] for i in range(COUNT)] == [0, 1, 0, 1, 0, 0]
    assert stats["unauthenticated_commands"] == 1 and stats["ticks_missed"] == 0
    rejected = result["metrics"]["runtime"]["rejected"]
    assert rejected["unauthenticated"] == {"poses": 1, "messages": 2, "commands": 1, "readings": 0}
    assert rejected["future"] == {"poses": 0, "messages": 0, "commands": 0}
    for i, agent in records.items():  # nobody froze: every agent computed every tick
        assert agent["ticks"] == len(clean) - 1 and agent["messages"]["lost"] == 0, (i, agent)

    out = tmp_path / "acl"
    result, with_acl = _run(
        _scenario(tmp_path, acl=True), out, ["--pose", "0", "--msg", "0", "--cmd", "0"], credentials=True
    )
    _same_trajectory(clean, with_acl)
    records = _records(out)
    stats = json.loads((out / "server_stats.json").read_text())
    assert [records[i]["messages"]["unauthenticated"] for i in range(COUNT)] == [0, 1, 0, 0, 0, 1]
    assert records[0]["poses"]["unauthenticated"] == 0  # the router refused the forged pose
    assert stats["unauthenticated_commands"] == 1 and stats["ticks_missed"] == 0


def test_forward_dated_samples_signed_with_the_run_key_are_refused_by_their_tick(tmp_path):
    """An insider (the run key read from a process's environment on a robot's host) signs its
    forward-dated samples: they pass authentication, and the tick window (swarm/runtime/ticks.py) and
    the server's command check are what refuse them; nothing changes."""
    _, clean = _run(_scenario(tmp_path, acl=False), tmp_path / "clean", None)
    out = tmp_path / "insider"
    result, forged = _run(
        _scenario(tmp_path, acl=False), out, ["--pose", "5", "--msg", "2", "--cmd", "3"], insider=True
    )
    assert sorted(result["sent"]) == ["cmd", "msg", "pose"], result["sent"]
    _same_trajectory(clean, forged)
    records = _records(out)
    stats = json.loads((out / "server_stats.json").read_text())
    assert records[5]["poses"]["unauthenticated"] == 0 and records[5]["poses"]["future"] == 1
    assert [records[i]["messages"]["future"] for i in range(COUNT)] == [0, 1, 0, 1, 0, 0]
    assert stats["future_commands"] == 1 and stats["unauthenticated_commands"] == 0
    rejected = result["metrics"]["runtime"]["rejected"]
    assert rejected["future"] == {"poses": 1, "messages": 2, "commands": 1}
    assert rejected["unauthenticated"] == {"poses": 0, "messages": 0, "commands": 0, "readings": 0}


def test_a_forward_dated_pose_does_not_freeze_the_centralized_controller(tmp_path):
    path = _scenario(tmp_path, acl=False)
    data = yaml.safe_load(path.read_text())
    data["controller"] = {"kind": "centralized", "gain": 1.0}
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "central"
    result, lines = _run(path, out, ["--pose", "4"])
    assert sorted(result["sent"]) == ["pose"]
    record = json.loads((out / "logs" / "central.json").read_text())
    stats = json.loads((out / "server_stats.json").read_text())
    assert record["poses_unauthenticated"] == 1 and record["ticks"] == len(lines) - 1, record
    assert stats["ticks_missed"] == 0
