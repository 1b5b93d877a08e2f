"""The task registry's contract (swarm.core.tasks): every registered task passes the same tests."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from swarm.core import tasks
from swarm.scenarios.scenario import ScenarioError, parse_scenario
from swarm.sim.controller_kinds import CONTROLLER_KINDS

BASE = {"name": "t", "robots": {"count": 6}, "topology": {"kind": "cycle"}, "sim": {"engine": "kinematic"}}
SECTIONS = {
    "rendezvous": {"kind": "rendezvous"},
    "formation": {"kind": "formation", "slots": {"circle": {"radius_m": 1.0}}},
    "coverage": {"kind": "coverage", "region": [[-2, -2], [2, -2], [2, 2], [-2, 2]]},
}


def test_rendezvous_is_the_default_and_first():
    assert tasks.names()[0] == "rendezvous"
    assert parse_scenario(BASE).task.kind == "rendezvous"
    assert parse_scenario({**BASE, "task": "rendezvous"}).task == parse_scenario(BASE).task


@pytest.mark.parametrize("name", tasks.names())
def test_every_task_names_what_a_run_needs(name):
    task = tasks.get(name)
    assert (
        task.section().kind == name
        if name == "rendezvous"
        else task.section.model_fields["kind"].default == name
    )
    assert task.experts and task.baselines, "an expert and a decentralized baseline"
    for kind in task.controllers:
        assert CONTROLLER_KINDS[kind].task == name, kind
    others = {kind for kind, entry in CONTROLLER_KINDS.items() if entry.task == name} - set(task.controllers)
    assert not others, f"controller kinds of task {name} that its entry does not list"
    for kind in task.experts:
        assert CONTROLLER_KINDS[kind].central, f"{kind}: an expert of {name} is centralized"
    assert task.bound in ("lower_bound", "reference")
    if task.bound == "lower_bound":
        assert task.bound_s is not None and task.bound_s.__doc__, "the bound says why it holds"
    else:
        assert task.reference is not None and "not a bound" in (task.reference.__doc__ or ""), (
            "a reference says how it is found and that it is not a bound"
        )
    module, _, function = task.plot.partition(":")
    assert callable(getattr(importlib.import_module(module), function))
    assert name in SECTIONS, "give the test a valid section of the new task"


@pytest.mark.parametrize("name", tasks.names())
def test_every_controller_of_a_task_validates_and_others_are_refused(name):
    for kind in CONTROLLER_KINDS:
        data = {**BASE, "task": SECTIONS[name], "controller": {"kind": kind}}
        if CONTROLLER_KINDS[kind].task == name:
            assert parse_scenario(data).controller.kind == kind
        else:
            with pytest.raises(
                ScenarioError, match=f"controller.kind: controller '{kind}' does not do task '{name}'"
            ):
                parse_scenario(data)


def test_bad_task_sections_get_one_line_naming_the_key():
    cases = [
        ({"kind": "flocking"}, "task: Input should be 'rendezvous', 'formation' or 'coverage'"),
        ("formation", "task.slots: required key is missing"),
        (
            {"kind": "formation", "slots": {"circle": {"radius_m": -1}}},
            "task.slots.circle.radius_m: Input should be",
        ),
        (
            {"kind": "formation", "slots": {"circle": {"radius_m": 1.0}}, "tolerance_m": 0.6},
            "task.tolerance_m: 0.6 m is not under half the smallest slot spacing 1 m",
        ),
        (
            {"kind": "formation", "slots": {"points": [[0, 0]]}},
            "task.slots: points has 1 slots but robots.count is 6",
        ),
        (
            {"kind": "formation", "slots": {"circle": {"radius_m": 1.0}, "line": {"spacing_m": 1.0}}},
            "give exactly one of 'circle', 'grid', 'line' and 'points'",
        ),
    ]
    for section, message in cases:
        with pytest.raises(ScenarioError, match=message.replace("[", r"\[").replace("(", r"\(")):
            parse_scenario({**BASE, "task": section, "controller": {"kind": "capt"}})
    coverage_cases = [
        ({"kind": "coverage", "region": [[0, 0], [1, 1], [2, 2]]}, "task.region: the polygon has no area"),
        ({"kind": "coverage", "region": [[0, 0], [1, 0]]}, "task.region: List should have at least 3 items"),
        (
            {"kind": "coverage", "gaussians": [{"mean": [0, 0], "sigma_m": 0}]},
            "task.gaussians[0].sigma_m: Input should be greater than 0",
        ),
        ({"kind": "coverage", "tolerance": 0}, "task.tolerance: Input should be greater than 0"),
    ]
    for section, message in coverage_cases:
        with pytest.raises(ScenarioError, match=message.replace("[", r"\[").replace("(", r"\(")):
            parse_scenario({**BASE, "task": section, "controller": {"kind": "lloyd_flood"}})


@pytest.mark.parametrize("name", tasks.names())
def test_the_bound_is_not_beaten_by_the_expert(name):
    """Every task's expert, on a few random starts, takes at least the bound (a reference: no check)."""
    from swarm.runtime.runner import build_controller
    from swarm.scenarios.results import task_outcome
    from swarm.sim.kinematic import KinematicSim

    task = tasks.get(name)
    if task.bound != "lower_bound":
        pytest.skip("a reference, not a bound")
    for seed in range(3):
        data = {
            **BASE,
            "task": SECTIONS[name],
            "controller": {"kind": task.experts[-1]},
            "robots": {"count": 6, "init": {"random": {"seed": seed}}},
            "sim": {"engine": "kinematic", "duration_s": 25},
        }
        scenario = parse_scenario(data)
        sim = KinematicSim(
            scenario.robot,
            build_controller(scenario),
            0.05,
            scenario.initial_poses()[None],
            adjacency=scenario.adjacency(),
        )
        trajectory = sim.rollout(scenario.steps)[:, 0]
        times = np.arange(len(trajectory)) * 0.05
        outcome = task_outcome(scenario, times, trajectory, scenario.adjacency())
        assert outcome["converged"], seed
        assert outcome["ratio_to_lower_bound"] >= 1.0


def test_swarm_sweep_sends_another_tasks_controller_to_its_task_sweep(capsys):
    """A rendezvous sweep of a formation or coverage kind: exit 2, naming ``swarm sweep --task``."""
    from swarm.cli import main

    for kind, task in (("capt_flood", "formation"), ("lloyd_flood", "coverage")):
        assert main(["sweep", "--controllers", kind, "--sizes", "6", "--seeds", "1"]) == 2
        error = capsys.readouterr().err
        assert f"'{kind}' does task {task}; sweep it with swarm sweep --task {task}" in error
