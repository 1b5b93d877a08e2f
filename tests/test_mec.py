"""The minimum-enclosing-circle controllers: ``mec_flood`` (decentralized) and ``centralized_mec``.

Oracles are independent of the code under test: Welzl's circle of ``swarm.core.metrics`` for the numba
circle, hand-written hop counts on a line, a numpy argmax over the initial positions for the
completed flood, ``swarm.core.experts`` (numpy) for the kernels' drive law.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.core import graphs, metrics
from swarm.core.experts import centralized_mec_velocity, drive_toward_velocity
from swarm.core.faults import LinkFaults
from swarm.core.robot import RobotParams, point_velocity_to_wheels
from swarm.scenarios.scenario import ScenarioError, parse_scenario
from swarm.scenarios.sweep import SweepConfig, converge_batch
from swarm.sim.controller_kinds import robot_controller
from swarm.sim.controllers import CentralizedMec, MecFlood
from swarm.sim.kinematic import KinematicSim
from swarm.sim.mec_kernels import welzl_circle
from swarm.sim.onboard import OnboardMecFlood

ROBOT = RobotParams()
DT = 0.05
M = 16


def support_oracle(positions: np.ndarray, directions: int = M) -> np.ndarray:
    """Per direction d_m the point of largest <p, d_m> (numpy argmax; ties do not occur here)."""
    angles = 2 * np.pi * np.arange(directions) / directions
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return positions[np.argmax(positions @ d.T, axis=0)]


def supports(outbox: np.ndarray) -> np.ndarray:
    """``(..., D)`` messages -> ``(..., M, 2)`` support points."""
    return outbox[..., : 2 * M].reshape(*outbox.shape[:-1], M, 2)


@pytest.mark.parametrize("count", [1, 2, 3, 4, 7, 16, 60])
def test_numba_circle_is_welzls_circle(count):
    rng = np.random.default_rng(count)
    for trial in range(40):
        points = rng.normal(size=(count, 2)) * rng.uniform(0.01, 10)
        if trial % 4 == 1:
            points[: count // 2] = points[0]  # repeated points
        if trial % 4 == 2:
            points[:, 1] = 2.0 * points[:, 0] + 1.0  # collinear
        centre, radius = metrics.minimum_enclosing_circle(points)
        cx, cy, r = welzl_circle(points[:, 0].copy(), points[:, 1].copy(), count)
        assert r == pytest.approx(radius, abs=1e-9 * max(1.0, radius))
        assert math.hypot(cx - centre[0], cy - centre[1]) <= 1e-7 * max(1.0, radius)
        assert np.all(np.hypot(points[:, 0] - cx, points[:, 1] - cy) <= r + 1e-12 * max(1, r))


def line_start(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    poses = np.zeros((1, count, 3))
    poses[0, :, 0] = np.arange(count) * 1.0
    poses[0, :, 1] = rng.uniform(-0.2, 0.2, count)
    poses[0, :, 2] = rng.uniform(-np.pi, np.pi, count)
    return poses


def test_flood_on_a_line_knows_exactly_k_hops_after_k_ticks():
    """Robots 0..5 on a line at x = 0..5: after tick k robot i's +x support is robot min(i+k, 5)'s
    initial position and its -x support robot max(i-k, 0)'s (hand-counted hops)."""
    count = 6
    start = line_start(count)
    sim = KinematicSim(ROBOT, MecFlood(ROBOT, DT), DT, start, adjacency=graphs.line(count))
    for tick in range(count + 1):
        sim.step()  # the inbox now holds what every robot sent at `tick`
        known = supports(sim.inbox[0])
        for i in range(count):
            assert np.array_equal(known[i, 0], start[0, min(i + tick, count - 1), :2]), (tick, i)
            assert np.array_equal(known[i, M // 2], start[0, max(i - tick, 0), :2]), (tick, i)


def test_once_the_flood_is_complete_every_robot_has_the_same_target():
    count = 12
    rng = np.random.default_rng(3)
    start = np.concatenate([rng.uniform(-3, 3, (4, count, 2)), rng.uniform(-np.pi, np.pi, (4, count, 1))], -1)
    adjacency = np.stack([graphs.erdos_renyi(count, 0.3, seed, connected=True) for seed in range(4)])
    sim = KinematicSim(ROBOT, MecFlood(ROBOT, DT), DT, start, adjacency=adjacency)
    for _ in range(count):  # more than any diameter
        sim.step()
    u_world = sim.act()
    for env in range(4):
        expected = support_oracle(start[env, :, :2])
        for i in range(count):
            np.testing.assert_array_equal(supports(sim.inbox[env, i]), expected)
        centre, _ = metrics.minimum_enclosing_circle(expected)
        targets = np.broadcast_to(centre, (count, 2))
        law = drive_toward_velocity(sim.poses[env], targets, ROBOT.v_max_mps, DT)
        np.testing.assert_allclose(u_world[env], law, atol=1e-9)


def test_lost_and_delayed_messages_only_delay_the_flood():
    count = 10
    start = line_start(count, seed=1)
    faults = LinkFaults(
        [{"kind": "packet_loss", "p": 0.5}, {"kind": "delay", "ticks": 2, "at_s": 0.2, "until_s": 0.6}],
        DT,
        seed=4,
    )
    clean = KinematicSim(ROBOT, MecFlood(ROBOT, DT), DT, start, adjacency=graphs.line(count))
    lossy = KinematicSim(
        ROBOT,
        MecFlood(ROBOT, DT),
        DT,
        start,
        adjacency=graphs.line(count),
        link_faults=faults,
        message_max_age_ticks=1,
    )
    angles = 2 * np.pi * np.arange(M) / M
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    expected = support_oracle(start[0, :, :2])
    complete_at = {}
    for tick in range(200):
        clean.step()
        lossy.step()
        for name, sim in (("clean", clean), ("lossy", lossy)):
            known = supports(sim.inbox[0][:count])
            # everything known is some robot's initial position, never beyond the true support
            assert np.all(np.einsum("imk,mk->im", known, d) <= (expected * d).sum(-1) + 1e-12)
            if name not in complete_at and np.array_equal(known, np.broadcast_to(expected, known.shape)):
                complete_at[name] = tick
    assert lossy.fault_counts["lost_by_fault"] > 0
    assert complete_at["clean"] == count - 1  # diameter 9: the message of tick 9
    assert complete_at["clean"] < complete_at["lossy"] < 200


def test_decentralized_robot_0_of_a_line_of_10_ignores_robot_9_for_8_ticks():
    count = 10
    start = line_start(count, seed=2)
    moved = start.copy()
    moved[0, 9] += [3.0, -2.0, 1.0]
    runs = []
    for poses in (start, moved):
        sim = KinematicSim(ROBOT, MecFlood(ROBOT, DT), DT, poses, adjacency=graphs.line(count))
        commands = []
        for _ in range(10):
            u_world = sim.act()
            commands.append(u_world[0, 0].copy())
            advance(sim, u_world[0])
        runs.append(np.array(commands))
    np.testing.assert_array_equal(runs[0][:8], runs[1][:8])
    assert np.abs(runs[0][8:] - runs[1][8:]).max() > 1e-6  # tick 9: robot 9's start has arrived


@pytest.mark.parametrize(
    ("offset_m", "grid"), [(ROBOT.offset_m, False), (0.2, False), (ROBOT.offset_m, True)]
)
def test_onboard_flood_computes_what_the_batched_one_computes_whatever_the_order(offset_m, grid):
    """Per-robot (plain floats, the agents' code) vs the numba kernel, tick by tick, with neighbours
    heard in a shuffled order and some messages heard twice (idempotent, commutative merge). On a
    grid start robots share coordinates, so support points tie in projection and the merge's
    tie-break (larger x, then larger y) decides: the kernel's inline copy must break ties alike."""
    count = 8
    robot = RobotParams(offset_m=offset_m)
    rng = np.random.default_rng(5)
    adjacency = graphs.erdos_renyi(count, 0.4, 1, connected=True)
    start = np.concatenate([rng.uniform(-2, 2, (1, count, 2)), rng.uniform(-np.pi, np.pi, (1, count, 1))], -1)
    if grid:  # a 4 x 2 grid, 1 m apart, 2 km from the origin, in shuffled order
        cells = np.stack(np.meshgrid(np.arange(4.0), np.arange(2.0)), -1).reshape(-1, 2)
        start[0, :, :2] = 2000.0 + cells[rng.permutation(count)]
    sim = KinematicSim(robot, MecFlood(robot, DT, reverse=True), DT, start, adjacency=adjacency)
    agents = [OnboardMecFlood(robot, DT) for _ in range(count)]
    last = None
    for _ in range(25):
        poses = sim.poses[0].copy()
        u_batched = sim.act()[0]
        outbox = sim.inbox[0]
        for i, agent in enumerate(agents):
            heard = [] if last is None else [last[j] for j in np.flatnonzero(adjacency[i])]
            heard = [heard[k] for k in rng.permutation(len(heard))] + heard[:1]
            u, message = agent.act_floats(*poses[i], heard)
            np.testing.assert_allclose(u, u_batched[i], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(message, outbox[i])
        last = [list(row) for row in outbox]
        advance(sim, u_batched, robot)


def advance(sim: KinematicSim, u_world: np.ndarray, robot: RobotParams = ROBOT) -> None:
    """Move the robots with the commands :meth:`KinematicSim.act` already returned."""
    from swarm.sim import kernels

    kernels.advance_unicycles(
        sim.poses.reshape(-1, 3),
        sim.headings.reshape(-1, 2),
        sim.points.reshape(-1, 2),
        np.ascontiguousarray(u_world[None]).reshape(-1, 2),
        robot.offset_m,
        robot.half_axle_m,
        robot.v_max_mps,
        DT,
    )
    sim.tick += 1


def test_a_restarted_robot_starts_afresh_and_is_flooded_back():
    count = 6
    start = line_start(count, seed=6)
    agents = [OnboardMecFlood(ROBOT, DT) for _ in range(count)]
    messages = [None] * count
    for tick in range(30):
        if tick == 12:
            agents[2] = robot_controller("mec_flood", ROBOT, control_period_s=DT)  # a fresh process
            first_u, first = agents[2].act_floats(9.0, 9.0, 0.0, [])
            assert first_u == (0.0, 0.0)  # knows nobody: holds still
            assert first[: 2 * M] == [9.0, 9.0] * M  # its current position, nothing remembered
        new = []
        for i, agent in enumerate(agents):
            heard = [messages[j] for j in (i - 1, i + 1) if 0 <= j < count and messages[j] is not None]
            new.append(agent.act_floats(*start[0, i], heard)[1])
        messages = new
    expected = support_oracle(np.vstack([start[0, :, :2], [[9.0, 9.0]]]))
    for message in messages:
        np.testing.assert_array_equal(np.reshape(message[: 2 * M], (M, 2)), expected)


def test_reverse_drives_backwards_to_a_target_behind():
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    targets = np.array([[-2.0, 0.3], [2.0, 0.3]])
    u = drive_toward_velocity(poses, targets, ROBOT.v_max_mps, DT)
    wheels = point_velocity_to_wheels(u, poses[:, 2], ROBOT)
    assert np.all(wheels[0] < 0) and np.all(wheels[1] > 0)  # backwards / forwards
    # backwards: the rear point x - l h moves along axle -> target (v < 0, turning toward +y from behind)
    v, w = wheels[0].mean(), (wheels[0, 1] - wheels[0, 0]) / (2 * ROBOT.half_axle_m)
    rear_velocity = np.array([v, -ROBOT.offset_m * w])
    direction = targets[0] - poses[0, :2]
    cross = rear_velocity[0] * direction[1] - rear_velocity[1] * direction[0]
    assert cross == pytest.approx(0.0, abs=1e-9)
    assert rear_velocity @ direction > 0
    forward = drive_toward_velocity(poses, targets, ROBOT.v_max_mps, DT, reverse=False)
    np.testing.assert_array_equal(forward[1], u[1])  # target ahead: the same command
    assert np.abs(forward[0] - u[0]).max() > 0.1  # behind: the point ahead of the axle leads instead


@pytest.mark.parametrize("backward", [True, False])
def test_a_chosen_law_reaches_the_target_and_arrives_facing_its_way(backward):
    """``backward`` forces the law whatever the heading: both robots (target ahead, target behind)
    reach it, facing back along their way in (backward) or along it (forward). Integrated here from
    the wheel speeds, not by the engine."""
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi]])
    targets = np.array([[2.0, 0.5], [2.0, 0.5]])
    for _ in range(400):
        u = drive_toward_velocity(poses, targets, ROBOT.v_max_mps, DT, backward=np.array([backward] * 2))
        wheels = point_velocity_to_wheels(u, poses[:, 2], ROBOT)
        v, w = wheels.mean(-1), (wheels[:, 1] - wheels[:, 0]) / (2 * ROBOT.half_axle_m)
        poses = poses + DT * np.c_[v * np.cos(poses[:, 2]), v * np.sin(poses[:, 2]), w]
    np.testing.assert_allclose(poses[:, :2], targets, atol=1e-3)
    way_in = targets[0] / np.linalg.norm(targets[0])
    facing = np.c_[np.cos(poses[:, 2]), np.sin(poses[:, 2])] @ way_in
    assert np.all(facing < -0.9) if backward else np.all(facing > 0.9), facing


