"""The max-flooding GNN (``gnn_flood``) in the distributed runtime: real ``swarm run`` processes (sim
server + one torch-free agent per robot), real Zenoh, real PyBullet.

Oracle: the batched kinematic engine's compiled forward (``swarm.flood_kernel``) fed the poses the
server logged and its own previous outbox as everybody's inbox (lockstep: every agent heard all
its neighbours' messages of the last tick).
"""

from __future__ import annotations

import json

import numpy as np
import torch
from test_runtime import Run, agent_records, scenario_file

from swarm.links import Links
from swarm.models.flood import FloodGNN
from swarm.policy import load_policy
from swarm.robot import RobotParams, controlled_point, point_velocity_to_wheels
from swarm.scenario import load_scenario


def logged(out):
    """The server's logged poses ``(T, N, 3)`` and the wheel speeds applied at each tick."""
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    return np.array([line["poses"] for line in lines]), np.array([line["wheels"] for line in lines[:-1]])


def test_flood_gnn_agents_are_torch_free_and_compute_the_batched_forward(tmp_path):
    torch.manual_seed(0)
    model_path = FloodGNN().export(tmp_path / "flood.npz", RobotParams())
    path = scenario_file(
        tmp_path,
        "line-local_consensus",
        sim__duration=3.0,
        controller__kind="gnn",
        controller__model=str(model_path),
    )
    out = tmp_path / "out"
    code, _, stderr = Run(path, out).finish()
    assert code in (0, 1), stderr
    records = agent_records(out)
    assert all(r["controller"] == "gnn" and r["heavy_modules"] == [] for r in records.values())
    assert all(r["messages"]["lost"] == 0 for r in records.values())

    scenario = load_scenario(path)
    poses, applied = logged(out)
    count = scenario.robots.count
    policy = load_policy(model_path, scenario.robot, count)
    points = controlled_point(poses, scenario.robot.offset_m)
    inbox, heard = np.zeros((1, count, policy.message_dim)), Links.nobody(1, count)
    for tick, wheels in enumerate(applied):
        u_world, inbox = policy.act(poses[tick][None], points[tick][None], inbox, heard)
        expected = point_velocity_to_wheels(u_world[0], poses[tick, :, 2], scenario.robot)
        np.testing.assert_allclose(wheels, expected, rtol=0, atol=1e-9, err_msg=f"tick {tick}")
        heard = Links.from_dense(scenario.adjacency()[None])
    assert np.all(applied[0] == 0.0)  # tick 0: nobody heard yet, everybody holds still
    assert np.abs(applied[1:]).max() > 0.1
