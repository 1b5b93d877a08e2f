"""The coverage task (swarm.core.tasks.coverage) and its controllers (lloyd, lloyd_local, lloyd_flood,
lloyd_predict): the cost and the reference by hand on small cases, the cell rule on ties in both
forms, decentralization measured from outside, and a run of the scenarios through ``swarm run``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from swarm.core import graphs, tasks
from swarm.core.robot import RobotParams
from swarm.core.tasks import coverage
from swarm.scenarios.scenario import ControllerSpec
from swarm.sim.controller_kinds import (
    CONTROLLER_KINDS,
    ControllerArgs,
    batched_controller,
    onboard_controller,
)
from swarm.sim.coverage_controllers import _nearest_first, cell_sums, centroid_targets
from swarm.sim.coverage_onboard import HORIZON_TICKS, cell_centroid, predicted_positions
from swarm.sim.kinematic import KinematicSim

ROOT = Path(__file__).resolve().parents[1]
ROBOT = RobotParams()
DT = 0.05
SQUARE = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]


def section(**more) -> coverage.CoverageSection:
    return tasks.parse_section({"kind": "coverage", "region": SQUARE, **more})


def test_the_quadrature_is_the_midpoint_rule_of_the_region():
    square = section(grid_per_axis=10)
    points, weights = square.quadrature()
    assert len(points) == 100 and np.isclose(weights.sum(), 1.0) and np.allclose(weights, 0.01)
    assert np.isclose(points[:, 0].min(), -0.9) and np.isclose(points[:, 0].max(), 0.9)
    # an L: the unit square [0, 2]^2 less its top right quarter holds 3/4 of the cells
    ell = tasks.parse_section(
        {"kind": "coverage", "region": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], "grid_per_axis": 20}
    )
    points, _ = ell.quadrature()
    assert len(points) == 300
    assert not np.any((points[:, 0] > 1) & (points[:, 1] > 1))


def test_the_cost_of_one_robot_at_the_centre_of_a_square_is_two_thirds():
    """H = (1/4) double integral over [-1, 1]^2 of x^2 + y^2 = 2/3; the midpoint rule is h^2/6 short."""
    square = section(grid_per_axis=48)
    points, weights = square.quadrature()
    h = 2.0 / 48
    assert math.isclose(float(coverage.locational_cost(np.zeros((1, 2)), points, weights)), 2 / 3 - h * h / 6)


def _plain_locational_cost(positions: np.ndarray, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """H as the expression reads, with its temporaries, in the same chunks of frames (so the same
    matrix-vector products): what every committed coverage cell was computed with."""
    flat = positions.reshape(-1, *positions.shape[-2:])
    cost = np.empty(len(flat))
    for start in range(0, len(flat), coverage.FRAMES_PER_CHUNK):
        chunk = flat[start : start + coverage.FRAMES_PER_CHUNK]
        nearest = np.full((len(chunk), len(points)), np.inf)
        for robot in range(chunk.shape[1]):
            dx, dy = points[None, :, 0] - chunk[:, robot, 0:1], points[None, :, 1] - chunk[:, robot, 1:2]
            nearest = np.minimum(nearest, dx * dx + dy * dy)
        cost[start : start + len(chunk)] = nearest @ weights
    return cost.reshape(positions.shape[:-2])


@pytest.mark.parametrize("frames", [1, 31, 32, 33, 70])
@pytest.mark.parametrize("count", [1, 2, 7, 100])
def test_the_locational_cost_is_the_plain_expression_bit_for_bit(frames, count):
    """Far from the origin, robots on one another and on quadrature points (ties), chunks of frames
    cut anywhere; and within rounding of a per-frame sum of the definition."""
    rng = np.random.default_rng(frames * 1000 + count)
    far = section(
        region=[[1e4, -1e4], [1e4 + 3, -1e4], [1e4 + 3, -1e4 + 2], [1e4, -1e4 + 2]], grid_per_axis=40
    )
    for shaped in (section(grid_per_axis=48), far):
        points, weights = shaped.quadrature()
        low, high = points.min(axis=0), points.max(axis=0)
        positions = rng.uniform(low - 0.5, high + 0.5, (frames, count, 2))
        positions[:, : count // 2] = positions[:, count - count // 2 :][:, : count // 2]  # pairs on one spot
        positions[::2, 0] = points[rng.integers(len(points), size=len(positions[::2]))]  # on a point
        fast = coverage.locational_cost(positions, points, weights)
        assert fast.shape == (frames,)
        assert np.array_equal(fast, _plain_locational_cost(positions, points, weights))
        squared = ((points[None, :, None, :] - positions[:, None, :, :]) ** 2).sum(-1).min(-1)
        assert np.allclose(fast, squared @ weights, rtol=1e-12, atol=0.0)
    # leading axes kept: (2, 3, N, 2) -> (2, 3)
    points, weights = section(grid_per_axis=20).quadrature()
    batch = rng.uniform(-1, 1, (2, 3, count, 2))
    assert np.array_equal(
        coverage.locational_cost(batch, points, weights),
        _plain_locational_cost(batch, points, weights),
    )


@pytest.mark.parametrize("case", range(6))
def test_the_locational_cost_keeps_the_nearest_of_robots_all_but_equidistant(case):
    """Robots on a circle around a quadrature point, their radii apart by a few ulps: which is nearest
    to the point (and to its block's other points) is decided by the last bits, so a robot that the
    cost's block pruning dropped wrongly would change them."""
    rng = np.random.default_rng(case)
    points, weights = section(grid_per_axis=48).quadrature()
    centre = points[rng.integers(len(points))]
    count = [3, 12, 40][case % 3]
    angle = rng.uniform(0, 2 * np.pi, (5, count))
    radius = [0.05, 0.7][case // 3] * (1.0 + rng.integers(0, 8, (5, count)) * np.finfo(float).eps)
    positions = centre + radius[..., None] * np.stack([np.cos(angle), np.sin(angle)], -1)
    assert np.array_equal(
        coverage.locational_cost(positions, points, weights),
        _plain_locational_cost(positions, points, weights),
    )


def test_the_locational_cost_carries_a_position_that_is_not_finite_as_the_expression_does():
    points, weights = section(grid_per_axis=24).quadrature()
    positions = np.random.default_rng(0).uniform(-1, 1, (4, 6, 2))
    positions[1, 3, 0], positions[2, 4, 1], positions[3, :, 0] = np.nan, np.inf, np.inf
    cost = coverage.locational_cost(positions, points, weights)
    assert np.array_equal(cost, _plain_locational_cost(positions, points, weights), equal_nan=True)
    assert np.isnan(cost[1]) and np.isfinite(cost[2]) and cost[3] == np.inf


def test_the_reference_of_two_robots_in_a_square_is_the_halves():
    """Two robots on [-1, 1]^2: the cells are halves and their centroids (+-0.5, 0) (or the transpose);
    H = 1/12 + 1/3 = 5/12 (the grid's midpoint rule short by h^2/6)."""
    square = section(grid_per_axis=48)
    h_ref, positions = coverage.reference(square, 2)
    h = 2.0 / 48
    assert math.isclose(h_ref, 5 / 12 - h * h / 6, rel_tol=1e-9)
    assert np.allclose(np.sort(np.abs(positions).max(axis=1)), [0.5, 0.5])


def test_a_gaussian_density_pulls_the_reference_to_its_mean():
    skewed = section(gaussians=[{"mean": [0.5, 0.5], "sigma_m": 0.2}])
    _, positions = coverage.reference(skewed, 3)
    assert np.linalg.norm(positions.mean(axis=0) - [0.5, 0.5]) < 0.15


@pytest.mark.parametrize("count", [6, 12, 23, 24, 50, 100, 200])
def test_a_sweep_cell_gives_every_robot_its_share_of_quadrature_points(count):
    """Lloyd on a grid of a few points a cell stops short (bench/results/lloyd_quadrature.md): the
    sweep's square has at least QUADRATURE_POINTS_PER_ROBOT points a robot, and the default grid (the
    results of N <= 23 unchanged) wherever that gives enough."""
    points, _ = coverage.sweep_section(count).quadrature()
    assert len(points) >= coverage.QUADRATURE_POINTS_PER_ROBOT * count
    grid = coverage.sweep_section(count).grid_per_axis
    assert grid == 48 if 100 * count <= 48 * 48 else (grid - 1) ** 2 < 100 * count  # no finer than needed


def test_a_tie_point_belongs_to_every_cell_it_is_nearest_to_in_both_forms():
    """Grid of 8 cells per side on [0, 4]^2 (points at 0.25 .. 3.75); robots at (1, 0.25) and
    (1.5, 0.25): the points of column x = 1.25 are as near one as the other and count in both cells."""
    tie = tasks.parse_section(
        {"kind": "coverage", "region": [[0, 0], [4, 0], [4, 4], [0, 4]], "grid_per_axis": 8}
    )
    points, weights = tie.quadrature()
    own, other = np.array([1.0, 0.25]), np.array([1.5, 0.25])
    fallback = np.zeros(2)
    mine = cell_centroid(own, other[None], points, weights, fallback)
    column = points[:, 0] <= 1.25  # x = 0.25, 0.75 and 1.25: the tie column included
    assert np.allclose(mine, points[column].mean(axis=0))
    sums = np.empty((1, 2, 3))
    both = np.array([[own, other]])
    cell_sums(
        both, both[:, ::-1][:, :, None, :].copy(), np.ones((1, 2, 1), bool), points, weights, math.inf, sums
    )
    batched = centroid_targets(sums, fallback)[0]
    assert np.allclose(batched[0], mine)
    assert np.allclose(batched[1], cell_centroid(other, own[None], points, weights, fallback))
    assert np.isclose(sums[0, 0, 0] + sums[0, 1, 0], 1.0 + 8 / 64)  # the tie column counted twice


def _brute_force_sums(own, others, valid, points, weights, radius_sq):
    """The definition, point by point: a point is robot i's when within the radius and no valid other is
    strictly nearer; its weight and moments added in the points' order."""
    out = np.zeros((*own.shape[:2], 3))
    for b, i in np.ndindex(*own.shape[:2]):
        dx, dy = points[:, 0] - own[b, i, 0], points[:, 1] - own[b, i, 1]
        mine = dx * dx + dy * dy
        inside = mine <= radius_sq
        for k in np.flatnonzero(valid[b, i]):
            ex, ey = points[:, 0] - others[b, i, k, 0], points[:, 1] - others[b, i, k, 1]
            inside &= ~(ex * ex + ey * ey < mine)
        for g in np.flatnonzero(inside):
            out[b, i, 0] += weights[g]
            out[b, i, 1] += weights[g] * points[g, 0]
            out[b, i, 2] += weights[g] * points[g, 1]
    return out


@pytest.mark.parametrize("case", range(48))
def test_the_cell_kernel_sums_exactly_the_points_of_the_definition(case):
    """``cell_sums`` tests only the points its windows pick and the others that could be nearer; its sums
    must be the definition's bit for bit, on starts snapped to the grid (ties on cell boundaries, robots
    on one spot), far from the origin, swarms of one and two, others unheard, a radius cut, and points
    in another order than grid rows (shuffled, scattered, rows with a gap)."""
    rng = np.random.default_rng(case)
    count = [1, 2, 3, 7, 12, 40][case % 6]
    offset = [0.0, 0.0, 1e4, 1e6][case // 10 % 4]
    layout = case % 4
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, 21), np.linspace(-2, 2, 17)), -1).reshape(-1, 2)
    points = {
        0: grid,
        1: grid[np.abs(grid[:, 0] - 0.3) > 0.5],  # every row with a gap
        2: grid[rng.permutation(len(grid))],
        3: rng.uniform(-2, 2, (300, 2)),
    }[layout] + offset
    weights = rng.random(len(points))
    weights /= weights.sum()
    own = rng.uniform(-2.5, 2.5, (3, count, 2))
    if case % 2 == 0:  # on the grid's lines: points equidistant from two robots
        own = np.round(own / 0.4) * 0.4
    if case % 3 == 0 and count > 1:
        own[:, 1] = own[:, 0]  # two robots on one spot
    own += offset
    others = np.broadcast_to(own[:, None], (3, count, count, 2)).copy()
    valid = (rng.random((3, count, count)) < 0.8) & ~np.eye(count, dtype=bool)
    for radius_sq in (math.inf, 0.8):
        sums = np.empty((3, count, 3))
        cell_sums(own, others, valid, points, weights, radius_sq, sums)
        expected = _brute_force_sums(own, others, valid, points, weights, radius_sq)
        np.testing.assert_array_equal(sums, expected)
        if radius_sq == math.inf:  # a point is at least its nearest robot's, whoever that one heard
            assert np.all(expected[..., 0].sum(axis=1) >= 1.0 - 1e-9)


