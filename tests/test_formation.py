"""Formation with assignment (swarm.core.tasks.formation, swarm.sim.formation_controllers).

Oracles: brute force over every permutation (assignment, bottleneck), hand-made configurations
(bound, success time), and the definition of decentralization (a robot's first k ticks do not depend
on robots more than k hops away)."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from swarm.core import graphs
from swarm.core.robot import RobotParams
from swarm.core.tasks import formation
from swarm.core.tasks.formation import FormationSection
from swarm.sim.formation_controllers import CaptExpert, CaptFlood
from swarm.sim.kinematic import KinematicSim


def _brute(positions: np.ndarray, slots: np.ndarray) -> tuple[float, float]:
    """(least bottleneck, least sum of squares among the assignments of that bottleneck)."""
    dist = np.sqrt(((positions[:, None] - slots[None]) ** 2).sum(-1))
    best = (math.inf, math.inf)
    for chosen in itertools.permutations(range(len(slots)), len(positions)):
        values = dist[np.arange(len(positions)), list(chosen)]
        best = min(best, (float(values.max()), float((values**2).sum())))
    return best


def _cost(positions, slots, assignment) -> tuple[float, float]:
    values = np.sqrt(((positions - slots[assignment]) ** 2).sum(-1))
    return float(values.max()), float((values**2).sum())


@pytest.mark.parametrize("seed", range(40))
def test_capt_assignment_is_the_brute_force_optimum(seed):
    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 7))
    slots_count = count + int(rng.integers(0, 2)) if seed % 3 else count  # also fewer robots than slots
    positions = rng.uniform(-2, 2, (count, 2))
    if seed % 4 == 0:  # ties: integer grid points
        positions = rng.integers(-2, 3, (count, 2)).astype(float)
    slots = rng.uniform(-2, 2, (slots_count, 2)) if seed % 4 else rng.integers(-2, 3, (slots_count, 2)) + 0.0
    assignment = formation.capt_assignment(positions, slots)
    assert len(set(assignment.tolist())) == count
    bottleneck, squares = _cost(positions, slots, assignment)
    best_bottleneck, best_squares = _brute(positions, slots)
    assert bottleneck == best_bottleneck
    assert squares == pytest.approx(best_squares, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("seed", range(40))
def test_a_subsets_bottleneck_as_the_search_start_gives_the_brute_force_optimum(seed):
    """``at_least_m``, the bottleneck of a subset (as ``capt_flood`` passes that of the robots it knew
    before), must not change the assignment; a hint of 0 or of the answer itself neither."""
    rng = np.random.default_rng(500 + seed)
    count = int(rng.integers(1, 7))
    positions = rng.uniform(-2, 2, (count, 2))
    slots = rng.uniform(-2, 2, (count + int(rng.integers(0, 2)), 2))
    if seed % 4 == 0:  # ties: integer grid points
        positions = rng.integers(-2, 3, (count, 2)).astype(float)
        slots = rng.integers(-2, 3, (len(slots), 2)).astype(float)
    subset = rng.permutation(count)[: int(rng.integers(0, count + 1))]
    hints = [0.0, _brute(positions[subset], slots)[0] if len(subset) else 0.0, _brute(positions, slots)[0]]
    best_bottleneck, best_squares = _brute(positions, slots)
    for hint in hints:
        bottleneck, squares = _cost(positions, slots, formation.capt_assignment(positions, slots, hint))
        assert bottleneck == best_bottleneck
        assert squares == pytest.approx(best_squares, rel=1e-12, abs=1e-12)


def test_bottleneck_prefers_the_least_largest_distance_over_the_least_sum():
    # sum of squares alone takes 0->0, 1->1 (1 + 9 = 10, largest 3); the bottleneck takes 0->1,
    # 1->0 (largest sqrt(8) = 2.83, sum 8 + 8 = 16 > 10? no: checked below by the numbers)
    positions = np.array([[0.0, 0.0], [3.0, 0.0]])
    slots = np.array([[1.0, 0.0], [0.0, 3.0]])
    # 0->0: 1, 1->1: sqrt(18)=4.24 (largest 4.24); 0->1: 3, 1->0: 2 (largest 3)
    assert formation.capt_assignment(positions, slots).tolist() == [1, 0]
    assert formation.bottleneck_distance(positions, slots) == 3.0


def test_ties_in_the_bottleneck_go_to_the_least_sum_of_squares():
    positions = np.array([[0.0, 0.0], [1.0, 0.0]])
    slots = np.array([[0.0, 2.0], [1.0, 0.5]])
    # 0->0: 2, 1->1: 0.5 (max 2, sum 4.25); 0->1: sqrt(1.25), 1->0: sqrt(5) = 2.24 (max 2.24)
    assert formation.capt_assignment(positions, slots).tolist() == [0, 1]
    positions = np.array([[0.0, 0.0], [0.0, 1.0]])
    slots = np.array([[0.0, 3.0], [0.0, -1.0]])
    # both assignments: the largest distance is 3 (0->0) or 4 (1->1 ... ) ; 0->0 3, 1->1 2: max 3, sum 13;
    # 0->1 1, 1->0 2: max 2, sum 5
    assert formation.capt_assignment(positions, slots).tolist() == [1, 0]


@pytest.mark.parametrize("seed", range(30))
def test_occupied_is_bottleneck_within_tolerance(seed):
    rng = np.random.default_rng(100 + seed)
    count = int(rng.integers(2, 6))
    slots = FormationSection(slots={"circle": {"radius_m": 1.0}}).slot_positions(count)
    tolerance = 0.45 * formation.smallest_spacing_m(slots)
    positions = slots[rng.permutation(count)] + rng.normal(0, tolerance * 0.8, (count, 2))
    expected = _brute(positions, slots)[0] <= tolerance
    assert bool(formation.occupied(positions, slots, tolerance)) == expected


def test_slot_shapes():
    circle = FormationSection(slots={"circle": {"radius_m": 2.0, "centre": (1.0, 0.0)}}).slot_positions(4)
    np.testing.assert_allclose(circle, [[3, 0], [1, 2], [-1, 0], [1, -2]], atol=1e-12)
    grid = FormationSection(slots={"grid": {"spacing_m": 1.0, "columns": 2}}).slot_positions(3)
    np.testing.assert_allclose(grid, [[-0.5, 0.5], [0.5, 0.5], [-0.5, -0.5]])
    line = FormationSection(slots={"line": {"spacing_m": 0.5, "angle_rad": math.pi / 2}}).slot_positions(3)
    np.testing.assert_allclose(line, [[0, -0.5], [0, 0], [0, 0.5]], atol=1e-12)
    with pytest.raises(ValueError, match=r"2 slots but robots\.count is 3"):
        FormationSection(slots={"points": [[0, 0], [1, 1]]}).slot_positions(3)


def test_settle_time_needs_the_hold():
    times = np.arange(6) * 0.5
    assert formation.settle_time(times, [0, 1, 0, 1, 1, 1], 1.0) == 1.5
    assert formation.settle_time(times, [0, 1, 0, 0, 1, 1], 1.0) is None  # held 0.5 s only
    assert formation.settle_time(times, [1, 1, 1, 1, 1, 0], 0.0) is None


def _run(controller_cls, poses, section, adjacency=None, seconds=30.0, **kwargs):
    robot = RobotParams()
    count = poses.shape[-2]
    controller = controller_cls(robot, 0.05, section, **kwargs)
    sim = KinematicSim(
        robot,
        controller,
        0.05,
        poses,
        adjacency=np.ones((count, count)) - np.eye(count) if adjacency is None else adjacency,
    )
    return sim.rollout(round(seconds / 0.05))


def test_the_bound_is_met_by_a_robot_already_heading_for_its_slot():
    # one robot 3 m from its slot, facing it: straight at v_max, success (within 0.1 m) at (3 - 0.1) / 0.5
    section = FormationSection(slots={"points": [[3.0, 0.0]]}, tolerance_m=0.1, hold_s=1.0)
    poses = np.array([[[0.0, 0.0, 0.0]]])
    trajectory = _run(CaptExpert, poses, section, seconds=10.0)
    times = np.arange(len(trajectory)) * 0.05
    outcome = formation.outcome(times, trajectory[:, 0, :, :2], section, 0.5)
    assert outcome["lower_bound_s"] == pytest.approx(5.8)
    assert outcome["lower_bound_s"] <= outcome["convergence_time_s"] <= outcome["lower_bound_s"] + 0.05 + 1e-9


@pytest.mark.parametrize("controller", [CaptExpert, CaptFlood])
@pytest.mark.parametrize("graph", ["complete", "line"])
def test_every_start_succeeds_no_faster_than_the_bound(controller, graph):
    rng = np.random.default_rng(7)
    count = 8
    section = FormationSection(slots={"circle": {"radius_m": 1.2}})
    poses = np.concatenate([rng.uniform(-3, 3, (6, count, 2)), rng.uniform(-np.pi, np.pi, (6, count, 1))], -1)
    adjacency = graphs.complete(count) if graph == "complete" else graphs.line(count)
    kwargs = {"robot_count": count} if controller is CaptFlood else {}
    trajectory = _run(controller, poses, section, adjacency, seconds=40.0, **kwargs)
    times = np.arange(len(trajectory)) * 0.05
    for b in range(len(poses)):
        outcome = formation.outcome(times, trajectory[:, b, :, :2], section, 0.5)
        assert outcome["converged"], b
        assert outcome["conflicts"] == 0
        assert outcome["ratio_to_lower_bound"] >= 1.0


def test_the_baseline_ends_with_the_experts_assignment():
    rng = np.random.default_rng(3)
    count = 7
    section = FormationSection(slots={"grid": {"spacing_m": 0.8}})
    poses = np.concatenate([rng.uniform(-3, 3, (3, count, 2)), rng.uniform(-np.pi, np.pi, (3, count, 1))], -1)
    robot = RobotParams()
    expert = CaptExpert(robot, 0.05, section)
    flood = CaptFlood(robot, 0.05, section, count)
    KinematicSim(robot, expert, 0.05, poses, adjacency=graphs.complete(count)).rollout(1)
    KinematicSim(robot, flood, 0.05, poses, adjacency=graphs.line(count)).rollout(count)  # diameter + 1
    assert flood._targets is not None and expert.targets is not None
    np.testing.assert_array_equal(flood._targets, expert.targets)


def test_decentralized_robot_zero_ignores_robots_beyond_k_hops_for_k_ticks():
    """Robot 0's state (its message: everything it knows) and pose through tick k do not depend on robots
    more than k hops away on a line; with them moved, robot 0's message differs later."""
    count, hops = 8, 4
    rng = np.random.default_rng(11)
    section = FormationSection(slots={"circle": {"radius_m": 1.5}})
    poses = np.concatenate([rng.uniform(-3, 3, (1, count, 2)), rng.uniform(-np.pi, np.pi, (1, count, 1))], -1)
    moved = poses.copy()
    moved[0, hops + 1 :, :2] += 5.0  # robots more than `hops` hops from robot 0 on the line
    robot = RobotParams()
    records = []
    for start in (poses, moved):
        sim = KinematicSim(
            robot, CaptFlood(robot, 0.05, section, count), 0.05, start, adjacency=graphs.line(count)
        )
        messages, robot_poses = [], [sim.poses[0, 0].copy()]
        for _ in range(count + 1):
            sim.step()
            messages.append(sim.inbox[0, 0].copy())  # robot 0's message of the tick just acted
            robot_poses.append(sim.poses[0, 0].copy())
        records.append((np.array(messages), np.array(robot_poses)))
    (messages, robot_poses), (moved_messages, moved_poses) = records
    np.testing.assert_array_equal(messages[: hops + 1], moved_messages[: hops + 1])  # ticks 0..k
    np.testing.assert_array_equal(robot_poses[: hops + 2], moved_poses[: hops + 2])  # acted on ticks 0..k
    assert not np.array_equal(messages[hops + 1], moved_messages[hops + 1])  # tick k+1: robot k+1 heard of


