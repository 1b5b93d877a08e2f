"""Tests for the batched kinematic simulator (swarm.sim.kinematic), its numba kernels (swarm.sim.kernels), the
neighbour lists (swarm.sim.links) and the batched controllers (swarm.sim.controllers).

Covers: kernels == numpy reference of swarm.core.robot; the information timing of docs/design.md (tick 0, k-1
messages, k hops = k ticks); batched == per-robot controller; symmetries (relabelling, rigid motions);
centroid conservation; disk graphs; keep(); batch == separate runs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarm.core import graphs
from swarm.core.experts import consensus_velocity
from swarm.core.robot import (
    RobotParams,
    controlled_point,
    integrate_unicycle,
    point_velocity_to_wheels,
    wrap_angle,
)
from swarm.sim import kernels
from swarm.sim.controllers import Centralized, LocalConsensus
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links

CONTROLLERS = [LocalConsensus, Centralized]
seeds = st.integers(0, 2**32 - 1)


def random_poses(rng: np.random.Generator, batch: int, count: int, half_width: float = 2.0) -> np.ndarray:
    xy = rng.uniform(-half_width, half_width, size=(batch, count, 2))
    theta = rng.uniform(-math.pi, math.pi, size=(batch, count, 1))
    return np.concatenate([xy, theta], axis=-1)


def random_symmetric(rng: np.random.Generator, count: int, p: float = 0.5) -> np.ndarray:
    upper = np.triu(rng.random((count, count)) < p, k=1).astype(float)
    return upper + upper.T


def assert_same_poses(actual: np.ndarray, expected: np.ndarray, atol: float) -> None:
    np.testing.assert_allclose(actual[..., :2], expected[..., :2], rtol=0, atol=atol)
    np.testing.assert_allclose(wrap_angle(actual[..., 2] - expected[..., 2]), 0.0, rtol=0, atol=atol)


# ---------------------------------------------------------------- (a) kernel == numpy reference


def run_kernel(poses: np.ndarray, u: np.ndarray, params: RobotParams, dt: float):
    poses = np.array(poses, dtype=float)
    headings = np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=-1)
    points = np.full((len(poses), 2), np.nan)  # rewritten by the kernel
    kernels.advance_unicycles(
        poses,
        headings,
        points,
        np.array(u, dtype=float),
        params.offset_m,
        params.half_axle_m,
        params.v_max_mps,
        dt,
    )
    return poses, headings, points


def reference_step(poses: np.ndarray, u: np.ndarray, params: RobotParams, dt: float) -> np.ndarray:
    wheels = point_velocity_to_wheels(u, poses[:, 2], params)
    return integrate_unicycle(poses, wheels, params.half_axle_m, dt)


def check_kernel_against_reference(poses, u, params, dt):
    new, headings, points = run_kernel(poses, u, params, dt)
    expected = reference_step(poses, u, params, dt)
    assert_same_poses(new, expected, atol=1e-12)
    assert np.all((new[:, 2] >= -math.pi) & (new[:, 2] <= math.pi))
    np.testing.assert_allclose(headings, np.stack([np.cos(new[:, 2]), np.sin(new[:, 2])], -1), atol=1e-12)
    np.testing.assert_allclose(points, controlled_point(expected, params.offset_m), rtol=0, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    seed=seeds,
    v_max=st.floats(0.05, 2.0),
    dt=st.floats(0.005, 0.5),
    half_axle=st.floats(0.03, 0.3),
    offset=st.floats(0.01, 0.3),
    scale=st.sampled_from([0.01, 0.3, 5.0]),
)
def test_advance_unicycles_equals_numpy_reference(seed, v_max, dt, half_axle, offset, scale):
    rng = np.random.default_rng(seed)
    count = 64
    params = RobotParams(v_max_mps=v_max, half_axle_m=half_axle, offset_m=offset)
    poses = random_poses(rng, 1, count, half_width=5.0)[0]
    # headings at and next to the wrap point +-pi
    poses[:8, 2] = [-math.pi, math.pi - 1e-15, -math.pi + 1e-15, math.pi - 1e-9, 3.14, -3.14, 0.0, -0.0]
    u = rng.normal(0.0, scale, size=(count, 2))
    u[:4] = 0.0
    check_kernel_against_reference(poses, u, params, dt)


def test_advance_unicycles_large_turns_take_the_non_series_branch():
    # v_max / d = 1 / 0.1 = 10 rad/s; with dt = 0.4 s the half turn is w dt / 2 = 2 rad (> 0.25: sin/cos)
    params = RobotParams(v_max_mps=1.0, half_axle_m=0.1, offset_m=0.05)
    poses = np.array([[0.0, 0.0, 3.0], [1.0, -1.0, -3.0], [0.5, 0.5, math.pi - 1e-12], [0.0, 0.0, -math.pi]])
    u = np.array([[0.0, 5.0], [0.1, -5.0], [-3.0, 2.0], [0.2, 0.2]])
    for dt in (0.4, 0.051, 0.05, 1.0):
        check_kernel_against_reference(poses, u, params, dt)
    # pure turn by hand: u = (0, 5) with heading 0 wants v = 0, w = 5 / 0.05 = 100 rad/s: wheels (-10, 10)
    # saturate by 1/10 to (-1, 1), w = 10 rad/s; in 0.1 s the heading turns by exactly 1 rad in place
    new, _, _ = run_kernel(np.array([[2.0, 3.0, 0.0]]), np.array([[0.0, 5.0]]), params, 0.1)
    np.testing.assert_allclose(new, [[2.0, 3.0, 1.0]], atol=1e-12)


# ---------------------------------------------------------------- (b) timing at tick 0 and tick k-1


def two_robots(controller_class, gain: float = 1.0):
    params = RobotParams(v_max_mps=10.0)  # never saturates here
    poses = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    return KinematicSim(params, controller_class(params, gain), 0.1, poses, adjacency=graphs.complete(2))


def test_local_consensus_holds_still_at_tick_zero():
    rng = np.random.default_rng(1)
    poses = random_poses(rng, 3, 5)
    params = RobotParams()
    sim = KinematicSim(params, LocalConsensus(params), 0.05, poses, adjacency=graphs.complete(5))
    sim.step()
    np.testing.assert_array_equal(sim.poses, poses)
    assert sim.tick == 1
    assert sim.time_s == pytest.approx(0.05)
    sim.step()
    assert np.abs(sim.poses - poses).max() > 1e-3


def test_centralized_moves_at_tick_zero():
    # u_0 = -K (2 p_0 - (p_0 + p_1)) = p_1 - p_0 = (1.05 - 0.05, 0) = (1, 0): heading 0 so v = 1, w = 0;
    # in 0.1 s robot 0 moves 0.1 m forward, robot 1 (u = (-1, 0)) 0.1 m backward
    sim = two_robots(Centralized)
    sim.step()
    np.testing.assert_allclose(sim.poses[0], [[0.1, 0.0, 0.0], [0.9, 0.0, 0.0]], atol=1e-12)


def test_command_at_tick_k_uses_neighbour_points_of_tick_k_minus_1():
    # Two robots facing +x, l = 0.05, K = 1, dt = 0.1, no saturation; the controlled points are on the
    # x-axis at x0 + 0.05 and x1 + 0.05, so everything stays on the x-axis with w = 0 and v = u_x.
    # tick 0: nobody heard anybody: x0 = 0 stays 0, x1 = 1 stays 1.
    # tick 1: inbox = points of tick 0 = (0.05, 1.05): u0 = -(0.05 - 1.05) = 1   -> x0 = 0 + 0.1 = 0.1
    #                                                   u1 = -(1.05 - 0.05) = -1 -> x1 = 1 - 0.1 = 0.9
    # tick 2: inbox = points of tick 1 = (0.05, 1.05) (nobody moved at tick 0):
    #         u0 = -(0.15 - 1.05) = 0.9 -> x0 = 0.19   (with tick 2's point 0.95 it would be 0.8 -> 0.18)
    #         u1 = -(0.95 - 0.05) = -0.9 -> x1 = 0.81
    # tick 3: inbox = points of tick 2 = (0.15, 0.95): u0 = -(0.24 - 0.95) = 0.71 -> x0 = 0.261; x1 = 0.739
    sim = two_robots(LocalConsensus)
    trajectory = sim.rollout(4)
    expected_x0 = [0.0, 0.0, 0.1, 0.19, 0.261]
    np.testing.assert_allclose(trajectory[:, 0, 0, 0], expected_x0, atol=1e-12)
    np.testing.assert_allclose(trajectory[:, 0, 1, 0], 1.0 - np.array(expected_x0), atol=1e-12)
    np.testing.assert_allclose(trajectory[..., 1:], 0.0, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=seeds, count=st.integers(2, 7), gain=st.floats(0.2, 3.0))
def test_delayed_consensus_matches_hand_written_recursion(seed, count, gain):
    # the same timing for any graph: u_i(k) = -K sum_j A_ij (p_i(k) - p_j(k-1)) for k >= 1, 0 at k = 0
    rng = np.random.default_rng(seed)
    params = RobotParams()
    adjacency = random_symmetric(rng, count)
    poses = random_poses(rng, 1, count)
    sim = KinematicSim(params, LocalConsensus(params, gain), 0.05, poses, adjacency=adjacency)
    trajectory = sim.rollout(6)
    expected = poses[0]
    previous_points = None
    for k in range(6):
        points = controlled_point(expected, params.offset_m)
        if previous_points is None:
            u = np.zeros_like(points)
        else:
            u = -gain * (adjacency.sum(1)[:, None] * points - adjacency @ previous_points)
        expected = reference_step(expected, u, params, 0.05)
        previous_points = points
        assert_same_poses(trajectory[k + 1, 0], expected, atol=1e-9)


# ---------------------------------------------------------------- (c) k hops away = k ticks old


class TickRelay:
    """A real controller (not a mock) that relays how fresh its news of robot ``source`` is: the source
    broadcasts ``k + 1`` at tick k, everyone else rebroadcasts the largest value it heard last tick
    (0 = no news yet). It never moves."""

    message_dim = 1
    centralized = False

    def __init__(self, source: int):
        self.source = source
        self.tick = 0

    def act(self, poses, points, inbox, heard):
        dense = heard.dense
        relayed = np.where(dense > 0, inbox[..., 0][:, None, :], 0.0).max(axis=-1, initial=0.0)
        relayed[:, self.source] = self.tick + 1
        self.tick += 1
        return np.zeros_like(points), relayed[..., None]


def test_information_from_k_hops_is_k_ticks_old():
    count = 6
    params = RobotParams()
    sim = KinematicSim(
        params,
        TickRelay(source=0),
        0.05,
        random_poses(np.random.default_rng(0), 2, count),
        adjacency=graphs.line(count),
    )
    for k in range(10):
        sim.step()
        # after acting at tick k, robot h (h hops from robot 0) sends what robot 0 sent at tick k - h,
        # i.e. (k - h) + 1; before tick h it has heard nothing
        expected = np.array([k - h + 1 if k >= h else 0 for h in range(count)], dtype=float)
        np.testing.assert_array_equal(sim.inbox[..., 0], np.broadcast_to(expected, (2, count)))


def test_consensus_news_of_a_displaced_robot_spreads_one_hop_per_two_ticks():
    # Line 0 - 1 - 2 - 3; robots 1..3 sit at one pose (consensus), robot 0 elsewhere. Under local
    # consensus a robot's position reaches a neighbour's command one tick later (message), and the
    # neighbour's reaction reaches the next robot only after it has moved (one more tick): robot h first
    # moves during tick 2h - 1, so robot 2 starts two ticks after robot 1, robot 3 two ticks after robot 2.
    params = RobotParams()
    poses = np.array([[[-1.0, 0.0, 0.3], [1.0, 0.5, 2.0], [1.0, 0.5, 2.0], [1.0, 0.5, 2.0]]])
    sim = KinematicSim(params, LocalConsensus(params), 0.05, poses, adjacency=graphs.line(4))
    trajectory = sim.rollout(8)
    moved = np.abs(trajectory[:, 0, :, :2] - poses[0, :, :2]).max(axis=-1) > 1e-9  # (ticks, robots)
    first_moved_tick = [int(np.argmax(moved[:, robot])) for robot in range(4)]
    # pose at tick t is the result of the command at tick t - 1
    assert first_moved_tick == [2, 2, 4, 6]


# ---------------------------------------------------------------- (d) batched == per-robot


@settings(max_examples=30, deadline=None)
@given(seed=seeds, batch=st.integers(1, 4), count=st.integers(1, 8), gain=st.floats(0.1, 5.0))
def test_local_consensus_batched_equals_per_robot(seed, batch, count, gain):
    rng = np.random.default_rng(seed)
    params = RobotParams()
    controller = LocalConsensus(params, gain)
    poses = random_poses(rng, batch, count)
    points = controlled_point(poses, params.offset_m)
    inbox = rng.uniform(-3, 3, size=(batch, count, 2))
    # heard need not be symmetric: a lost packet removes one direction only
    heard = (rng.random((batch, count, count)) < 0.5) & ~np.eye(count, dtype=bool)
    u, outbox = controller.act(poses, points, inbox, Links.from_dense(heard.astype(float)))
    for b in range(batch):
        for i in range(count):
            u_one, message = controller.act_one(poses[b, i], inbox[b, np.flatnonzero(heard[b, i])])
            np.testing.assert_allclose(u[b, i], u_one, rtol=0, atol=1e-12)
            np.testing.assert_allclose(outbox[b, i], message, rtol=0, atol=1e-15)


def test_act_one_with_no_neighbours_holds_still():
    controller = LocalConsensus(RobotParams())
    u, message = controller.act_one(np.array([1.0, 2.0, 0.0]), np.empty((0, 2)))
    np.testing.assert_array_equal(u, [0.0, 0.0])
    np.testing.assert_allclose(message, [1.05, 2.0])


def test_links_dense_round_trip_with_weights():
    rng = np.random.default_rng(3)
    weights = rng.uniform(0.5, 2.0, size=(2, 5, 5)) * (rng.random((2, 5, 5)) < 0.5)
    links = Links.from_dense(weights)
    np.testing.assert_array_equal(Links(links.index, links.weight).dense, weights)
    np.testing.assert_allclose(links.heard_count(), weights.sum(-1))


# ---------------------------------------------------------------- (e) symmetries and conservation


@settings(max_examples=20, deadline=None)
@given(
    seed=seeds,
    permutation=st.integers(3, 7).flatmap(lambda n: st.permutations(list(range(n)))),
    controller_class=st.sampled_from(CONTROLLERS),
    disk=st.booleans(),
)
def test_relabelling_robots_permutes_the_trajectory(seed, permutation, controller_class, disk):
    rng = np.random.default_rng(seed)
    count = len(permutation)
    perm = np.array(permutation)
    params = RobotParams()
    poses = random_poses(rng, 2, count)
    if disk:
        graph = {"disk_radius_m": 2.5}
        relabelled_graph = graph
    else:
        adjacency = random_symmetric(rng, count)
        graph = {"adjacency": adjacency}
        relabelled_graph = {"adjacency": adjacency[np.ix_(perm, perm)]}
    original = KinematicSim(params, controller_class(params), 0.05, poses, **graph)
    relabelled = KinematicSim(params, controller_class(params), 0.05, poses[:, perm], **relabelled_graph)
    trajectory = original.rollout(15)
    relabelled_trajectory = relabelled.rollout(15)
    assert_same_poses(relabelled_trajectory, trajectory[:, :, perm], atol=1e-9)


def commanded_wheels(sim: KinematicSim, heard: Links) -> np.ndarray:
    """Wheel speeds the sim's controller commands at the current tick (fixed graph, tick >= 1)."""
    u, _ = sim.controller.act(sim.poses, sim.points, sim.inbox, heard)
    return point_velocity_to_wheels(u, sim.poses[..., 2], sim.robot)