@pytest.mark.parametrize("case", range(12))
def test_the_cells_grouping_passes_every_other_within_a_reach_before_it_stops(case):
    """``_nearest_first`` orders the others so that a scan stopping at the first ``floor_sq`` beyond its
    reach has passed every other within it: checked against the values it was given, for every reach
    between and at them, with zeros (robots on one spot), ties, and a range wider than its groups."""
    rng = np.random.default_rng(case)
    gap_sq = rng.uniform(0.0, 5.0, 1 + case * 9) ** [1, 2, 4][case % 3]
    if case % 2 == 0:
        gap_sq[rng.random(len(gap_sq)) < 0.3] = 0.0
        gap_sq[rng.random(len(gap_sq)) < 0.3] = gap_sq[0]
    order, floor_sq = _nearest_first(gap_sq)
    assert sorted(order.tolist()) == list(range(len(gap_sq)))
    assert np.all(floor_sq <= gap_sq[order]) and np.all(np.diff(floor_sq) >= 0.0)
    for reach_sq in np.concatenate([gap_sq, gap_sq * (1 + 1e-12), gap_sq * (1 - 1e-12), [0.0, np.inf]]):
        stop = int(np.argmax(floor_sq > reach_sq)) if np.any(floor_sq > reach_sq) else len(order)
        assert set(np.flatnonzero(gap_sq <= reach_sq)) <= set(order[:stop].tolist())