@pytest.mark.parametrize("offset_m", [ROBOT.offset_m, 0.2])
def test_centralized_mec_kernel_is_the_numpy_expert(offset_m):
    rng = np.random.default_rng(8)
    poses = np.concatenate([rng.uniform(-4, 4, (3, 30, 2)), rng.uniform(-np.pi, np.pi, (3, 30, 1))], -1)
    u, _ = CentralizedMec(RobotParams(offset_m=offset_m), DT).act(poses, None, np.zeros((3, 30, 0)), None)
    for env in range(3):
        expected = centralized_mec_velocity(poses[env], ROBOT.v_max_mps, DT)
        np.testing.assert_allclose(u[env], expected, atol=1e-9)


@pytest.mark.parametrize(
    ("topology", "controller"),
    [
        ("line", "mec_flood"),
        ("disk", "mec_flood"),
        ("cycle", "centralized_mec"),
        ("line", "mec_flood_forward"),
    ],
)
def test_mec_controllers_gather_near_the_lower_bound(topology, controller):
    from swarm.scenarios.sweep import run_cell, summarize_cell

    config = SweepConfig(seeds=1000, first_starts=40, controllers=[controller])
    row = summarize_cell(run_cell(config, topology, 24, controller))
    assert row["success_rate"] == 1.0
    assert row["median_ratio_to_lower_bound"] < 1.08