@pytest.mark.parametrize("translation_free", [False, True])
@pytest.mark.parametrize("graph", ["line", "cycle", "complete"])
def test_the_per_robot_baseline_computes_what_the_batched_one_computes(graph, translation_free):
    """``OnboardCaptFlood``, one instance per robot keeping its own messages, fed the engine's poses,
    against ``CaptFlood`` in ``KinematicSim``: the same commands and messages, bit for bit."""
    from swarm.sim.formation_onboard import OnboardCaptFlood

    count = 7
    rng = np.random.default_rng(5)
    section = FormationSection(slots={"line": {"spacing_m": 0.6}}, translation_free=translation_free)
    poses = np.concatenate([rng.uniform(-3, 3, (1, count, 2)), rng.uniform(-np.pi, np.pi, (1, count, 1))], -1)
    adjacency = {"line": graphs.line, "cycle": graphs.cycle, "complete": graphs.complete}[graph](count)
    robot = RobotParams()
    sim = KinematicSim(robot, CaptFlood(robot, 0.05, section, count), 0.05, poses, adjacency=adjacency)
    robots = [OnboardCaptFlood(robot, 0.05, section, count, i) for i in range(count)]
    sent = None
    for _ in range(3 * count):
        now = sim.poses[0].copy()
        outputs = []
        for i, onboard in enumerate(robots):
            heard = [] if sent is None else [sent[j] for j in np.flatnonzero(adjacency[i])]
            messages = np.array(heard).reshape(len(heard), 3 * count)
            outputs.append(onboard.act_one(now[i], messages, None))
        u_world = sim.act()
        np.testing.assert_array_equal(u_world[0], np.array([u for u, _ in outputs]))
        sent = np.array([message for _, message in outputs])
        np.testing.assert_array_equal(sim.inbox[0], sent)
        sim.move(u_world)