def test_an_empty_cell_heads_for_the_density_centroid():
    square = section(grid_per_axis=8, gaussians=[{"mean": [0.5, 0.0], "sigma_m": 0.4}])
    points, weights = square.quadrature()
    centre = coverage.density_centroid(points, weights)
    far_robot = cell_centroid(np.array([30.0, 30.0]), np.zeros((1, 2)), points, weights, centre)
    assert np.array_equal(far_robot, centre)
    cut = cell_centroid(np.array([3.0, 0.0]), np.zeros((0, 2)), points, weights, centre, radius_m=1.0)
    assert np.array_equal(cut, centre)


def _args(kind_section, count, robot_id=0, **more):
    return ControllerArgs(
        robot=ROBOT, control_period_s=DT, robot_count=count, task=kind_section, robot_id=robot_id, **more
    )


DECENTRALIZED_KINDS = [  # every coverage kind a robot runs on board (lloyd_gnn: its shipped policy)
    name for name, kind in CONTROLLER_KINDS.items() if kind.task == "coverage" and not kind.central
]


def test_every_decentralized_coverage_kind_is_checked():
    assert {"lloyd_local", "lloyd_flood", "lloyd_predict", "lloyd_gnn"} <= set(DECENTRALIZED_KINDS)


@pytest.mark.parametrize("kind", DECENTRALIZED_KINDS)
def test_a_robot_hears_of_a_robot_k_hops_away_no_sooner_than_k_ticks(kind):
    """Decentralization from outside: on a line of 8, moving robot 7's start changes nothing of robot
    0's commands for the first 7 ticks (7 hops), and does change the swarm's later. Robot 7 sits next
    to robot 0, so that a controller reading its position (``lloyd``) changes robot 0's command at once."""
    count, square = 8, section(grid_per_axis=24)
    rng = np.random.default_rng(3)
    start = np.concatenate([rng.uniform(-1, 1, (1, count, 2)), rng.uniform(-np.pi, np.pi, (1, count, 1))], -1)
    start[0, 7, :2] = start[0, 0, :2] + [0.3, 0.0]
    moved = start.copy()
    moved[0, 7, :2] += [0.1, 0.2]
    commands = []
    for poses in (start, moved):
        sim = KinematicSim(
            ROBOT,
            batched_controller(kind, _args(square, count)),
            DT,
            poses,
            adjacency=graphs.line(count)[None],
        )
        ticks = []
        for _ in range(12):
            u_world = sim.act()
            ticks.append(u_world[0].copy())
            sim.move(u_world)
        commands.append(np.array(ticks))
    assert np.array_equal(commands[0][:7, 0], commands[1][:7, 0])
    assert not np.array_equal(commands[0][:, 6], commands[1][:, 6])


