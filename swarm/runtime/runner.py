"""Runs a scenario on an engine and writes its results directory.

``kinematic`` runs in this process on the batched simulator (B = 1); ``pybullet`` runs the sim
server and one process per robot over Zenoh (``swarm.runtime.distributed``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from swarm.core.faults import PROCESS_FAULTS, LinkFaults, message_max_age_ticks
from swarm.core.obstacles import Capsules
from swarm.scenarios.fault_results import add_fault_results
from swarm.scenarios.results import (
    TrajectoryWriter,
    prepare_results_dir,
    task_outcome,
    write_metrics,
    write_partial_results,
)
from swarm.scenarios.safety_results import add_safety_results
from swarm.scenarios.scenario import Scenario, ScenarioError, engine_warnings
from swarm.scenarios.task_report import task_pictures
from swarm.sim.controller_kinds import CONTROLLER_KINDS, ControllerArgs, batched_controller
from swarm.sim.controllers import BatchedController
from swarm.sim.kinematic import KinematicSim
from swarm.sim.safety_filter import SafetyFilter

log = logging.getLogger(__name__)


def build_controller(scenario: Scenario, scenario_path: Path | None = None) -> BatchedController:
    """The batched controller named by ``scenario.controller`` (``swarm.sim.controller_kinds``)."""
    spec = scenario.controller
    from swarm.scenarios.scenario import policy_path

    policy = policy_path(scenario, scenario_path)
    args = ControllerArgs.from_spec(
        spec.model_dump(),
        scenario.robot,
        scenario.sim.control_period_s,
        robot_count=scenario.robots.count,
        policy=policy,
        task=scenario.task,
    )
    try:
        return batched_controller(spec.kind, args)
    except ValueError as error:  # swarm.sim.policy.PolicyFormatError is a ValueError
        key = "controller.model" if "model" in CONTROLLER_KINDS[spec.kind].options else "controller.kind"
        where = f"{policy}: " if policy is not None else ""
        raise ScenarioError(f"{key}: {where}{error}") from None


def run_kinematic(
    scenario: Scenario, out_dir: Path, scenario_path: Path | None = None, progress: bool = True
) -> dict:
    """Run on the kinematic engine, streaming the trajectory; returns the outcome (metrics.json).
    Link faults apply as in the agents (``swarm.core.faults``); process faults need the pybullet engine."""
    for index, fault in enumerate(scenario.faults):
        if fault.kind in PROCESS_FAULTS:
            raise ScenarioError(
                f"faults[{index}].kind: {fault.kind} needs the pybullet engine (the kinematic engine runs"
                " no processes)"
            )
    for warning in engine_warnings(scenario):
        log.warning("%s", warning)
    controller = build_controller(scenario, scenario_path)
    adjacency = scenario.adjacency()
    obstacles = Capsules(scenario.obstacles)
    safety = SafetyFilter(scenario.robot, scenario.safety, obstacles) if scenario.safety else None
    sim = KinematicSim(
        scenario.robot,
        controller,
        scenario.sim.control_period_s,
        scenario.initial_poses()[None],
        adjacency=adjacency,
        disk_radius_m=scenario.topology.radius_m if adjacency is None else None,
        link_faults=LinkFaults.from_scenario(scenario) if scenario.faults else None,
        message_max_age_ticks=message_max_age_ticks(scenario.sim),
        safety=safety,
    )
    prepare_results_dir(out_dir, scenario)
    (out_dir / "events.jsonl").unlink(missing_ok=True)  # process faults of an earlier run there
    steps = scenario.steps
    times = np.arange(steps + 1) * scenario.sim.control_period_s
    poses = np.empty((steps + 1, scenario.robots.count, 3))
    ticks = range(steps + 1)
    if progress:
        from tqdm import tqdm

        ticks = tqdm(ticks, desc=f"{scenario.name} (kinematic)", unit="tick", leave=False)
    try:
        with TrajectoryWriter(out_dir / "trajectory.jsonl") as trajectory:
            for tick in ticks:
                poses[tick] = sim.poses[0]
                trajectory.write(tick, times[tick], poses[tick])
                if tick < steps:
                    sim.step()
    except KeyboardInterrupt:  # the results of the ticks so far, marked partial, then out
        done = (out_dir / "trajectory.jsonl").read_bytes().count(b"\n")
        write_partial_results(out_dir, f"interrupted (Ctrl-C) after {done} of {steps + 1} ticks")
        raise
    final_adjacency = sim.adjacency()[0]
    outcome = task_outcome(scenario, times, poses, final_adjacency)
    if scenario.faults:
        add_fault_results(outcome, scenario, out_dir, {}, times, poses, message_counts=sim.fault_counts)
    counts = safety.counts if safety is not None else None
    add_safety_results(outcome, poses, scenario.robot.body_radius_m, obstacles, counts)
    write_metrics(out_dir, outcome)
    task_pictures(out_dir, scenario, times, poses, outcome)
    return outcome


def run_scenario(
    scenario: Scenario,
    out_dir: Path,
    scenario_path: Path | None = None,
    progress: bool = True,
    agent_nice: int | None = None,
) -> dict:
    """Run ``scenario`` on its engine; ``agent_nice``: the pybullet agents' niceness (None: the
    runner's default, ``swarm.runtime.distributed.AGENT_NICE``)."""
    log.debug(
        "%s: %s engine, %d robots, %s graph, %s controller -> %s",
        scenario.name,
        scenario.sim.engine,
        scenario.robots.count,
        scenario.topology.kind,
        scenario.controller.kind,
        out_dir,
    )
    if scenario.sim.engine == "kinematic":
        return run_kinematic(scenario, out_dir, scenario_path, progress)
    if scenario.sim.engine == "pybullet":
        from swarm.runtime.distributed import run_distributed

        if agent_nice is None:
            return run_distributed(scenario, out_dir, scenario_path, progress)
        return run_distributed(scenario, out_dir, scenario_path, progress, agent_nice)
    raise ScenarioError(f"sim.engine: '{scenario.sim.engine}' is not available in this version")
