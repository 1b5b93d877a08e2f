"""The runtime-limit benchmark's stand-ins (``bench/bare_agent.py --role stand-in`` and ``answer``): with no
``robot_agent`` process at all, a sim server started alone runs a real run to its end on their commands."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import bare_agent
import runtime_limit
import yaml

from swarm.scenarios.results import read_trajectory

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out


@pytest.mark.parametrize("role", ["stand-in", "answer"])
def test_stand_in_agents_drive_a_real_lockstep_run_to_the_end(tmp_path: Path, role: str) -> None:
    count, duration_s = 3, 3.0
    steps = round(duration_s / 0.05)
    data = runtime_limit.scenario_data(count, "lockstep", duration_s, None, None, seed=2)
    data["sim"]["deadline"] = 60.0  # a stalled process is waited for: every tick served is then causal
    scenario = tmp_path / "limit.yaml"
    scenario.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    result = runtime_limit.run_standin(scenario, out, steps, 200.0, role, agent_nice=0)
    assert "error" not in result, result
    stats = json.loads((out / "server_stats.json").read_text())
    # the server waited for their tokens and got, every tick, every agent's command of that tick,
    # each decoded by the real decoder (swarm.runtime.wire.decode_command in the server)
    assert stats["exit"] == "done"
    assert sorted(e["robot"] for e in stats["agent_events"] if e["event"] == "alive") == list(range(count))
    assert stats["ticks_served"] == stats["ticks"] == steps
    assert stats["latency_ms"]["count"] == count * steps
    assert stats["invalid_commands"] == stats["late_commands"] == stats["future_commands"] == 0
    assert stats["old_commands"] == 0
    records = [json.loads(p.read_text()) for p in sorted((out / "logs").glob("floor_*.json"))]
    assert [r["role"] for r in records] == [role] * count
    assert [(r["first_tick"], r["last_tick"], r["ticks"]) for r in records] == [(0, steps - 1, steps)] * count
    assert all(r["exit_reason"] == "done" for r in records)
    assert result["agents_at_last_tick"] == count and result["served_share"] == 1.0
    # and the server applied those commands: the trajectory is complete and the robots moved as told
    times_s, _, _ = read_trajectory(out / "trajectory.jsonl")
    assert len(times_s) == steps + 1
    lines = (out / "trajectory.jsonl").read_text().splitlines()
    wheels = [json.loads(line)["wheels"] for line in lines[:-1]]
    if role == "answer":
        assert all(w == [list(bare_agent.ANSWER_WHEELS_MPS)] * count for w in wheels)
    else:
        assert any(any(v != 0.0 for pair in w for v in pair) for w in wheels)