def test_the_flood_knows_everyone_after_the_diameter_and_ages_count_hops():
    count, square = 6, section(grid_per_axis=12)
    rng = np.random.default_rng(0)
    start = np.concatenate([rng.uniform(-1, 1, (count, 2)), np.zeros((count, 1))], -1)
    agents = [onboard_controller("lloyd_flood", _args(square, count, robot_id=i)) for i in range(count)]
    adjacency = graphs.line(count)
    sent = [np.zeros(3 * count) for _ in range(count)]
    for _ in range(count):  # tick k: robot 0 knows the robots k hops away
        outbox = []
        for i, agent in enumerate(agents):
            heard = np.array([sent[j] for j in range(count) if adjacency[i, j]])
            outbox.append(agent.act_one(start[i], heard)[1])
        sent = outbox
    table = sent[0].reshape(count, 3)
    assert np.array_equal(table[:, 0], 1.0 + np.arange(count))  # robot j is j hops from robot 0
    assert np.array_equal(table[:, 1:], start[:, :2])


def test_lloyd_predict_places_a_robot_where_its_target_takes_it_in_its_entrys_age():
    """By hand, a step of 0.1 m a tick: an entry 3 ticks old (age + 1 = 4) whose target is 1 m along x
    is 0.3 m along; one whose target is 0.2 m away has reached it; one of this tick, one with its
    target where it is and an unknown one stay where they were sent."""
    table = np.array(
        [
            [4.0, 1.0, 2.0, 2.0, 2.0],  # 3 ticks old, target 1 m along +x
            [4.0, 0.0, 0.0, 0.0, -0.2],  # 3 ticks old, target 0.2 m along -y: reached
            [1.0, 5.0, 5.0, 9.0, 9.0],  # this tick's
            [9.0, -1.0, 1.0, -1.0, 1.0],  # 8 ticks old, already at its target
            [0.0, 3.0, 4.0, 0.0, 0.0],  # unknown
            [2.0, 0.0, 0.0, 3.0, 4.0],  # 1 tick old, target 5 m along (3, 4) / 5
        ]
    )
    expected = [[1.3, 2.0], [0.0, -0.2], [5.0, 5.0], [-1.0, 1.0], [3.0, 4.0], [0.06, 0.08]]
    np.testing.assert_allclose(predicted_positions(table, 0.1), expected, rtol=0, atol=1e-15)
    batched = predicted_positions(np.stack([table, table[::-1]]), 0.1)  # any leading shape
    np.testing.assert_allclose(batched, [expected, expected[::-1]], rtol=0, atol=1e-15)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["complete-lloyd", "cycle-lloyd_flood", "complete-lloyd_local"])