@pytest.mark.slow
def test_flood_gathers_under_half_the_messages_lost():
    config = SweepConfig(seeds=1000, first_starts=60, packet_loss=0.5)
    from swarm.scenarios.sweep import run_cell, summarize_cell

    lossy = summarize_cell(run_cell(config, "line", 24, "mec_flood"))
    assert lossy["success_rate"] == 1.0 and lossy["median_ratio_to_lower_bound"] < 1.10


def test_scenario_schema_takes_the_new_kinds_and_names_bad_options():
    base = {
        "name": "x",
        "robots": {"count": 4},
        "topology": {"kind": "cycle"},
        "sim": {"engine": "kinematic"},
    }
    spec = parse_scenario(
        {**base, "controller": {"kind": "mec_flood", "directions": 8, "reverse": False}}, "f.yaml"
    )
    assert (spec.controller.directions, spec.controller.reverse) == (8, False)
    assert parse_scenario({**base, "controller": {"kind": "centralized_mec"}}, "f.yaml").controller.central
    bad = [
        ({"kind": "mec_flood", "directions": 2}, "controller.directions"),
        ({"kind": "local_consensus", "directions": 8}, "controller.directions"),
        ({"kind": "centralized_mec", "directions": 8}, "controller.directions"),
        ({"kind": "flood"}, "controller.kind"),
    ]
    for controller, key in bad:
        with pytest.raises(ScenarioError) as error:
            parse_scenario({**base, "controller": controller}, "f.yaml")
        message = str(error.value)
        assert "\n" not in message and message.startswith("f.yaml") and key in message, message


