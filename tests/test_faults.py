"""Link faults (swarm.core.faults): the schedule, the scenario schema, the kinematic engine, the results of
faulty runs, and the PyBullet runtime with real agent processes that cope with missing neighbours.

The runtime tests run ``python -m swarm.cli run`` (sim server + one process per robot over Zenoh, real
PyBullet) as tests/test_runtime.py does, and check what the processes left behind.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_runtime import Run, agent_records, graphs_min_distance

from swarm.cli import main
from swarm.core import graphs
from swarm.core.faults import (
    DROPPED,
    HEARD,
    LOST,
    LinkFaults,
    loss_uniform,
    loss_uniform_array,
    message_max_age_ticks,
    select_message,
    usable,
    usable_ticks,
)
from swarm.core.robot import RobotParams, point_velocity_to_wheels
from swarm.scenarios.fault_results import add_fault_results, fault_summary
from swarm.scenarios.results import read_trajectory, summarize
from swarm.scenarios.scenario import ScenarioError, load_scenario, parse_scenario
from swarm.sim.controller_kinds import robot_controller
from swarm.sim.controllers import LocalConsensus
from swarm.sim.kinematic import KinematicSim
from swarm.sim.onboard import OnboardLocalConsensus
from swarm.sim.policy import load_policy, save_policy

PROJECT_ROOT = Path(__file__).resolve().parent.parent
FAULT_SCENARIOS = sorted((PROJECT_ROOT / "scenarios" / "faults").glob("*.yaml"))
DT = 0.05


def schedule(*faults: dict, seed: int = 0) -> LinkFaults:
    return LinkFaults(list(faults), DT, seed)


# ---------------------------------------------------------------------------------- the schedule


def test_loss_draw_is_a_pure_function_the_same_in_scalar_and_array_form():
    rng = np.random.default_rng(0)
    senders, receivers = rng.integers(0, 1000, 500), rng.integers(0, 1000, 500)
    for seed, fault, tick in [(0, 0, 0), (7, 3, 12345), (2**40, 1, 2**31)]:
        draws = loss_uniform_array(seed, fault, senders, receivers, tick)
        assert draws.shape == (500,) and np.all((draws >= 0) & (draws < 1))
        scalar = [loss_uniform(seed, fault, s, r, tick) for s, r in zip(senders, receivers, strict=True)]
        np.testing.assert_array_equal(draws, scalar)  # bit for bit: both engines lose the same packets
    assert loss_uniform(0, 0, 1, 2, 3) == loss_uniform(0, 0, 1, 2, 3)
    assert len({loss_uniform(0, 0, 1, 2, 3), loss_uniform(1, 0, 1, 2, 3), loss_uniform(0, 0, 2, 1, 3)}) == 3


@pytest.mark.parametrize("p", [0.0, 0.2, 0.5, 1.0])
def test_packet_loss_rate_is_p_on_every_directed_link(p):
    faults = schedule({"kind": "packet_loss", "p": p}, seed=3)
    senders, receivers = np.meshgrid(np.arange(8), np.arange(8))
    off_diagonal = senders != receivers
    lost = np.array([faults.reasons_array(senders, receivers, tick)[off_diagonal] for tick in range(400)])
    assert set(np.unique(lost)) <= {HEARD, LOST}
    rate = np.mean(lost == LOST)
    n = lost.size  # 22,400 draws: 3 sigma of the rate is under 0.01
    assert abs(rate - p) <= 3 * math.sqrt(p * (1 - p) / n) + 1e-12, rate
    if 0 < p < 1:  # the two directions of a link and consecutive ticks are drawn independently
        assert np.mean(lost[:, 0] == lost[:, 7]) < 0.7 and np.mean(lost[1:] == lost[:-1]) < 0.7


def test_drop_and_restore_follow_sim_time_and_direction():
    both = schedule(
        {"kind": "drop_link", "at_s": 1.0, "link": [0, 1]},
        {"kind": "restore_link", "at_s": 2.0, "link": [0, 1]},
    )
    # at 1.0 s = tick 20 the link goes down; at 2.0 s = tick 40 it is back
    assert [both.heard(0, 1, tick) for tick in (19, 20, 39, 40)] == [True, False, False, True]
    assert [both.heard(1, 0, tick) for tick in (19, 20, 39, 40)] == [True, False, False, True]
    assert both.reason(0, 1, 25) == DROPPED and both.heard(0, 2, 25) and both.heard(2, 1, 25)
    one = schedule({"kind": "drop_link", "at_s": 1.0, "link": [0, 1], "direction": "one"})
    assert not one.heard(0, 1, 30) and one.heard(1, 0, 30)  # only robot 1 stops hearing robot 0
    assert not one.heard(0, 1, 10**6)  # never restored
    assert schedule().empty and not one.empty


def test_delay_and_until():
    faults = schedule(
        {"kind": "delay", "ticks": 3, "at_s": 1.0, "until_s": 2.0},
        {"kind": "delay", "ticks": 5, "link": [2, 3], "direction": "one", "at_s": 1.5},
        {"kind": "packet_loss", "p": 1.0, "link": [4, 5], "at_s": 1.0, "until_s": 1.5},
    )
    assert [faults.delay_ticks(0, 1, tick) for tick in (19, 20, 39, 40)] == [0, 3, 3, 0]
    assert faults.delay_ticks(2, 3, 35) == 5 and faults.delay_ticks(3, 2, 35) == 3  # the largest applies
    assert faults.delay_ticks(2, 3, 10**5) == 5 and faults.max_delay_ticks == 5
    assert [faults.heard(4, 5, tick) for tick in (19, 20, 29, 30)] == [True, False, False, True]
    assert [faults.heard(5, 4, tick) for tick in (19, 20, 29, 30)] == [True, False, False, True]
    assert list(usable_ticks(10, 0, 1)) == [9]
    assert list(usable_ticks(10, 3, 1)) == [6]
    assert list(usable_ticks(10, 3, 4)) == [6, 5, 4, 3]
    assert list(usable_ticks(2, 0, 10)) == [1, 0] and list(usable_ticks(0, 0, 1)) == []
    assert message_max_age_ticks({"mode": "lockstep"}) == 1
    assert message_max_age_ticks({"mode": "realtime", "message_max_age_ticks": None}) == 10
    assert message_max_age_ticks({"mode": "lockstep", "message_max_age_ticks": 3}) == 3


def test_message_selection_rule_by_hand():
    """Receiving tick 10: with delay 3 and age limit 2 only the messages of ticks 6 and 5 (ages 4, 5)
    may be used, the newest heard one wins; the same rule elementwise on arrays."""
    assert [usable(age, 3, 2, True) for age in range(1, 8)] == [False, False, False, True, True, False, False]
    assert not usable(4, 3, 2, False)  # not heard: never used
    arrived = {9, 8, 6, 5, 4}
    assert select_message(10, 3, 2, arrived.__contains__) == 6
    assert select_message(10, 3, 2, {5, 4}.__contains__) == 5  # 6 missing: the older one stands in
    assert select_message(10, 3, 2, {4, 7}.__contains__) is None  # 7 too new, 4 too old
    assert select_message(10, 0, 1, {8}.__contains__) is None  # lockstep: only tick 9 counts
    assert select_message(1, 0, 10, {0}.__contains__) == 0 and select_message(0, 0, 10, bool) is None
    ages = np.array([[1, 4], [5, 6]])
    delays = np.array([[0, 3], [3, 3]])
    heard = np.array([[True, True], [False, True]])
    np.testing.assert_array_equal(usable(ages, delays, 2, heard), [[True, True], [False, False]])


def test_array_forms_equal_the_per_link_answers():
    faults = schedule(
        {"kind": "drop_link", "at_s": 0.5, "link": [0, 1]},
        {"kind": "drop_link", "at_s": 0.2, "link": [2, 3], "direction": "one"},
        {"kind": "restore_link", "at_s": 1.0, "link": [0, 1]},
        {"kind": "packet_loss", "p": 0.3, "at_s": 0.3, "until_s": 1.2},
        {"kind": "packet_loss", "p": 0.6, "link": [1, 2]},
        {"kind": "delay", "ticks": 2, "link": [3, 4], "at_s": 0.4},
        seed=11,
    )
    senders, receivers = np.meshgrid(np.arange(6), np.arange(6))
    for tick in range(0, 40, 3):
        reasons = faults.reasons_array(senders, receivers, tick)
        delays = faults.delay_array(senders, receivers, tick)
        for s, r in zip(senders.ravel(), receivers.ravel(), strict=True):
            assert reasons[r, s] == faults.reason(s, r, tick)
            assert delays[r, s] == faults.delay_ticks(s, r, tick)


# ---------------------------------------------------------------------------------- the schema

BASE = {
    "name": "faults-schema",
    "robots": {"count": 6},
    "topology": {"kind": "cycle"},
    "sim": {"engine": "kinematic", "duration": 5.0},
}

BAD_FAULTS = [
    ({"kind": "drop_link", "link": [0, 1]}, "faults[0].at", "required for kind drop_link"),
    ({"kind": "drop_link", "at": 1}, "faults[0].link", "required for kind drop_link"),
    ({"kind": "drop_link", "at": 1, "link": [0, 2]}, "faults[0].link", "[0, 2] is not an edge of the cycle"),
    ({"kind": "drop_link", "at": 1, "link": [0, 0]}, "faults[0].link", "two different robots"),
    ({"kind": "drop_link", "at": 1, "link": [0, 9]}, "faults[0].link", "robot 9 but robots.count is 6"),
    ({"kind": "drop_link", "at": 1, "link": [0, 1], "p": 0.2}, "faults[0].p", "not a key of kind drop_link"),
    (
        {"kind": "drop_link", "at": 1, "link": [0, 1], "direction": "up"},
        "faults[0].direction",
        "'both' or 'one'",
    ),
    ({"kind": "restore_link", "at": 1, "link": [0, 1]}, "faults[0].link", "no earlier drop_link dropped"),
    ({"kind": "packet_loss"}, "faults[0].p", "required for kind packet_loss"),
    ({"kind": "packet_loss", "p": 1.5}, "faults[0].p", "less than or equal to 1"),
    ({"kind": "packet_loss", "p": 0.2, "direction": "one"}, "faults[0].direction", "needs 'link'"),
    ({"kind": "packet_loss", "p": 0.2, "at": 2, "until": 1}, "faults[0].until", "must be after 'at'"),
    ({"kind": "packet_loss", "p": 0.2, "robot": 1}, "faults[0].robot", "not a key of kind packet_loss"),
    ({"kind": "delay"}, "faults[0].ticks", "required for kind delay"),
    ({"kind": "delay", "ticks": 0}, "faults[0].ticks", "greater than or equal to 1"),
    ({"kind": "delay", "ticks": 2, "duration": 1}, "faults[0].duration", "not a key of kind delay"),
    ({"kind": "kill_agent", "at": 1}, "faults[0].robot", "required for kind kill_agent"),
    ({"kind": "kill_agent", "robot": 1}, "faults[0].at", "required for kind kill_agent"),
    ({"kind": "kill_agent", "at": 1, "robot": 6}, "faults[0].robot", "robot 6 but robots.count is 6"),
    ({"kind": "hang_agent", "at": 1, "robot": 1}, "faults[0].duration", "required for kind hang_agent"),
    ({"kind": "restart_agent", "at": 1, "robot": 1, "link": [0, 1]}, "faults[0].link", "not a key of kind"),
    ({"kind": "kill_server", "at": 1, "robot": 2}, "faults[0].robot", "not a key of kind kill_server"),
    ({"kind": "unplug", "at": 1}, "faults[0].kind", "Input should be"),
]


@pytest.mark.parametrize(
    ("fault", "key", "reason"), BAD_FAULTS, ids=[f"{c[0]['kind']}-{c[1]}" for c in BAD_FAULTS]
)
def test_bad_fault_is_one_line_naming_file_key_and_reason(tmp_path, fault, key, reason):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({**BASE, "faults": [fault]}))
    with pytest.raises(ScenarioError) as error:
        load_scenario(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"{path}: {key}: "), message
    assert reason in message, message


def test_every_fault_kind_loads_and_round_trips():
    data = {
        **BASE,
        "sim": {"engine": "pybullet", "duration": 5.0},
        "faults_seed": 4,
        "faults": [
            {"kind": "drop_link", "at": 1, "link": [0, 1], "direction": "one"},
            {"kind": "restore_link", "at": 2, "link": [0, 1], "direction": "one"},
            {"kind": "packet_loss", "p": 0.2},
            {"kind": "packet_loss", "p": 0.5, "link": [2, 3], "at": 1, "until": 3},
            {"kind": "delay", "ticks": 2, "at": 1, "until": 2},
            {"kind": "kill_agent", "at": 1, "robot": 2},
            {"kind": "restart_agent", "at": 2, "robot": 2},
            {"kind": "hang_agent", "at": 1, "robot": 3, "duration": 1.5},
            {"kind": "kill_server", "at": 4},
        ],
    }
    scenario = parse_scenario(data)
    assert scenario.faults_seed == 4 and scenario.faults[4].ticks == 2 and scenario.faults[3].until_s == 3
    assert parse_scenario(scenario.model_dump(mode="json")) == scenario
    assert LinkFaults.from_scenario(scenario).max_delay_ticks == 2


@pytest.mark.parametrize("path", FAULT_SCENARIOS, ids=lambda path: path.stem)
def test_fault_scenarios_load(path):
    scenario = load_scenario(path)
    assert scenario.faults and scenario.name.startswith("faults-")


def test_the_link_fault_examples_are_there():
    names = {path.stem for path in FAULT_SCENARIOS}
    assert {"drop-link", "disconnect", "packet-loss", "delay"} <= names


def test_process_faults_need_the_pybullet_engine(tmp_path, capsys):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump({**BASE, "faults": [{"kind": "kill_agent", "at": 1, "robot": 2}]}))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "faults[0].kind: kill_agent needs the pybullet engine" in err
    assert not (tmp_path / "out").exists()  # nothing started


# ---------------------------------------------------------------------------------- the kinematic engine


class Commands:
    """A batched "controller" that returns the velocities it is given (the engine's motion only)."""

    message_dim, centralized = 2, False

    def __init__(self, count: int):
        self.u_world = np.zeros((1, count, 2))

    def act(self, poses, points, inbox, heard):
        return self.u_world.copy(), points.copy()


def reference_rollout(faults: LinkFaults, adjacency, poses, steps, max_age, gain=1.0) -> np.ndarray:
    """The agents' rule, robot by robot with the scalar schedule: newest heard message among the
    usable ticks, neighbours in index order, local consensus on board. ``(steps + 1, N, 3)``."""
    robot = RobotParams()
    controller = OnboardLocalConsensus(robot, gain)
    commands = Commands(len(poses))
    sim = KinematicSim(robot, commands, DT, poses[None], adjacency=adjacency)
    sent = []  # the point each robot broadcast, by tick
    trajectory = [sim.poses[0].copy()]
    for tick in range(steps):
        points = []
        for i, (x, y, theta) in enumerate(sim.poses[0]):
            heard, weights = [], []
            for j in np.flatnonzero(adjacency[i]):
                delay = faults.delay_ticks(j, i, tick)
                usable = [k for k in usable_ticks(tick, delay, max_age) if faults.heard(j, i, k)]
                if usable:
                    heard.append(sent[usable[0]][j])
                    weights.append(adjacency[i, j])
            commands.u_world[0, i], point = controller.act_floats(x, y, theta, heard, weights)
            points.append(point)
        sent.append(points)
        trajectory.append(sim.step()[0].copy())
    return np.array(trajectory)


@pytest.mark.parametrize("max_age", [1, 3])
def test_kinematic_engine_applies_the_schedule_as_the_agents_do(max_age):
    count, steps = 6, 60
    adjacency = graphs.cycle(count) * np.array([1.0, 2.0, 1.0, 1.0, 0.5, 1.0])[:, None]
    adjacency = np.maximum(adjacency, adjacency.T)  # weighted links
    faults = schedule(
        {"kind": "drop_link", "at_s": 0.5, "link": [0, 1]},
        {"kind": "restore_link", "at_s": 1.5, "link": [0, 1]},
        {"kind": "drop_link", "at_s": 0.3, "link": [2, 3], "direction": "one"},
        {"kind": "packet_loss", "p": 0.4},
        {"kind": "delay", "ticks": 2, "at_s": 0.8, "until_s": 2.2},
        {"kind": "delay", "ticks": 4, "link": [4, 5]},
        seed=5,
    )
    poses = np.random.default_rng(2).uniform(-2, 2, (count, 3))
    expected = reference_rollout(faults, adjacency, poses, steps, max_age)
    robot = RobotParams()
    sim = KinematicSim(
        robot,
        LocalConsensus(robot),
        DT,
        poses[None],
        adjacency=adjacency,
        link_faults=faults,
        message_max_age_ticks=max_age,
    )
    np.testing.assert_allclose(sim.rollout(steps)[:, 0], expected, rtol=0, atol=1e-12)
    counts = sim.fault_counts
    assert counts["dropped_by_fault"] > 0 and counts["lost_by_fault"] > 0 and counts["delayed_by_fault"] > 0


def test_faults_that_change_nothing_leave_the_kinematic_engine_bit_for_bit_alone():
    poses = np.random.default_rng(3).uniform(-2, 2, (2, 6, 3))
    robot = RobotParams()
    runs = []
    for faults in (None, schedule({"kind": "packet_loss", "p": 0.0})):
        sim = KinematicSim(
            robot, LocalConsensus(robot), DT, poses, adjacency=graphs.line(6), link_faults=faults
        )
        runs.append(sim.rollout(30))
    np.testing.assert_array_equal(runs[0], runs[1])
    # and keep(): the kept environment goes on exactly as if alone
    faults = schedule({"kind": "packet_loss", "p": 0.5}, {"kind": "delay", "ticks": 2, "at_s": 0.5})
    both = KinematicSim(robot, LocalConsensus(robot), DT, poses, adjacency=graphs.line(6), link_faults=faults)
    alone = KinematicSim(
        robot, LocalConsensus(robot), DT, poses[1:], adjacency=graphs.line(6), link_faults=faults
    )
    both.rollout(15)
    alone.rollout(15)
    both.keep(np.array([False, True]))
    np.testing.assert_array_equal(both.rollout(15), alone.rollout(15))


def random_policy(tmp_path: Path) -> Path:
    """A thesis-style MLP with biases: its output on zero features is not zero."""
    rng = np.random.default_rng(0)
    metadata = {
        "model": {"kind": "model2", "activation": "tanh"},
        "features": {"hops": 2, "phi_source": "m", "normaliser": "degree"},
        "feature_scale_m": 1.0,
        "output_scale_mps": 0.5,
        "robot": RobotParams().model_dump(),
        "training": {"note": "random weights, for this test"},
    }
    arrays = {
        "net.0.weight": rng.normal(0, 0.5, (8, 4)),
        "net.0.bias": rng.normal(0, 0.5, 8),
        "net.1.weight": rng.normal(0, 0.5, (2, 8)),
        "net.1.bias": np.array([0.3, -0.2]),
    }
    return save_policy(tmp_path / "policy.npz", metadata, arrays)


def test_a_policy_that_heard_nobody_holds_still(tmp_path):
    robot = RobotParams()
    path = random_policy(tmp_path)
    policy = load_policy(path, robot, 4)
    pose = np.array([0.5, -0.2, 0.7])
    assert np.abs(policy.forward(np.zeros((2, 2)))).max() > 0.05  # the network alone would move
    u_world, _ = policy.act_one(pose, np.zeros((0, 4)))
    assert np.all(u_world == 0.0)
    onboard = robot_controller("gnn", robot, 1.0, path.read_bytes(), 4)
    u_world, _ = onboard.act_one(pose, np.zeros((0, 4)), np.zeros(0))
    assert np.all(u_world == 0.0)
    default = robot_controller(
        "gnn", robot, 1.0, (PROJECT_ROOT / "models" / "gnn_default.npz").read_bytes(), 4
    )
    u_world, _ = default.act_one(pose, np.zeros((0, 4)), np.zeros(0))
    assert np.all(u_world == 0.0)
    # batched: robot 0 hears nobody (its links dropped one way), the others hear it and move
    poses = np.random.default_rng(1).uniform(-2, 2, (1, 4, 3))
    faults = schedule(
        {"kind": "drop_link", "at_s": 0.0, "link": [1, 0], "direction": "one"},
        {"kind": "drop_link", "at_s": 0.0, "link": [3, 0], "direction": "one"},
    )
    sim = KinematicSim(robot, policy, DT, poses, adjacency=graphs.cycle(4), link_faults=faults)
    trajectory = sim.rollout(20)
    np.testing.assert_array_equal(trajectory[:, 0, 0], np.broadcast_to(poses[0, 0], (21, 3)))
    assert np.abs(trajectory[-1, 0, 1:] - poses[0, 1:]).max() > 0.05


# ---------------------------------------------------------------------------------- results of faulty runs


def test_consensus_is_judged_over_live_robots_per_live_component(tmp_path):
    """Robot 2 of a line of 5 killed (never restarted), robot 4 killed and restarted: the live graph is
    {0, 1} and {3, 4}; both gathered, the dead robot did not move: per-component consensus, exit 1."""
    data = {
        **BASE,
        "robots": {"count": 5},
        "topology": {"kind": "line"},
        "sim": {"engine": "pybullet", "duration": 1.0},
        "faults": [
            {"kind": "kill_agent", "at": 0.2, "robot": 2},
            {"kind": "kill_agent", "at": 0.3, "robot": 4},
            {"kind": "restart_agent", "at": 0.5, "robot": 4},
        ],
        "success": {"threshold": 0.3},
    }
    scenario = parse_scenario(data)
    events = [
        {"kind": "kill_agent", "robot": 2, "at_s": 0.2, "tick": 4, "wall_s": 1.0, "detail": ""},
        {"kind": "kill_agent", "robot": 4, "at_s": 0.3, "tick": 6, "wall_s": 1.1, "detail": ""},
        {"kind": "restart_agent", "robot": 4, "at_s": 0.5, "tick": 10, "wall_s": 1.2, "pid": 77},
    ]
    (tmp_path / "events.jsonl").write_text("".join(json.dumps(event) + "\n" for event in events))
    times = np.arange(21) * DT
    start = np.array([[0, 0, 0], [1, 0, 0], [5, 0, 0], [9, 0, 0], [10, 0, 0]], dtype=float)
    end = np.array([[0.4, 0, 0], [0.6, 0, 0], [5, 0, 0], [9.4, 0, 0], [9.6, 0, 0]], dtype=float)
    poses = np.array([start + (end - start) * min(1.0, k / 10) for k in range(21)])
    counters = {"lost": 2, "dropped_by_fault": 1, "invalid": 0}
    records = {i: {"pid": 70 + i, "ticks": 20, "messages": counters} for i in range(4)}
    records[4] = {"pid": 77, "ticks": 10, "messages": counters}  # the restarted process drove robot 4
    summary = fault_summary(scenario, tmp_path, records, times, poses)
    assert summary["agents_lost"] == [2] and summary["agents_restarted"] == [4]
    assert summary["live_robots"] == [0, 1, 3, 4] and summary["events"] == events
    assert [c["robots"] for c in summary["components"]] == [[0, 1], [3, 4]]
    assert all(
        c["converged"] and c["convergence_time_s"] == pytest.approx(0.45) for c in summary["components"]
    )
    assert summary["messages"]["lost"] == 10 and summary["messages"]["dropped_by_fault"] == 5
    outcome = add_fault_results(
        summarize(scenario, times, poses, scenario.adjacency()), scenario, tmp_path, records, times, poses
    )
    assert outcome["converged"] is False and outcome["graph_connected"] is False  # no global consensus
    assert outcome["faults"]["every_component_converged"] is True
    assert outcome["components"] == summary["components"]
    assert outcome["final_metric"] == pytest.approx(9.2)  # over the live robots only
    json.dumps(outcome)  # metrics.json can hold it


@pytest.mark.parametrize(
    "record_4",
    [None, {"pid": 77, "ticks": 0}, {"pid": 66, "ticks": 20}],
    ids=["no record", "no tick computed", "a record of the killed process"],
)
def test_a_restarted_robot_whose_new_agent_never_drove_it_is_out_of_the_live_swarm(tmp_path, record_4):
    """Robot 4 of a line of 5 killed and restarted, but the new process (pid 77) never drove it: the
    live swarm is 0-3, which gathered; robot 4 left behind does not make the run fail or converge."""
    data = {
        **BASE,
        "robots": {"count": 5},
        "topology": {"kind": "line"},
        "sim": {"engine": "pybullet", "duration": 1.0},
        "faults": [
            {"kind": "kill_agent", "at": 0.3, "robot": 4},
            {"kind": "restart_agent", "at": 0.5, "robot": 4},
        ],
        "success": {"threshold": 0.3},
    }
    scenario = parse_scenario(data)
    events = [
        {"kind": "kill_agent", "robot": 4, "at_s": 0.3, "tick": 6, "wall_s": 1.1, "detail": "", "pid": 66},
        {"kind": "restart_agent", "robot": 4, "at_s": 0.5, "tick": 10, "wall_s": 1.2, "pid": 77},
    ]
    (tmp_path / "events.jsonl").write_text("".join(json.dumps(event) + "\n" for event in events))
    times = np.arange(21) * DT
    start = np.array([[0, 0, 0], [0.2, 0, 0], [0.4, 0, 0], [0.6, 0, 0], [9, 0, 0]], dtype=float)
    poses = np.array([start] * 21)
    records: dict = {i: {"pid": 70 + i, "ticks": 20} for i in range(4)}
    if record_4 is not None:
        records[4] = record_4
    summary = fault_summary(scenario, tmp_path, records, times, poses)
    assert summary["agents_restarted"] == [4] and summary["agents_restarted_never_back"] == [4]
    assert summary["live_robots"] == [0, 1, 2, 3]
    assert [c["robots"] for c in summary["components"]] == [[0, 1, 2, 3]]
    # the same run with a new agent that did drive robot 4: it is live, and 9 m away
    records[4] = {"pid": 77, "ticks": 10}
    summary = fault_summary(scenario, tmp_path, records, times, poses)
    assert summary["agents_restarted_never_back"] == [] and summary["live_robots"] == [0, 1, 2, 3, 4]


# ---------------------------------------------------------------------------------- the PyBullet runtime


def fault_scenario(tmp_path: Path, name: str, **changes: object) -> Path:
    """An example of scenarios/faults with top-level or ``section__key`` changes, written to tmp_path."""
    data = yaml.safe_load((PROJECT_ROOT / "scenarios" / "faults" / f"{name}.yaml").read_text())
    for dotted, value in changes.items():
        if "__" in dotted:
            section, key = dotted.split("__")
            data.setdefault(section, {})[key] = value
        else:
            data[dotted] = value
    path = tmp_path / f"{name}-{len(list(tmp_path.glob('*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def finish(path: Path, out: Path, *options: str) -> tuple[int, str, dict, dict[int, dict]]:
    run = Run(path, out, *options)
    code, stdout, stderr = run.finish()
    assert code in (0, 1), stderr
    assert run.survivors() == []
    return code, stdout, json.loads((out / "metrics.json").read_text()), agent_records(out)


def edges_keeping_connected(adjacency: np.ndarray, how_many: int) -> list[list[int]]:
    """The first ``how_many`` edges whose removal, together, leaves the graph connected."""
    adjacency, chosen = adjacency.copy(), []
    for i, j in zip(*np.nonzero(np.triu(adjacency)), strict=True):
        trial = adjacency.copy()
        trial[i, j] = trial[j, i] = 0
        if len(chosen) < how_many and graphs.is_connected(trial):
            adjacency, chosen = trial, [*chosen, [int(i), int(j)]]
    return chosen


@pytest.mark.runtime
@pytest.mark.parametrize(
    ("controller", "topology"),
    [
        ("gnn", {"kind": "cycle"}),
        ("local_consensus", {"kind": "random", "p": 0.5, "seed": 3, "connected": True}),
    ],
    ids=["gnn-cycle", "local_consensus-random"],
)
def test_runtime_converges_with_dropped_links_and_half_the_packets_lost(tmp_path, controller, topology):
    data = yaml.safe_load((PROJECT_ROOT / "scenarios" / "faults" / "packet-loss.yaml").read_text())
    data.update(topology=topology, controller={"kind": controller}, faults_seed=2)
    data["sim"]["duration"] = 10.0
    adjacency = parse_scenario(data).adjacency()
    links = edges_keeping_connected(adjacency, 1 if topology["kind"] == "cycle" else 2)
    data["faults"] = [
        {"at": 0.5, "kind": "drop_link", "link": links[0]},
        *({"at": 0.5, "kind": "drop_link", "link": link, "direction": "one"} for link in links[1:]),
        {"kind": "packet_loss", "p": 0.5},
    ]
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    code, stdout, metrics, _ = finish(path, tmp_path / "out")
    assert code == 0 and metrics["converged"] is True, stdout
    block = metrics["faults"]
    assert block["live_robots"] == list(range(6)) and block["live_graph_connected"] is True
    assert [entry["kind"] for entry in block["scheduled"]] == [fault["kind"] for fault in data["faults"]]
    messages = block["messages"]
    assert messages["invalid"] == 0 and messages["lost"] == 0  # nothing missing beyond the faults
    # each receiving agent counts a dropped link once a tick: ticks 11 to 199 use messages 10 to 198
    steps, start = 200, 10
    directions = 2 + len(links[1:])
    assert messages["dropped_by_fault"] == (steps - 1 - start) * directions
    needed = int(adjacency.sum()) * (steps - 1)  # messages the agents' ticks 1..199 name
    assert 0.45 < messages["lost_by_fault"] / (needed - messages["dropped_by_fault"]) < 0.55


@pytest.fixture(scope="module")
def lossy_cycle(tmp_path_factory):
    """Local consensus on the thesis cycle start with a dropped link, 50% packet loss and a delay on
    one link, 4 s (robots touch from ~3 s), run twice in the PyBullet runtime."""
    tmp_path = tmp_path_factory.mktemp("lossy")
    path = fault_scenario(
        tmp_path,
        "delay",
        sim__duration=4.0,
        sim__deadline=5.0,  # no loaded machine misses these: a missed one would change the trajectory
        sim__neighbour_deadline=5.0,
        faults=[
            {"at": 0.5, "kind": "drop_link", "link": [0, 1]},
            {"at": 1.5, "kind": "restore_link", "link": [0, 1]},
            {"kind": "packet_loss", "p": 0.5},
            {"at": 0.3, "kind": "delay", "ticks": 3, "link": [2, 3], "direction": "one"},
        ],
    )
    outs = []
    for attempt in range(2):
        out = tmp_path / f"run{attempt}"
        finish(path, out)
        outs.append(out)
    return load_scenario(path), outs


@pytest.mark.runtime
def test_lockstep_runs_with_packet_loss_are_reproducible(lossy_cycle):
    _, (first, second) = lossy_cycle
    assert (first / "trajectory.jsonl").read_text() == (second / "trajectory.jsonl").read_text()
    for out in (first, second):
        assert json.loads((out / "server_stats.json").read_text())["ticks_missed"] == 0


@pytest.mark.runtime
def test_every_command_is_what_the_kinematic_engine_computes_under_the_same_faults(lossy_cycle):
    """The agents apply the schedule at their transport layer exactly as the kinematic engine does:
    replaying the logged poses through it gives every command the agents sent, tick by tick."""
    scenario, (out, _) = lossy_cycle
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    poses = np.array([line["poses"] for line in lines])
    applied = np.array([line["wheels"] for line in lines[:-1]])
    robot = scenario.robot
    faults = LinkFaults.from_scenario(scenario)
    sim = KinematicSim(
        robot,
        LocalConsensus(robot),
        DT,
        poses[:1],
        adjacency=scenario.adjacency(),
        link_faults=faults,
    )
    expected = []
    for tick in range(len(applied)):
        sim.set_poses(poses[tick][None])
        expected.append(point_velocity_to_wheels(sim.act()[0], poses[tick, :, 2], robot))
        sim.tick += 1
    np.testing.assert_allclose(applied, np.array(expected), rtol=0, atol=1e-9)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["faults"]["messages"]["dropped_by_fault"] == sim.fault_counts["dropped_by_fault"]
    assert metrics["faults"]["messages"]["lost_by_fault"] == sim.fault_counts["lost_by_fault"]
    assert metrics["faults"]["messages"]["delayed_by_fault"] == sim.fault_counts["delayed_by_fault"] > 0
    # the same replay without the faults computes other commands: the check can tell them apart
    plain = KinematicSim(robot, LocalConsensus(robot), DT, poses[:1], adjacency=scenario.adjacency())
    unfaulty = []
    for tick in range(len(applied)):
        plain.set_poses(poses[tick][None])
        unfaulty.append(point_velocity_to_wheels(plain.act()[0], poses[tick, :, 2], robot))
    assert np.abs(applied - np.array(unfaulty)).max() > 1e-2


FAULTY_POSITION_TOLERANCE_M = 0.2
"""Kinematic vs PyBullet axle positions under the ``lossy_cycle`` faults, before the first contact.
Measured: 0.144 m at most over the 4 s (0.118 m with 20% loss instead of 50%), against 0.043 m for
the fault-free run (tests/test_runtime.py): every lost message changes a
robot's command abruptly, and each command change costs the physical robot 1-2 cm against the
kinematic unicycle's instant change of speed. The same kinematic run blind to the faults ends 1.08 m
away, so the check still tells whether both engines apply the faults."""


@pytest.mark.runtime
def test_both_engines_agree_on_a_fault_scenario_until_contact(lossy_cycle):
    scenario, (out, _) = lossy_cycle
    _, physical, _ = read_trajectory(out / "trajectory.jsonl")
    errors_m = []
    for faults in (LinkFaults.from_scenario(scenario), None):
        sim = KinematicSim(
            scenario.robot,
            LocalConsensus(scenario.robot, scenario.controller.gain),
            DT,
            scenario.initial_poses()[None],
            adjacency=scenario.adjacency(),
            link_faults=faults,
        )
        kinematic = sim.rollout(scenario.steps)[:, 0]
        contact_m = 2 * scenario.robot.body_radius_m + 0.02
        closest = [graphs_min_distance(trajectory) for trajectory in (kinematic, physical)]
        contact = (closest[0] < contact_m) | (closest[1] < contact_m)
        first_contact = int(np.argmax(contact)) if contact.any() else len(contact)
        assert first_contact > 20
        error_m = np.linalg.norm(physical[:first_contact, :, :2] - kinematic[:first_contact, :, :2], axis=-1)
        errors_m.append(error_m.max())
    assert errors_m[0] < FAULTY_POSITION_TOLERANCE_M, errors_m
    assert errors_m[1] > 3 * FAULTY_POSITION_TOLERANCE_M, errors_m


@pytest.mark.runtime
def test_a_drop_that_splits_the_graph_gives_per_component_consensus_and_a_restore_global(tmp_path):
    split = fault_scenario(tmp_path, "disconnect", faults=[{"at": 1.0, "kind": "drop_link", "link": [2, 3]}])
    data = yaml.safe_load(split.read_text())
    data["sim"]["duration"] = 5.0
    split.write_text(yaml.safe_dump(data))
    code, stdout, metrics, _ = finish(split, tmp_path / "split")
    assert code == 1 and "NOT converged" in stdout and "graph has 2 components" in stdout, stdout
    assert metrics["converged"] is False and metrics["graph_connected"] is False
    assert [c["robots"] for c in metrics["components"]] == [[0, 1, 2], [3, 4, 5]]
    assert all(c["converged"] for c in metrics["components"])
    assert (
        metrics["faults"]["links_down_at_end"] == [[2, 3]] and metrics["faults"]["every_component_converged"]
    )

    restored = fault_scenario(tmp_path, "disconnect", sim__duration=14.0)
    data = yaml.safe_load(restored.read_text())
    data["faults"][1]["at"] = 4.0
    restored.write_text(yaml.safe_dump(data))
    code, stdout, metrics, _ = finish(restored, tmp_path / "restored")
    assert code == 0 and metrics["converged"] is True and metrics["graph_connected"] is True, stdout
    assert metrics["convergence_time_s"] > 4.0  # not before the link came back
    assert metrics["faults"]["links_down_at_end"] == []


@pytest.mark.runtime
def test_an_agent_that_hears_nobody_holds_still(tmp_path):
    """Robot 0 of a GNN cycle stops hearing its two neighbours from the start (they still hear it):
    its wheels stay at zero all run, and the others gather around it."""
    path = fault_scenario(
        tmp_path,
        "drop-link",
        sim__duration=4.0,
        faults=[
            {"at": 0.0, "kind": "drop_link", "link": [1, 0], "direction": "one"},
            {"at": 0.0, "kind": "drop_link", "link": [5, 0], "direction": "one"},
        ],
    )
    _, _, metrics, records = finish(path, tmp_path / "out")
    lines = [json.loads(line) for line in (tmp_path / "out" / "trajectory.jsonl").read_text().splitlines()]
    wheels = np.array([line["wheels"] for line in lines[:-1]])
    assert np.all(wheels[:, 0] == 0.0) and np.abs(wheels[:, 1:]).max() > 0.1
    assert records[0]["messages"]["dropped_by_fault"] == 2 * (len(wheels) - 1)
    assert records[1]["messages"]["dropped_by_fault"] == 0
    poses = np.array([line["poses"] for line in lines])
    assert np.abs(poses[-1, 0, :2] - poses[0, 0, :2]).max() < 0.01  # pushed at most by contact
    assert metrics["faults"]["live_graph_connected"] is True