def test_the_coverage_scenarios_run_and_report_the_cost(tmp_path, name):
    """``swarm run`` of a committed scenario: exit 0, success, and the final cost recomputed here from the
    trajectory on a finer grid of this test's own (the oracle) within the quadrature's error."""
    from swarm.cli import main

    out = tmp_path / name
    assert main(["run", str(ROOT / "scenarios" / "coverage" / f"{name}.yaml"), "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["task"] == "coverage" and metrics["converged"]
    assert metrics["final_metric"] <= 1.05 and metrics["first_within_s"] <= metrics["convergence_time_s"]
    assert {"coverage.png", "convergence.png", "coverage.png.json"} <= {p.name for p in out.iterdir()}
    lines = (out / "trajectory.jsonl").read_text().splitlines()
    final = np.array([pose[:2] for pose in json.loads(lines[-1])["poses"]])
    scenario = tasks.parse_section(
        __import__("yaml").safe_load((ROOT / "scenarios" / "coverage" / f"{name}.yaml").read_text())["task"]
    )
    vertices = np.array(scenario.region)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    fine = 400
    xs = low[0] + (np.arange(fine) + 0.5) * (high[0] - low[0]) / fine
    ys = low[1] + (np.arange(fine) + 0.5) * (high[1] - low[1]) / fine
    grid = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)  # the region is a square: every point inside
    nearest = ((grid[:, None, :] - final[None]) ** 2).sum(-1).min(axis=1)
    assert math.isclose(float(nearest.mean()), metrics["coverage_cost_m2"], rel_tol=0.01)


@pytest.mark.slow
def test_a_recorded_coverage_run_carries_its_cost_ratio(tmp_path):
    """``--record mcap`` of a coverage run: ``/metric`` is H / H_ref of every tick, computed here from
    the trajectory (the nearest robot of every quadrature point, summed with its weight)."""
    import yaml
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from swarm.cli import main
    from swarm.scenarios.results import read_trajectory

    data = yaml.safe_load((ROOT / "scenarios" / "coverage" / "complete-lloyd_flood.yaml").read_text())
    data["sim"]["duration_s"] = 3.0
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    assert main(["run", str(path), "--out", str(out), "--quiet", "--record", "mcap"]) in (0, 1)
    metrics = json.loads((out / "metrics.json").read_text())
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    points, weights = tasks.parse_section(data["task"]).quadrature()
    expected = []
    for frame in poses[..., :2]:
        nearest = np.array([min(float(((q - p) ** 2).sum()) for p in frame) for q in points])
        expected.append(float(nearest @ weights) / metrics["reference_cost_m2"])
    with open(out / "recording.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        recorded = [
            m.data for _, channel, _, m in reader.iter_decoded_messages() if channel.topic == "/metric"
        ]
    assert len(recorded) == len(poses) == 61
    assert recorded == pytest.approx(expected, rel=1e-12)


# ----------------------------------------------------------------------------- the PettingZoo environment


@pytest.mark.parametrize(
    "overrides", [{"robots": 4, "topology": "line"}, {"robots": 5, "density": "gaussian"}]
)
def test_the_coverage_env_passes_pettingzoos_checks(overrides):
    from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test

    from swarm.rl import coverage_v0

    parallel_api_test(coverage_v0.parallel_env(**overrides), num_cycles=100)
    parallel_seed_test(lambda: coverage_v0.parallel_env(**overrides))
    api_test(coverage_v0.env(**overrides), num_cycles=20)


def test_the_coverage_env_rewards_the_cost_decrease_and_hears_only_neighbours():
    """The Lloyd expert's episode: the return is (H_0 - H_end) / H_ref plus the bonus, H computed here from
    the global state; each robot's neighbour slots hold its line neighbours' axles of one tick before."""
    from swarm.rl import coverage_v0

    env = coverage_v0.parallel_env(robots=5, topology="line", action_repeat=1)
    observations, _ = env.reset(seed=3)
    points, weights = env.section.quadrature()

    def cost() -> float:
        axles = env.state().reshape(5, 4)[:, :2].astype(np.float64)
        return float((((points[:, None, :] - axles[None]) ** 2).sum(-1).min(axis=1)) @ weights)

    first, total, previous = cost(), 0.0, env.state().reshape(5, 4)[:, :2]
    assert all(not obs[6:].any() for obs in observations.values())  # nothing heard at tick 0
    while env.agents:
        observations, rewards, terminations, _, infos = env.step(env.expert_actions())
        total += rewards["robot_0"]
        now = env.state().reshape(5, 4)[:, :2]
        for i in range(5):
            slots = observations[f"robot_{i}"][6:].reshape(4, 3)
            neighbours = [j for j in (i - 1, i + 1) if 0 <= j < 5]
            assert np.allclose(
                slots[: len(neighbours), :2], (previous[neighbours] - now[i]) / env.config.side, atol=1e-6
            )
            assert slots[: len(neighbours), 2].tolist() == [1.0] * len(neighbours)
            assert not slots[len(neighbours) :].any()
        previous = now
    assert terminations["robot_0"] and infos["robot_0"]["ratio"] <= 1.05
    assert total == pytest.approx((first - cost()) / env.h_ref + 1.0, rel=1e-5)


@pytest.mark.runtime
def test_the_pybullet_runtime_covers_with_one_agent_per_robot_and_is_judged_by_the_cost(tmp_path):
    """``scenarios/tasks/coverage-cycle-lossy.yaml`` (12 agent processes, 20% loss, a dropped link) and
    ``coverage-line-lossy.yaml`` (the dropped link cuts robot 0 off the line): the exit status is 0 exactly
    when H / H_ref, computed here from the sim server's last poses, is within 1.05; each agent heard
    only its graph neighbours."""
    from swarm.cli import main

    for name, neighbours in (
        ("coverage-cycle-lossy", lambda i: sorted({(i - 1) % 12, (i + 1) % 12})),
        ("coverage-line-lossy", lambda i: [j for j in (i - 1, i + 1) if 0 <= j < 12]),
    ):
        path = ROOT / "scenarios" / "tasks" / f"{name}.yaml"
        out = tmp_path / name
        code = main(["run", str(path), "--out", str(out), "--quiet"])
        metrics = json.loads((out / "metrics.json").read_text())
        final = np.array(
            [
                pose[:2]
                for pose in json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]
            ]
        )
        points, weights = tasks.parse_section(
            __import__("yaml").safe_load(path.read_text())["task"]
        ).quadrature()
        nearest = ((points[:, None, :] - final[None]) ** 2).sum(-1).min(axis=1)
        ratio = float(nearest @ weights) / metrics["reference_cost_m2"]
        assert code == (0 if ratio <= 1.05 else 1), (name, ratio, metrics.get("health"))
        assert metrics["faults"]["messages"]["lost_by_fault"] > 0
        for i in range(12):
            record = json.loads((out / "logs" / f"agent_{i}.json").read_text())
            assert record["controller"] == "lloyd_flood" and record["neighbours"] == neighbours(i), (name, i)


