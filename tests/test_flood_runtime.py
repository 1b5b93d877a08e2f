"""The max-flooding GNN (``gnn_flood``) in the distributed runtime: real ``swarm run`` processes (sim
server + one torch-free agent per robot), real Zenoh, real PyBullet.

Oracle: the batched kinematic engine's compiled forward (``swarm.sim.flood_kernel``) fed the poses the
server logged and its own previous outbox as everybody's inbox (lockstep: every agent heard all
its neighbours' messages of the last tick).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_runtime import Run, agent_records, assert_commands_equal_batched_policy, scenario_file

from swarm.core.robot import RobotParams
from swarm.learn.models.flood import FloodGNN

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out


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

    applied = assert_commands_equal_batched_policy(out, path, model_path)
    assert np.all(applied[0] == 0.0)  # tick 0: nobody heard yet, everybody holds still
    assert np.abs(applied[1:]).max() > 0.1