@pytest.mark.runtime
def test_swarm_run_and_report_of_a_formation_scenario(tmp_path):
    """``swarm run --engine kinematic`` of a committed scenario: exit 0, the task's metrics and
    pictures; ``swarm report`` re-creates the same metrics from the trajectory; an unreachable
    formation (40 s too short) exits 1."""
    import json

    from swarm.cli import main

    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "formation" / "cycle-capt_flood.yaml"
    out = tmp_path / "run"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["task"] == "formation" and metrics["converged"] and metrics["conflicts"] == 0
    assert metrics["ratio_to_lower_bound"] >= 1.0
    assert (out / "formation.png").is_file() and (out / "convergence.png").is_file()
    (out / "metrics.json").unlink()
    assert main(["report", str(out), "--quiet"]) == 0
    again = json.loads((out / "metrics.json").read_text())
    assert {key: again[key] for key in metrics} == metrics
    short = tmp_path / "short"
    assert main(["run", str(scenario), "--out", str(short), "--quiet", "--duration", "2"]) == 1


def _circle_of_twelve() -> list[tuple[float, float]]:
    """The slots of scenarios/formation/cycle-capt_flood.yaml, written out here: radius 1 m, slot k at
    angle 2 pi k / 12."""
    import math

    return [(math.cos(2 * math.pi * k / 12), math.sin(2 * math.pi * k / 12)) for k in range(12)]