@settings(max_examples=20, deadline=None)
@given(
    seed=seeds,
    angle=st.floats(-math.pi, math.pi),
    shift=st.tuples(st.floats(-10, 10), st.floats(-10, 10)),
    controller_class=st.sampled_from(CONTROLLERS),
)
def test_rigid_motion_of_the_swarm_leaves_local_commands_unchanged(seed, angle, shift, controller_class):
    rng = np.random.default_rng(seed)
    count = 5
    params = RobotParams()
    adjacency = graphs.erdos_renyi(count, 0.5, seed % 1000, connected=True)
    poses = random_poses(rng, 1, count)
    c, s = math.cos(angle), math.sin(angle)
    moved = poses.copy()
    moved[..., 0] = c * poses[..., 0] - s * poses[..., 1] + shift[0]
    moved[..., 1] = s * poses[..., 0] + c * poses[..., 1] + shift[1]
    moved[..., 2] = wrap_angle(poses[..., 2] + angle)
    heard = Links.from_dense(adjacency[None])
    original = KinematicSim(params, controller_class(params), 0.05, poses, adjacency=adjacency)
    transformed = KinematicSim(params, controller_class(params), 0.05, moved, adjacency=adjacency)
    original.step()
    transformed.step()
    for _ in range(12):
        np.testing.assert_allclose(
            commanded_wheels(transformed, heard), commanded_wheels(original, heard), rtol=0, atol=1e-9
        )
        original.step()
        transformed.step()
    # and the transformed swarm is where the transformed original swarm is
    expected = original.poses.copy()
    expected[..., 0] = c * original.poses[..., 0] - s * original.poses[..., 1] + shift[0]
    expected[..., 1] = s * original.poses[..., 0] + c * original.poses[..., 1] + shift[1]
    expected[..., 2] = original.poses[..., 2] + angle
    assert_same_poses(transformed.poses, expected, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(seed=seeds, count=st.integers(1, 10), gain=st.floats(0.01, 10.0))
def test_consensus_velocities_sum_to_zero_on_symmetric_graphs(seed, count, gain):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-5, 5, size=(count, 2))
    weights = np.triu(rng.uniform(0, 2, size=(count, count)) * (rng.random((count, count)) < 0.6), k=1)
    adjacency = weights + weights.T
    u = consensus_velocity(points, adjacency, gain)
    scale = gain * max(1.0, adjacency.sum()) * 5.0
    np.testing.assert_allclose(u.sum(axis=0), 0.0, atol=1e-12 * scale)
    # so the centroid of the points has zero velocity (and an explicit Euler step keeps it)
    np.testing.assert_allclose((points + 0.01 * u).mean(0), points.mean(0), atol=1e-12 * scale)