def test_lloyd_predict_extrapolates_over_at_most_its_horizon():
    """By hand, 0.1 m a tick toward a target 5 m along +x: an entry 8 ticks old goes 0.5 m with the
    default horizon of 5 ticks, 0.2 m with a horizon of 2, 0.8 m uncapped, and stays put with 0 (the
    cell of ``lloyd_flood``); one 3 ticks old goes 0.3 m under any horizon of 3 or more."""
    table = np.array([[9.0, 0.0, 0.0, 5.0, 0.0], [4.0, 0.0, 1.0, 5.0, 1.0]])
    assert HORIZON_TICKS == 5
    for horizon, (far_m, near_m) in {
        5: (0.5, 0.3),
        2: (0.2, 0.2),
        math.inf: (0.8, 0.3),
        0: (0.0, 0.0),
    }.items():
        expected = [[far_m, 0.0], [near_m, 1.0]]
        np.testing.assert_allclose(predicted_positions(table, 0.1, horizon), expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(predicted_positions(table, 0.1), [[0.5, 0.0], [0.3, 1.0]], rtol=0, atol=1e-15)


@pytest.mark.parametrize("horizon_ticks", [0.0, 1.0, HORIZON_TICKS, math.inf])
def test_the_batched_prediction_is_the_on_board_one_bit_for_bit(horizon_ticks):
    """The compiled prediction of ``lloyd_predict`` (batched) against the numpy one its robots run
    (``predicted_positions``): unknown entries, fresh ones, old ones past the horizon, targets at the
    position itself, a millimetre away and far, far from the origin."""
    from swarm.sim.coverage_controllers import _predicted_positions

    rng = np.random.default_rng(11)
    table = np.zeros((4, 6, 6, 5))
    table[..., 0] = rng.choice([0.0, 1.0, 2.0, 3.0, 7.0, 40.0], table.shape[:3])
    table[..., 1:3] = rng.uniform(-3, 3, (*table.shape[:3], 2))
    table[1, ..., 1:3] += [1e6, -1e6]
    gap = rng.choice([0.0, 1e-3, 0.01, 5.0], (*table.shape[:3], 1)) * rng.normal(size=(*table.shape[:3], 2))
    table[..., 3:5] = table[..., 1:3] + gap
    batched = np.empty((*table.shape[:3], 2))
    _predicted_positions(table, 0.025, horizon_ticks, batched)
    np.testing.assert_array_equal(batched, predicted_positions(table, 0.025, horizon_ticks))


@pytest.mark.parametrize("horizon", [0, 2, None])
def test_lloyd_gnn_places_the_robots_it_knows_over_the_horizon_its_policy_file_names(horizon, tmp_path):
    """The readout is trained on one cell and must run on it: the horizon is in the policy file
    (``meta["horizon_ticks"]``; a file without it was trained with ``HORIZON_TICKS``). Both forms of
    ``lloyd_gnn`` place the entries of a table (ages up to 40 ticks) exactly as ``lloyd_predict`` with
    that horizon does, and not as with another."""
    from swarm.sim.coverage_gnn import DEFAULT_MODEL_NAME, CoverageGnnWeights
    from swarm.sim.steering_mlp import PolicyFileError

    shipped = CoverageGnnWeights.load(Path("models") / DEFAULT_MODEL_NAME)
    meta = {key: value for key, value in shipped.meta.items() if key != "horizon_ticks"}
    if horizon is not None:
        meta["horizon_ticks"] = horizon
    path = tmp_path / "policy.npz"
    CoverageGnnWeights(shipped.weights, shipped.biases, meta).save(path)
    expected = HORIZON_TICKS if horizon is None else horizon
    count, square = 6, section(grid_per_axis=24)
    rng = np.random.default_rng(11)
    table = np.zeros((2, count, count, 5))
    table[..., 0] = rng.choice([0.0, 1.0, 2.0, 4.0, 9.0, 40.0], table.shape[:3])
    table[..., 1:3] = rng.uniform(-1, 1, (*table.shape[:3], 2))
    table[..., 3:5] = table[..., 1:3] + rng.normal(scale=0.5, size=(*table.shape[:3], 2))
    gnn = batched_controller("lloyd_gnn", _args(square, count, policy=str(path)))
    for other in sorted({0, 2, HORIZON_TICKS}):
        predict = batched_controller("lloyd_predict", _args(square, count, horizon_ticks=other))
        same = np.array_equal(gnn.known_positions(table), predict.known_positions(table))
        assert same == (other == expected), other
    onboard = onboard_controller("lloyd_gnn", _args(square, count, robot_id=1, policy=str(path)))
    np.testing.assert_array_equal(onboard.known_positions(table[0, 1]), gnn.known_positions(table)[0, 1])
    meta["horizon_ticks"] = -1
    CoverageGnnWeights(shipped.weights, shipped.biases, meta).save(path)
    with pytest.raises(PolicyFileError, match="horizon_ticks: -1"):
        CoverageGnnWeights.load(path)


def test_lloyd_predict_with_a_horizon_of_zero_drives_as_lloyd_flood():
    """``horizon_ticks: 0`` places every known robot where it was sent from: on a line of 8 (entries up
    to 7 ticks old) the swarm moves bit for bit as ``lloyd_flood``'s, while the default horizon does
    not. The option comes from the scenario's controller section and is refused for another kind."""
    count, square = 8, section(grid_per_axis=24)
    rng = np.random.default_rng(5)
    start = np.concatenate([rng.uniform(-1, 1, (2, count, 2)), rng.uniform(-np.pi, np.pi, (2, count, 1))], -1)
    spec = {"kind": "lloyd_predict", "horizon_ticks": 0}
    runs = {}
    for name, horizon in (("lloyd_flood", None), ("zero", 0), ("default", None)):
        kind = "lloyd_flood" if name == "lloyd_flood" else "lloyd_predict"
        args = _args(square, count, horizon_ticks=horizon)
        line = graphs.line(count)[None]
        sim = KinematicSim(ROBOT, batched_controller(kind, args), DT, start, adjacency=line)
        for _ in range(40):
            sim.move(sim.act())
        runs[name] = sim.poses.copy()
    assert np.array_equal(runs["zero"], runs["lloyd_flood"])
    assert not np.array_equal(runs["default"], runs["lloyd_flood"])
    assert ControllerArgs.from_spec(spec, ROBOT, DT).horizon_ticks == 0
    with pytest.raises(ValueError, match="horizon_ticks"):
        ControllerSpec.model_validate({"kind": "lloyd_flood", "horizon_ticks": 3})


def test_a_step_fraction_goes_that_fraction_of_the_way_once_within_reach():
    """By hand, ``v_max T`` = 0.025 m: a robot heading along +x, its target 1 cm ahead, goes the whole
    way in one tick by default (0.2 m/s) and half of it with ``step_fraction: 0.5`` (0.1 m/s); 4 cm ahead,
    beyond the default's reach but within the half step's 5 cm, full speed (0.5 m/s) against 0.4 m/s;
    10 cm ahead, full speed either way. The option comes from the scenario's controller section for the
    three Lloyd baselines, and is refused for another kind and outside (0, 1]."""
    from swarm.core.experts import drive_toward_velocity

    pose = np.array([0.0, 0.0, 0.0])
    for ahead_m, (whole_mps, half_mps) in {0.01: (0.2, 0.1), 0.04: (0.5, 0.4), 0.1: (0.5, 0.5)}.items():
        target = np.array([ahead_m, 0.0])
        whole = drive_toward_velocity(pose, target, ROBOT.v_max_mps, DT)
        half = drive_toward_velocity(pose, target, ROBOT.v_max_mps, DT, step_fraction=0.5)
        np.testing.assert_allclose(whole, [whole_mps, 0.0], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(half, [half_mps, 0.0], rtol=1e-12, atol=1e-15)
    for kind in ("lloyd_local", "lloyd_flood", "lloyd_predict"):
        spec = ControllerSpec.model_validate({"kind": kind, "step_fraction": 0.5}).model_dump()
        args = ControllerArgs.from_spec(spec, ROBOT, DT, robot_count=4, task=section(grid_per_axis=24))
        assert batched_controller(kind, args).step_fraction == 0.5
        assert onboard_controller(kind, args).step_fraction == 0.5
    with pytest.raises(ValueError, match="step_fraction"):
        ControllerSpec.model_validate({"kind": "lloyd_gnn", "step_fraction": 0.5})
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="step_fraction"):
            ControllerSpec.model_validate({"kind": "lloyd_flood", "step_fraction": bad})