@pytest.mark.runtime
def test_the_pybullet_runtime_forms_the_circle_with_one_agent_per_robot(tmp_path):
    """capt_flood on PyBullet: 12 agent processes, each hearing its two cycle neighbours, fill the 12
    slots of the circle. Judged from the sim server's trajectory against slots computed here
    (:func:`_circle_of_twelve`): every slot holds exactly one axle within the tolerance."""
    import json
    import math

    from swarm.cli import main

    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "formation" / "cycle-capt_flood.yaml"
    out = tmp_path / "pb"
    code = main(["run", str(scenario), "--out", str(out), "--quiet", "--engine", "pybullet"])
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 0, metrics.get("health")
    assert metrics["engine"] == "pybullet" and metrics["task"] == "formation" and metrics["conflicts"] == 0
    final = json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]
    slots = _circle_of_twelve()
    nearest = [min(range(12), key=lambda k: math.dist(pose[:2], slots[k])) for pose in final]
    assert sorted(nearest) == list(range(12))  # one robot per slot
    assert max(math.dist(pose[:2], slots[k]) for pose, k in zip(final, nearest, strict=True)) <= 0.1
    assert metrics["ratio_to_lower_bound"] >= 1.0
    for i in range(12):
        record = json.loads((out / "logs" / f"agent_{i}.json").read_text())
        assert record["controller"] == "capt_flood"
        assert record["neighbours"] == sorted({(i - 1) % 12, (i + 1) % 12})
        assert record["heavy_modules"] == []