CENTROID_DT_S = 0.001
CENTROID_TOLERANCE_M = 0.02  # with the swarm in a 4 m x 4 m box; measured drift is about 8 m/s x dt


@settings(max_examples=6, deadline=None)
@given(seed=seeds, controller_class=st.sampled_from(CONTROLLERS))
def test_unsaturated_consensus_keeps_the_centroid_of_the_points(seed, controller_class):
    # With no saturation and a small control period the controlled points follow u closely, and u sums
    # to zero (complete graph now; local consensus uses last tick's neighbour points, off by O(dt)),
    # so the centroid of the points drifts by O(dt) only.
    rng = np.random.default_rng(seed)
    count = 6
    params = RobotParams(v_max_mps=1e6)
    adjacency = graphs.erdos_renyi(count, 0.5, seed % 1000, connected=True)
    sim = KinematicSim(
        params, controller_class(params), CENTROID_DT_S, random_poses(rng, 1, count), adjacency=adjacency
    )
    trajectory = sim.rollout(round(3.0 / CENTROID_DT_S))
    centroids = controlled_point(trajectory, params.offset_m).mean(axis=-2)
    drift = np.linalg.norm(centroids - centroids[0], axis=-1).max()
    assert drift < CENTROID_TOLERANCE_M
    # while the swarm itself gathered (a path graph, the slowest, shrinks to about 0.4 in 3 s)
    start, end = controlled_point(trajectory[[0, -1], 0], params.offset_m)
    assert np.ptp(end, axis=0).max() < 0.8 * np.ptp(start, axis=0).max()