def test_sweep_runs_mec_flood_on_the_line_sorted_by_x():
    from swarm.scenarios.sweep import cell_starts

    config = SweepConfig(seeds=1000, first_starts=5)
    line, _, _ = cell_starts(config, "line", 12)
    ordered, adjacency, _ = cell_starts(config, "line_sorted", 12)
    assert np.all(np.diff(ordered[..., 0], axis=1) >= 0)
    np.testing.assert_array_equal(np.sort(line[..., 0], axis=1), ordered[..., 0])
    np.testing.assert_array_equal(adjacency[0], graphs.line(12))
    sim = KinematicSim(ROBOT, MecFlood(ROBOT, DT), DT, ordered, adjacency=adjacency)
    times = converge_batch(sim, 0.2, 200.0, 5.0)
    assert not np.isnan(times).any()


def test_disconnection_check_of_the_sweep_agrees_with_the_dense_one():
    from swarm.scenarios.sweep import connected, links_connected
    from swarm.sim.links import Links

    rng = np.random.default_rng(0)
    positions = rng.uniform(-3, 3, (200, 20, 2))
    for radius in (1.4, 1.7, 2.5):
        links = Links.disk(positions, radius)
        dense = connected(links.dense)
        assert 0 < dense.mean() < 1 or radius == 2.5
        np.testing.assert_array_equal(links_connected(links), dense)


@pytest.mark.parametrize("controller", [MecFlood, CentralizedMec])
@pytest.mark.parametrize("offset_m", [0.01, 0.2, 1.0])
def test_the_baselines_gather_the_axles_whatever_the_offset(controller, offset_m):
    """Success is judged on the axles (``swarm.core.metrics.max_pairwise`` of the poses): with the
    controlled point far ahead (0.2 m, 1 m; the schema takes any positive offset) both baselines
    must bring the axles within the 0.2 m threshold, not only their controlled points (which left
    the axles up to 2 l apart: 0 of 8 starts converged at l = 0.2 m before)."""
    robot = RobotParams(offset_m=offset_m)
    rng = np.random.default_rng(11)
    count, batch = 6, 8
    start = np.concatenate(
        [rng.uniform(-3, 3, (batch, count, 2)), rng.uniform(-np.pi, np.pi, (batch, count, 1))], -1
    )
    sim = KinematicSim(
        robot, controller(robot, DT), DT, start, adjacency=np.stack([graphs.cycle(count)] * batch)
    )
    for _ in range(round(40.0 / DT)):
        sim.step()
    assert np.all(metrics.max_pairwise(sim.poses[..., :2]) <= 0.2)
