"""The floor benchmark (bench/bare_agent.py beside the real agents of one ``swarm run``): real processes."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench" / "investigations"))

import bench_runtime
import pytest


@pytest.mark.runtime
def test_bare_agents_shadow_every_tick_with_the_real_payloads(tmp_path: Path) -> None:
    # 1200 lockstep ticks: the run (which waits for its real agents only) must not end before the
    # bare agents, started beside it once the server's address is in its log, are up on a loaded machine
    count, duration_s = 3, 60.0
    steps = round(duration_s / 0.05)
    data = bench_runtime.scenario_data(count, "lockstep", duration_s, None, None, seed=2)
    scenario = tmp_path / "floor.yaml"
    scenario.write_text(bench_runtime.yaml.safe_dump(data))
    # the window closes at mid-run: the edge is judged on commands counted by a consumer that may lag
    # on a loaded machine, and the agents must still be there when it closes (CI once sampled them
    # after they had exited, at an edge 60 ticks before the end: a negative CPU per tick)
    floor = bench_runtime.Floor(count, tmp_path / "bare", steps // 5, steps // 2)
    result = bench_runtime.run_once(scenario, tmp_path / "run", steps, 200.0, None, floor)
    assert "error" not in result, result
    measured = result["floor"]
    assert "error" not in measured, measured["error"]
    assert measured["bare_agents_ran"] == measured["bare_agents"] == measured["real_agents"] == count
    # every command a bare agent put passes the real decoder: the same payload layout as robot_agent's
    assert measured["bare_commands"] > 0 and measured["bare_commands_invalid"] == 0
    records = [bench_runtime.json.loads(p.read_text()) for p in (tmp_path / "bare").glob("floor_*.json")]
    # each ran to the run's last tick, unless it lagged so far behind when the lockstep run ended that
    # the poses the sim's router still held went with it (it is then stopped by Floor.finish: seen once
    # in 15 runs beside 4 busy loops, one bare agent at tick 872 of 1199)
    for record in records:
        if record["exit_reason"] == "done":
            assert record["last_tick"] == steps - 1, records
        else:
            assert record["exit_reason"] == "stopped" and measured["stopped_after_run"], records
            assert record["first_tick"] <= record["last_tick"] < steps - 1, records
    # each computed poses from its first one on, none twice (its pose ring drops the oldest when it
    # lags far behind on a loaded machine, so fewer is allowed: a CI-like run computed 1105 of 1200)
    assert all(0 < r["ticks"] <= steps - r["first_tick"] for r in records), records
    # the window opens once the bare agents are up; each set is charged for the ticks it computed in it.
    # A bare set that lagged behind at the window's first edge catches up inside it (CI saw 186 bare
    # ticks in a window of 176 real ones), so its count is bounded by the ticks it computed at all.
    assert measured["window_ticks"] > 0
    most_bare_ticks = max(r["ticks"] for r in records)
    assert 0 < measured["bare_ticks_in_window"] <= most_bare_ticks
    assert measured["real_cpu_ms_per_tick"] > 0 and measured["bare_cpu_ms_per_tick"] > 0
    # the split by thread lies within each set's whole (the main thread's share of the same /proc window)
    for agents in ("real", "bare"):
        main_ms = measured[f"{agents}_main_thread_ms_per_tick"]
        assert 0 <= main_ms <= measured[f"{agents}_cpu_ms_per_tick"], measured
        assert measured[f"{agents}_zenoh_threads_ms_per_tick"] >= 0, measured


def test_floor_ab_refuses_a_base_that_is_no_commit(tmp_path: Path, capsys) -> None:
    import floor_ab

    assert floor_ab.main(["--base", "no-such-revision-xyz", "--out", str(tmp_path), "--quiet"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "--base" in error and "no-such-revision-xyz" in error
    assert not (tmp_path / "floor_ab.json").exists()