# ---------------------------------------------------------------- (f) disk graphs


@settings(max_examples=40, deadline=None)
@given(seed=seeds, batch=st.integers(1, 3), count=st.integers(1, 12), radius=st.floats(0.0, 4.0))
def test_links_disk_equals_graphs_disk(seed, batch, count, radius):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-2, 2, size=(batch, count, 2))
    positions[..., -1, :] = positions[..., 0, :] + [radius, 0.0]  # a pair at exactly the radius
    np.testing.assert_array_equal(Links.disk(positions, radius).dense, graphs.disk(positions, radius))


def test_disk_graph_is_recomputed_as_robots_move():
    # Robots 0 and 1 are 2 m apart (linked, radius 2.05); robot 2 at (0, 1.95) is sqrt(1 + 1.95^2) = 2.19 m
    # from both, so it starts alone and holds still. Robots 0 and 1 meet near (0, 0), 1.95 m from robot 2:
    # the link appears and robot 2 starts moving.
    params = RobotParams()
    poses = np.array([[[-1.0, 0.0, 0.0], [1.0, 0.0, math.pi], [0.0, 1.95, -math.pi / 2]]])
    sim = KinematicSim(params, LocalConsensus(params), 0.05, poses, disk_radius_m=2.05)
    np.testing.assert_array_equal(sim.adjacency()[0], [[0, 1, 0], [1, 0, 0], [0, 0, 0]])
    linked_at = None
    robot_2_moved = []
    for tick in range(200):
        np.testing.assert_array_equal(sim.adjacency(), graphs.disk(sim.poses[..., :2], 2.05))
        if linked_at is None and sim.adjacency()[0, :, 2].any():
            linked_at = tick
        before = sim.poses[0, 2].copy()
        sim.step()
        robot_2_moved.append(bool(np.abs(sim.poses[0, 2, :2] - before[:2]).max() > 1e-12))
    assert linked_at is not None and linked_at > 10
    # robot 2 holds still until it has heard a neighbour, which is the tick after the link appeared
    assert robot_2_moved.index(True) == linked_at + 1
    assert graphs.is_connected(sim.adjacency()[0])


