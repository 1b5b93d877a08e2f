"""``mec_flood`` and ``centralized_mec`` in the distributed runtime: real ``swarm run`` processes
(sim server + one agent per robot, or the one central process), real Zenoh, real PyBullet.

The oracle for every command is the batched kinematic engine's controller, fed the poses the
server logged and, for the flood, its own previous outbox as everybody's inbox (lockstep: every
agent heard all its neighbours' messages of the last tick).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_runtime import Run, agent_records, scenario_file

from swarm.core.robot import controlled_point, point_velocity_to_wheels
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import load_scenario
from swarm.sim.controllers import CentralizedMec, MecFlood
from swarm.sim.links import Links

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out


def logged(out):
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    poses = np.array([line["poses"] for line in lines])
    return poses, np.array([line["wheels"] for line in lines[:-1]])


def test_mec_flood_agents_compute_what_the_kinematic_engines_controller_computes(tmp_path):
    path = scenario_file(
        tmp_path,
        "line-local_consensus",
        sim__duration=3.0,
        controller__kind="mec_flood",
        controller__directions=8,
    )
    out = tmp_path / "out"
    code, _, stderr = Run(path, out).finish()
    assert code in (0, 1), stderr
    records = agent_records(out)
    assert all(r["controller"] == "mec_flood" and r["heavy_modules"] == [] for r in records.values())
    assert all(r["messages"]["lost"] == 0 for r in records.values())

    scenario = load_scenario(path)
    poses, applied = logged(out)
    count = scenario.robots.count
    controller = MecFlood(scenario.robot, scenario.sim.control_period_s, directions=8)
    points = controlled_point(poses, scenario.robot.offset_m)
    inbox, heard = np.zeros((1, count, controller.message_dim)), Links.nobody(1, count)
    for tick, wheels in enumerate(applied):
        u_world, inbox = controller.act(poses[tick][None], points[tick][None], inbox, heard)
        expected = point_velocity_to_wheels(u_world[0], poses[tick, :, 2], scenario.robot)
        np.testing.assert_allclose(wheels, expected, rtol=0, atol=1e-9, err_msg=f"tick {tick}")
        heard = Links.from_dense(scenario.adjacency()[None])
    assert np.all(applied[0] == 0.0)  # tick 0: nobody known yet, everybody holds still
    assert np.abs(applied).max() > 0.4  # full speed


def test_centralized_mec_runs_as_one_central_process_with_the_batched_commands(tmp_path):
    path = scenario_file(tmp_path, "cycle-centralized", sim__duration=3.0, controller__kind="centralized_mec")
    out = tmp_path / "out"
    code, _, stderr = Run(path, out).finish()
    assert code in (0, 1), stderr
    record = json.loads((out / "logs" / "central.json").read_text())
    assert record["controller"] == "centralized_mec" and record["incomplete_ticks"] == 0
    scenario = load_scenario(path)
    poses, applied = logged(out)
    controller = CentralizedMec(scenario.robot, scenario.sim.control_period_s)
    for tick, wheels in enumerate(applied):
        u_world, _ = controller.act(poses[tick][None], None, None, None)
        expected = point_velocity_to_wheels(u_world[0], poses[tick, :, 2], scenario.robot)
        np.testing.assert_allclose(wheels, expected, rtol=0, atol=1e-9, err_msg=f"tick {tick}")


def test_a_restarted_mec_flood_agent_starts_afresh_and_the_swarm_still_gathers(tmp_path):
    """Robot 0's agent is killed at 1 s and a fresh process started: it remembers nothing, holds
    still until it hears a neighbour, and its neighbours flood the support points back."""
    path = scenario_file(
        tmp_path,
        "cycle-local_consensus",
        sim__duration=20.0,  # room for a restart that is slow on a loaded machine
        controller__kind="mec_flood",
        success__threshold={"kinematic": 0.2, "pybullet": 0.9},
    )
    data = load_scenario(path).model_dump(mode="json")
    data["faults"] = [{"kind": "restart_agent", "at_s": 1.0, "robot": 0}]
    path.write_text(json.dumps(data))
    out = tmp_path / "out"
    code, _, stderr = Run(path, out).finish()
    outcome = json.loads((out / "metrics.json").read_text())
    assert code == 0, (stderr, outcome.get("final_metric"), outcome.get("incomplete"))  # converged
    records = agent_records(out)
    assert records[0]["first_tick"] > 0 and records[0]["controller"] == "mec_flood"
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert np.ptp(poses[-1, :, :2], axis=0).max() < 0.9
