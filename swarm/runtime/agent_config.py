"""Each robot's :class:`~swarm.runtime.wire.AgentConfig` from a scenario: what the sim server serves on
``swarm/<run>/config/<i>`` and what an agent without a sim server (``robot-agent --ros2 --scenario``,
on a real robot) builds for itself. Importable without torch, pybullet or numba."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarm.runtime import wire
from swarm.scenarios.scenario import Scenario


def agent_configs(scenario: Scenario, run: str, policy: bytes | None) -> list[wire.AgentConfig]:
    """Each robot's configuration: its neighbours (and link weights) on the scenario's fixed graph; on a
    disk graph none (the sim's radio relays what it hears: ``sim_server.radio``)."""
    count = scenario.robots.count
    adjacency = scenario.adjacency()
    if adjacency is None:
        adjacency = np.zeros((count, count))
    common: dict[str, Any] = {
        "run": run,
        "robot_count": scenario.robots.count,
        "controller": scenario.controller.kind,
        "gain": scenario.controller.gain,
        "robot_params": scenario.robot.model_dump(),
        "mode": scenario.sim.mode,
        "control_period_s": scenario.sim.control_period_s,
        "neighbour_deadline_s": scenario.sim.neighbour_deadline_s,
        "scenario": scenario.model_dump(mode="json"),
        "policy": policy,
    }
    configs = []
    for i, row in enumerate(adjacency):
        neighbours = tuple(int(j) for j in np.flatnonzero(row))
        configs.append(
            wire.AgentConfig(
                robot=i, neighbours=neighbours, weights=tuple(float(row[j]) for j in neighbours), **common
            )
        )
    return configs