def test_kinematic_sim_needs_exactly_one_graph():
    params = RobotParams()
    poses = np.zeros((1, 2, 3))
    with pytest.raises(ValueError, match="exactly one"):
        KinematicSim(params, LocalConsensus(params), 0.05, poses)
    with pytest.raises(ValueError, match="exactly one"):
        KinematicSim(
            params, LocalConsensus(params), 0.05, poses, adjacency=graphs.complete(2), disk_radius_m=1
        )
    with pytest.raises(ValueError, match=r"\(B, N, 3\)"):
        KinematicSim(params, LocalConsensus(params), 0.05, np.zeros((2, 3)), adjacency=graphs.complete(2))


# ---------------------------------------------------------------- (g) keep() and (h) batch == separate


def make_sim(controller_class, poses, graph):
    params = RobotParams()
    return KinematicSim(params, controller_class(params), 0.05, poses, **graph)


GRAPHS = {"cycle": {"adjacency": graphs.cycle(6)}, "disk": {"disk_radius_m": 1.5}}


@pytest.mark.parametrize("graph", GRAPHS.values(), ids=GRAPHS.keys())
@pytest.mark.parametrize("controller_class", CONTROLLERS)
@pytest.mark.parametrize("selection", [np.array([True, False, True, False]), np.array([3, 1])])
def test_keep_continues_exactly_as_if_never_batched(graph, controller_class, selection):
    poses = random_poses(np.random.default_rng(7), 4, 6)
    kept = np.arange(4)[selection]
    batched = make_sim(controller_class, poses, graph)
    batched.rollout(5)
    batched.keep(selection)
    assert batched.batch_size == len(kept)
    tail = batched.rollout(20)
    alone = make_sim(controller_class, poses[kept], graph)
    np.testing.assert_array_equal(alone.rollout(25)[5:], tail)
    np.testing.assert_array_equal(alone.inbox, batched.inbox)


def test_keep_with_per_environment_adjacency():
    rng = np.random.default_rng(11)
    adjacency = np.stack([random_symmetric(rng, 5) for _ in range(3)])
    poses = random_poses(rng, 3, 5)
    batched = make_sim(LocalConsensus, poses, {"adjacency": adjacency})
    batched.rollout(4)
    batched.keep(np.array([2, 0]))
    np.testing.assert_array_equal(batched.adjacency(), adjacency[[2, 0]])
    tail = batched.rollout(10)
    alone = make_sim(LocalConsensus, poses[[2, 0]], {"adjacency": adjacency[[2, 0]]})
    np.testing.assert_array_equal(alone.rollout(14)[4:], tail)


@pytest.mark.parametrize("graph", GRAPHS.values(), ids=GRAPHS.keys())
@pytest.mark.parametrize("controller_class", CONTROLLERS)
def test_batch_equals_separate_runs(graph, controller_class):
    poses = random_poses(np.random.default_rng(5), 5, 6)
    batched = make_sim(controller_class, poses, graph).rollout(40)
    for b in range(5):
        alone = make_sim(controller_class, poses[b : b + 1], graph).rollout(40)
        np.testing.assert_array_equal(alone[:, 0], batched[:, b])