@pytest.mark.runtime
def test_the_pybullet_formation_is_judged_by_its_slots_under_faults(tmp_path):
    """Under 20% packet loss and a dropped link the robots still fill every slot (exit 0; the fault
    results had judged it as a rendezvous, 2.0 m apart: the circle's diameter); a robot killed off its
    slot leaves that slot empty (exit 1)."""
    import json
    import math

    import yaml

    from swarm.cli import main

    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "formation" / "cycle-capt_flood.yaml"
    data = yaml.safe_load(scenario.read_text())
    data["sim"]["engine"] = "pybullet"
    slots = _circle_of_twelve()
    for name, faults, expected in (
        ("lossy", [{"kind": "packet_loss", "p": 0.2}, {"at": 1.0, "kind": "drop_link", "link": [0, 1]}], 0),
        ("killed", [{"at": 0.5, "kind": "kill_agent", "robot": 3}], 1),
    ):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**data, "faults": faults}))
        out = tmp_path / name
        assert main(["run", str(path), "--out", str(out), "--quiet"]) == expected, name
        metrics = json.loads((out / "metrics.json").read_text())
        final = json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]
        gaps = [min(math.dist(pose[:2], slot) for pose in final) for slot in slots]  # per slot
        assert metrics["converged"] is (expected == 0) and (max(gaps) <= 0.1) is (expected == 0), name
        assert metrics["faults"]["scheduled"]
        if expected == 0:  # (the killed robot's body may sit by a slot that a live one takes: a conflict)
            assert metrics["conflicts"] == 0 and metrics["faults"]["messages"]["lost_by_fault"] > 0


@pytest.mark.runtime
def test_the_central_capt_expert_forms_the_circle_on_pybullet(tmp_path):
    """capt (central: one process hears every pose) on PyBullet fills the 12 slots of the circle, one
    robot each, judged from the trajectory against slots computed here; its time is no better than the
    lower bound."""
    import json
    import math

    from swarm.cli import main

    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "formation" / "cycle-capt_flood.yaml"
    out = tmp_path / "capt"
    code = main(
        ["run", str(scenario), "--out", str(out), "--quiet", "--engine", "pybullet", "--controller", "capt"]
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == 0, metrics.get("health")
    assert metrics["controller"] == "capt" and metrics["conflicts"] == 0
    final = json.loads((out / "trajectory.jsonl").read_text().splitlines()[-1])["poses"]
    slots = _circle_of_twelve()
    nearest = [min(range(12), key=lambda k: math.dist(pose[:2], slots[k])) for pose in final]
    assert sorted(nearest) == list(range(12))
    assert max(math.dist(pose[:2], slots[k]) for pose, k in zip(final, nearest, strict=True)) <= 0.1
    assert metrics["ratio_to_lower_bound"] >= 1.0
    record = json.loads((out / "logs" / "central.json").read_text())
    assert record["controller"] == "capt" and record["incomplete_ticks"] == 0


# ----------------------------------------------------------------------------- translation free


def _exact_translation_free(positions: np.ndarray, slots: np.ndarray) -> float:
    """``min over t and pi of max_i |x_i - s_pi(i) - t|``: for each bijection, the enclosing circle of the
    differences (its radius is the least max distance over t), by brute force over the bijections."""
    from swarm.core.metrics import minimum_enclosing_circle

    return min(
        minimum_enclosing_circle(positions - slots[list(chosen)])[1]
        for chosen in itertools.permutations(range(len(slots)))
    )


def test_a_shifted_shuffled_formation_is_found_at_distance_zero():
    slots = FormationSection(slots={"grid": {"spacing_m": 0.7}}).slot_positions(6)
    positions = slots[[3, 0, 5, 1, 4, 2]] + [4.0, -2.5]
    shift, value = formation.best_translation(positions, slots)
    assert value < 1e-9 and np.allclose(shift, [4.0, -2.5])
    assert formation.translation_free_lower_bound(positions, slots) == 0.0


@pytest.mark.parametrize("seed", range(12))
def test_the_translation_free_bound_is_below_the_exact_least_distance(seed):
    """Random 5-robot cases: lower bound <= exact (brute force over the 120 bijections) <= the placement
    the controllers use; the lower bound within 25% of the exact value."""
    rng = np.random.default_rng(seed)
    slots = FormationSection(slots={"circle": {"radius_m": 1.0}}).slot_positions(5)
    positions = rng.uniform(-3, 3, (5, 2)) + rng.uniform(-10, 10, 2)
    exact = _exact_translation_free(positions, slots)
    lower = formation.translation_free_lower_bound(positions, slots)
    _, upper = formation.best_translation(positions, slots)
    assert lower <= exact + 1e-9 <= upper + 2e-9
    assert lower >= 0.75 * exact


@pytest.mark.parametrize("controller", [CaptExpert, CaptFlood])
def test_a_translation_free_formation_forms_where_the_swarm_is(controller):
    """Starts 6 m off the slots' centre: the translation-free formation succeeds (no faster than its bound,
    no conflicts) near the starts, sooner than the fixed one."""
    rng = np.random.default_rng(2)
    count = 7
    fixed = FormationSection(slots={"circle": {"radius_m": 1.0}})
    free = FormationSection(slots={"circle": {"radius_m": 1.0}}, translation_free=True)
    poses = np.concatenate([rng.uniform(4, 8, (3, count, 2)), rng.uniform(-np.pi, np.pi, (3, count, 1))], -1)
    kwargs = {"robot_count": count} if controller is CaptFlood else {}
    times = {}
    for name, section in (("fixed", fixed), ("free", free)):
        trajectory = _run(controller, poses, section, graphs.line(count), seconds=40.0, **kwargs)
        stamps = np.arange(len(trajectory)) * 0.05
        times[name] = []
        for b in range(len(poses)):
            outcome = formation.outcome(stamps, trajectory[:, b, :, :2], section, 0.5)
            assert outcome["converged"] and outcome["conflicts"] == 0, (name, b)
            assert outcome["ratio_to_lower_bound"] >= 1.0
            times[name].append(outcome["convergence_time_s"])
            if name == "free":
                assert np.linalg.norm(np.mean(outcome["slots"], axis=0) - poses[b, :, :2].mean(axis=0)) < 1.5
    assert max(times["free"]) < min(times["fixed"])


@pytest.mark.slow
def test_swarm_run_of_the_translation_free_scenario_forms_where_the_robots_are(tmp_path):
    """``scenarios/formation/line-capt_flood-anywhere.yaml``: exit 0; the judged circle (12 slots, radius
    1 m) sits where the robots started, and every robot ends within tolerance of its own slot of it,
    checked here from the trajectory."""
    import json

    from swarm.cli import main

    scenario = (
        Path(__file__).resolve().parents[1] / "scenarios" / "formation" / "line-capt_flood-anywhere.yaml"
    )
    out = tmp_path / "anywhere"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    lines = (out / "trajectory.jsonl").read_text().splitlines()
    start = np.array([pose[:2] for pose in json.loads(lines[0])["poses"]])
    final = np.array([pose[:2] for pose in json.loads(lines[-1])["poses"]])
    slots = np.asarray(metrics["slots"])
    centre = slots.mean(axis=0)
    assert np.allclose(np.linalg.norm(slots - centre, axis=1), 1.0)
    assert np.allclose(centre, metrics["translation_m"], atol=1e-9)  # the circle's own centre is the origin
    assert np.linalg.norm(centre - start.mean(axis=0)) < 1.0
    gaps = np.sqrt(((final[:, None] - slots[None]) ** 2).sum(-1))
    assert sorted(gaps.argmin(axis=1).tolist()) == list(range(12)) and gaps.min(axis=1).max() <= 0.1
    assert metrics["ratio_to_lower_bound"] >= 1.0 and metrics["conflicts"] == 0
