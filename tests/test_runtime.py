"""Tests for the distributed runtime (``swarm run --engine pybullet``): real processes, real Zenoh
sessions on loopback, real PyBullet.

Each test runs ``python -m swarm.cli run`` (sim server + one process per robot) and checks what the
processes left behind: the results directory, the agents' own records of what they subscribed to,
the server's statistics, and that no process survives the run, a Ctrl-C, or a killed agent.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import swarm_run
import yaml
from PIL import Image

from swarm.core.robot import controlled_point, point_velocity_to_wheels
from swarm.runtime import wire
from swarm.runtime.distributed import AGENT_NICE
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import load_scenario
from swarm.sim.controllers import LocalConsensus
from swarm.sim.kinematic import KinematicSim
from swarm.sim.links import Links

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out

PROJECT_ROOT = Path(__file__).resolve().parent.parent
THESIS = PROJECT_ROOT / "scenarios" / "thesis"
RUN_TIMEOUT_S = 480.0
"""A hang detector, not a budget: on 2 cores at load 60 (100-agent benchmarks beside the suite) a
run's start-up alone can take minutes; only a run that never ends waits this long."""
METRICS_KEYS = {"converged", "convergence_time_s", "final_metric", "metric", "threshold", "lower_bound_s"}

POSITION_TOLERANCE_M = 0.08
"""Kinematic vs PyBullet axle positions before the first contact. Measured on the thesis cycle start
(seed 1): 0.043 m at most (tick 23, 1.15 s), from the wheels' finite acceleration in PyBullet (the
kinematic unicycle changes speed instantly; each command change costs the physical robot ~1-2 cm)."""


def scenario_file(tmp_path: Path, name: str, **changes: object) -> Path:
    """A thesis scenario with ``section.key=value`` changes, written to ``tmp_path``."""
    data = yaml.safe_load((THESIS / f"{name}.yaml").read_text())
    for dotted, value in changes.items():
        section, key = dotted.split("__")
        data.setdefault(section, {})[key] = value
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


class Run:
    """``swarm run`` in a subprocess, watching every process it starts (psutil)."""

    def __init__(self, scenario: Path, out: Path, *options: str):
        self.out = out
        self.process = swarm_run.start(scenario, out, *options, interruptible=True)
        self.seen: dict[int, float] = {}  # pid -> create time, of every descendant ever seen

    def watch(self) -> None:
        with contextlib.suppress(psutil.NoSuchProcess):
            for child in psutil.Process(self.process.pid).children(recursive=True):
                with contextlib.suppress(psutil.NoSuchProcess):
                    self.seen.setdefault(child.pid, child.create_time())

    def ticks(self) -> int:
        path = self.out / "trajectory.jsonl"
        return path.read_bytes().count(b"\n") if path.exists() else 0

    def wait_for(self, ready, timeout_s: float = RUN_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while not ready():
            self.watch()
            assert self.process.poll() is None, f"run ended early: {self.process.communicate()}"
            assert time.monotonic() < deadline, "timed out"
            time.sleep(0.02)

    def finish(self, timeout_s: float = RUN_TIMEOUT_S) -> tuple[int, str, str]:
        deadline = time.monotonic() + timeout_s
        while self.process.poll() is None:
            self.watch()
            if time.monotonic() > deadline:
                self.process.kill()
                pytest.fail("swarm run did not finish in time")
            time.sleep(0.02)
        out, err = self.process.communicate()
        return self.process.returncode, out, err

    def survivors(self, grace_s: float = 30.0) -> list[int]:
        """Descendants still running (zombies count as gone) after ``grace_s`` at most."""
        deadline = time.monotonic() + grace_s
        while True:
            alive = []
            for pid, created in self.seen.items():
                try:
                    process = psutil.Process(pid)
                    if process.create_time() == created and process.status() != psutil.STATUS_ZOMBIE:
                        alive.append(pid)
                except psutil.NoSuchProcess:
                    pass
            if not alive or time.monotonic() > deadline:
                return alive
            time.sleep(0.05)


def max_pairwise_of(poses: np.ndarray) -> np.ndarray:
    """Largest distance between two robots at each tick, computed here (not by swarm.core.metrics)."""
    xy = poses[..., :2]
    return np.array([max(np.hypot(*(a - b)) for a in frame for b in frame) for frame in xy])


def agent_records(out: Path) -> dict[int, dict]:
    return {int(p.stem.split("_")[1]): json.loads(p.read_text()) for p in (out / "logs").glob("agent_*.json")}


def assert_commands_equal_batched_policy(out: Path, scenario_path: Path, model: Path) -> np.ndarray:
    """Replay a lockstep run's logged poses through the batched policy of the kinematic engine (its
    own previous outbox as everybody's inbox: every agent heard all its neighbours last tick) and
    assert that every applied wheel command equals it to 1e-9; returns the applied commands
    ``(T, N, 2)``."""
    from swarm.sim.policy import load_policy

    scenario = load_scenario(scenario_path)
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    poses = np.array([line["poses"] for line in lines])
    applied = np.array([line["wheels"] for line in lines[:-1]])
    count = scenario.robots.count
    policy = load_policy(model, scenario.robot, count)
    points = controlled_point(poses, scenario.robot.offset_m)
    inbox, heard = np.zeros((1, count, policy.message_dim)), Links.nobody(1, count)
    for tick, wheels in enumerate(applied):
        u_world, inbox = policy.act(poses[tick][None], points[tick][None], inbox, heard)
        expected = point_velocity_to_wheels(u_world[0], poses[tick, :, 2], scenario.robot)
        np.testing.assert_allclose(wheels, expected, rtol=0, atol=1e-9, err_msg=f"tick {tick}")
        heard = Links.from_dense(scenario.adjacency()[None])
    return applied


def test_pybullet_run_writes_results_and_every_agent_listens_only_to_its_neighbours(tmp_path):
    scenario_path = scenario_file(tmp_path, "cycle-local_consensus", sim__duration=6.0)
    out = tmp_path / "results"
    run = Run(scenario_path, out)
    code, stdout, stderr = run.finish()
    assert code == 0, stderr
    assert "on pybullet" in stdout and "converged" in stdout
    assert run.survivors() == []

    scenario = load_scenario(scenario_path)
    steps, count = scenario.steps, scenario.robots.count
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= METRICS_KEYS | {"processes", "runtime", "components"}
    assert metrics["engine"] == "pybullet" and metrics["converged"] is True
    assert metrics["final_metric"] <= metrics["threshold"] == scenario.threshold
    runtime = metrics["runtime"]
    assert runtime["ticks_served"] + runtime["ticks_missed"] == steps
    assert runtime["messages_invalid"] == 0 and runtime["invalid_commands"] == 0
    stats = json.loads((out / "server_stats.json").read_text())
    assert sum(stats["latency_histogram_ms"].values()) == stats["latency_ms"]["count"] > 0
    assert all(stats[f"{part}_cpu_ms_per_tick"] > 0 for part in ("publish", "trajectory", "physics"))
    # The runner nices the agents (robot-agent --nice): the server wins a contended core.
    nice = min(19, os.getpriority(os.PRIO_PROCESS, 0) + AGENT_NICE)
    assert {record["nice"] for record in agent_records(out).values()} == {nice}

    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    assert [line["tick"] for line in lines] == list(range(steps + 1))
    assert all(np.shape(line["wheels"]) == (count, 2) for line in lines[:-1])
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert poses.shape == (steps + 1, count, 3)
    np.testing.assert_allclose(times_s, np.arange(steps + 1) * scenario.sim.control_period_s)
    np.testing.assert_allclose(poses[0], scenario.initial_poses(), atol=1e-3)  # after settling on the ground
    for picture, kind in [("convergence.png", "PNG"), ("animation.gif", "GIF")]:
        with Image.open(out / picture) as image:
            assert image.format == kind
    assert (out / "logs" / "sim_server.log").is_file() and (out / "server_stats.json").is_file()

    # decentralization, from each agent's own record of its declarations
    keys = wire.Keys(agent_records(out)[0]["run"])
    adjacency = scenario.adjacency()
    records = agent_records(out)
    assert sorted(records) == list(range(count))
    for i, record in records.items():
        neighbours = [int(j) for j in np.flatnonzero(adjacency[i])]
        assert record["robot"] == i and record["neighbours"] == neighbours
        assert record["subscriptions"] == [keys.pose(i), *(keys.msg(j) for j in neighbours)]
        assert record["liveliness_subscriptions"] == [
            keys.alive_sim,
            *(keys.alive_agent(j) for j in neighbours),
        ]
        assert record["publications"] == [keys.msg(i), keys.cmd(i)]
        assert record["liveliness_tokens"] == [keys.alive_agent(i)]
        assert record["heavy_modules"] == []  # no torch, pybullet or numba in an agent process
        assert record["ticks"] == steps and record["exit_reason"] == "sim gone"
        assert record["messages"]["invalid"] == 0
    pids = [record["pid"] for record in records.values()]
    processes = metrics["processes"]
    assert len(set(pids)) == count
    assert processes["agent_pids"] == {str(i): record["pid"] for i, record in records.items()}
    assert set(pids) <= set(run.seen)
    assert processes["server_pid"] in run.seen and processes["server_pid"] not in pids


def test_ctrl_c_mid_run_stops_every_process(tmp_path):
    run = Run(scenario_file(tmp_path, "line-local_consensus", sim__duration=120.0), tmp_path / "out")
    run.wait_for(lambda: run.ticks() >= 10)
    run.watch()
    assert len(run.seen) >= 8  # server, launcher, 6 agents
    run.process.send_signal(signal.SIGINT)
    code, stdout, stderr = run.finish(timeout_s=30)
    assert code == 130 and "interrupted" in stderr
    assert run.survivors() == []
    out = tmp_path / "out"
    stats = json.loads((out / "server_stats.json").read_text())
    assert stats["exit"] == "interrupted"
    # The run ends with its results, from the ticks on disk, marked partial in the file and on the plot.
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert 10 <= len(times_s) < 2401
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["partial"] is True and outcome["incomplete"].startswith("interrupted (Ctrl-C)")
    assert outcome["ticks"] == len(times_s) - 1 and outcome["ticks_planned"] == 2400
    assert "PARTIAL: interrupted (Ctrl-C)" in stdout and f"results: {out}" in stdout
    plot = json.loads((out / "convergence.png.json").read_text())
    assert plot["title"].startswith("PARTIAL: ")
    assert [text["gid"] for text in plot["texts"]] == ["partial"]
    judged = next(line for line in plot["lines"] if line["gid"] == "judged")
    assert np.allclose(judged["y"], max_pairwise_of(poses), atol=1e-5)  # the curve is this run's
    assert judged["x"] == pytest.approx(times_s.tolist())
    with Image.open(out / "animation.gif") as gif:
        assert gif.n_frames >= 2
        assert Image.open(out / "convergence.png").size[0] > 0


def test_a_killed_agent_stops_its_robot_and_the_run_goes_on(tmp_path):
    out = tmp_path / "out"
    run = Run(scenario_file(tmp_path, "cycle-local_consensus", sim__duration=4.0), out)
    run.wait_for(lambda: run.ticks() >= 10 and len(agent_records(out)) == 6)
    os.kill(agent_records(out)[2]["pid"], signal.SIGKILL)
    code, _, stderr = run.finish()
    assert code in (0, 1), stderr
    assert run.survivors() == []
    stats = json.loads((out / "server_stats.json").read_text())
    gone = [event for event in stats["agent_events"] if event["event"] == "gone"]
    assert [event["robot"] for event in gone] == [2]
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    after = [line["wheels"] for line in lines[gone[0]["tick"] + 1 : -1]]
    assert after and all(wheels[2] == [0.0, 0.0] for wheels in after)  # stopped at once, for good
    assert any(wheels[0] != [0.0, 0.0] for wheels in after)
    records = agent_records(out)
    assert records[1]["messages"]["lost"] > 0 and records[3]["messages"]["lost"] > 0  # 2's neighbours
    assert records[0]["messages"]["lost"] == 0


def test_agents_exit_when_the_sim_server_dies(tmp_path):
    out = tmp_path / "out"
    run = Run(scenario_file(tmp_path, "cycle-local_consensus", sim__duration=60.0), out)
    run.wait_for(lambda: run.ticks() >= 10 and len(agent_records(out)) == 6)
    server = next(
        p for p in psutil.Process(run.process.pid).children() if p.cmdline()[1:3] == ["-m", "sim_server"]
    )
    server.kill()
    code, _, stderr = run.finish(timeout_s=30)
    assert code == 1 and "sim server exited" in stderr  # ran, could not complete: not bad input
    assert run.survivors() == []
    assert {record["exit_reason"] for record in agent_records(out).values()} == {"sim gone"}


@pytest.fixture(scope="module")
def lockstep_cycle(tmp_path_factory):
    """The thesis cycle start, 4 s (robots touch from ~3 s), run twice in the PyBullet runtime."""
    tmp_path = tmp_path_factory.mktemp("lockstep")
    # deadlines no loaded machine reaches: a tick or message that misses one would change the trajectory
    path = scenario_file(
        tmp_path, "cycle-local_consensus", sim__duration=4.0, sim__deadline=5.0, sim__neighbour_deadline=5.0
    )
    outs = []
    for attempt in range(2):
        out = tmp_path / f"run{attempt}"
        code, _, stderr = Run(path, out).finish()
        assert code in (0, 1), stderr
        outs.append(out)
    return load_scenario(path), outs


def test_lockstep_runs_are_reproducible(lockstep_cycle):
    _, (first, second) = lockstep_cycle
    assert (first / "trajectory.jsonl").read_text() == (second / "trajectory.jsonl").read_text()
    for out in (first, second):
        assert json.loads((out / "server_stats.json").read_text())["ticks_missed"] == 0


def test_runtime_has_the_kinematic_engines_information_timing(lockstep_cycle):
    """Every command the agents sent is what the kinematic engine's controller computes from the
    same poses with the neighbours' points of the previous tick (and nothing at tick 0)."""
    scenario, (out, _) = lockstep_cycle
    lines = [json.loads(line) for line in (out / "trajectory.jsonl").read_text().splitlines()]
    poses = np.array([line["poses"] for line in lines])
    applied = np.array([line["wheels"] for line in lines[:-1]])
    robot = scenario.robot
    points = controlled_point(poses, robot.offset_m)
    controller = LocalConsensus(robot, scenario.controller.gain)
    links = Links.from_dense(scenario.adjacency()[None])

    def wheels(tick: int, inbox_tick: int) -> np.ndarray:
        u_world, _ = controller.act(poses[tick][None], points[tick][None], points[inbox_tick][None], links)
        return point_velocity_to_wheels(u_world[0], poses[tick, :, 2], robot)

    assert np.all(applied[0] == 0.0)  # tick 0: nobody has heard anybody yet
    delayed = np.array([wheels(k, k - 1) for k in range(1, len(applied))])
    np.testing.assert_allclose(applied[1:], delayed, rtol=0, atol=1e-9)
    undelayed = np.array([wheels(k, k) for k in range(1, len(applied))])
    assert np.abs(applied[1:] - undelayed).max() > 1e-3  # the check can tell the timings apart


def test_same_scenario_same_trajectory_as_kinematic_until_contact(lockstep_cycle):
    scenario, (out, _) = lockstep_cycle
    _, physical, _ = read_trajectory(out / "trajectory.jsonl")
    sim = KinematicSim(
        scenario.robot,
        LocalConsensus(scenario.robot, scenario.controller.gain),
        scenario.sim.control_period_s,
        scenario.initial_poses()[None],
        adjacency=scenario.adjacency(),
    )
    kinematic = sim.rollout(scenario.steps)[:, 0]
    contact_m = 2 * scenario.robot.body_radius_m + 0.02
    closest = [graphs_min_distance(trajectory) for trajectory in (kinematic, physical)]
    first_contact = int(np.argmax((closest[0] < contact_m) | (closest[1] < contact_m)))
    assert first_contact > 20  # the comparison covers a real stretch of the run
    error_m = np.linalg.norm(physical[:first_contact, :, :2] - kinematic[:first_contact, :, :2], axis=-1)
    assert error_m.max() < POSITION_TOLERANCE_M, error_m.max()
    assert error_m[1].max() < 1e-3  # both hold still during tick 0


def graphs_min_distance(poses: np.ndarray) -> np.ndarray:
    """Smallest axle-to-axle distance per tick, ``(T, N, 3) -> (T,)``."""
    gaps = np.linalg.norm(poses[:, :, None, :2] - poses[:, None, :, :2], axis=-1)
    gaps[:, np.arange(poses.shape[1]), np.arange(poses.shape[1])] = np.inf
    return gaps.min(axis=(1, 2))


def test_a_policy_file_runs_in_the_agents_with_the_kinematic_engines_timing(tmp_path):
    """The GNN path: the sim serves the policy file, each agent runs it with numpy (no torch), and
    every command equals what the batched policy of the kinematic engine computes, tick by tick,
    from the same poses and last tick's messages."""
    from swarm.sim.policy import save_policy

    rng = np.random.default_rng(0)
    metadata = {
        "model": {"kind": "model2", "activation": "tanh"},
        "features": {"hops": 2, "phi_source": "m", "normaliser": "degree"},
        "feature_scale_m": 1.0,
        "output_scale_mps": 0.5,
        "robot": {"wheel_radius_m": 0.04, "half_axle_m": 0.1, "offset_m": 0.05, "v_max_mps": 0.5},
        "training": {"note": "random weights, for this test"},
    }
    arrays = {"net.0.weight": rng.normal(0, 0.5, (8, 4)), "net.1.weight": rng.normal(0, 0.5, (2, 8))}
    model = save_policy(tmp_path / "policy.npz", metadata, arrays)
    path = scenario_file(tmp_path, "cycle-local_consensus", sim__duration=2.0, controller__kind="gnn")
    out = tmp_path / "out"
    code, _, stderr = Run(path, out, "--model", str(model)).finish()
    assert code in (0, 1), stderr
    assert all(r["controller"] == "gnn" and r["heavy_modules"] == [] for r in agent_records(out).values())

    applied = assert_commands_equal_batched_policy(out, path, model)
    assert np.abs(applied).max() > 0.1


def test_realtime_mode_runs_on_the_wall_clock(tmp_path):
    out = tmp_path / "out"
    path = scenario_file(tmp_path, "complete-local_consensus", sim__duration=3.0, sim__mode="realtime")
    started = time.monotonic()
    code, _, stderr = Run(path, out, "--agent-nice", "0").finish()
    assert code in (0, 1), stderr
    assert time.monotonic() - started >= 3.0
    nice = os.getpriority(os.PRIO_PROCESS, 0)  # --agent-nice 0: the agents at the runner's niceness
    assert {record["nice"] for record in agent_records(out).values()} == {nice}
    stats = json.loads((out / "server_stats.json").read_text())
    assert stats["mode"] == "realtime" and stats["exit"] == "done"
    # The lateness records account for every tick and command: a tick is served exactly when no
    # agent's command was missing at the step; poses never go out before their boundary.
    late = stats["late_agents_per_tick"]
    assert sum(late.values()) == stats["ticks"] == 60 and late["0"] == stats["ticks_served"]
    assert stats["slowest_command_ms"]["count"] == stats["ticks_served"]
    assert stats["publish_lag_ms"]["count"] == 60 and stats["publish_lag_ms"]["p50"] >= 0.0
    assert sum(stats["latency_histogram_ms"].values()) == stats["latency_ms"]["count"] > 0
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert len(poses) == 61
    spread = np.ptp(poses[:, :, :2], axis=1).max(axis=-1)
    assert spread[-1] < spread[0] - 0.5  # the robots came together
    assert all(record["ticks"] > 0 for record in agent_records(out).values())


def test_centralized_expert_runs_as_one_central_process(tmp_path):
    out = tmp_path / "out"
    code, _, stderr = Run(scenario_file(tmp_path, "cycle-centralized", sim__duration=4.0), out).finish()
    assert code == 0, stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["controller"] == "centralized" and metrics["processes"]["agent_pids"] == {}
    record = json.loads((out / "logs" / "central.json").read_text())
    keys = wire.Keys(record["run"])
    assert record["role"] == "centralized" and record["subscriptions"] == [keys.all_poses]
    assert record["pid"] == metrics["processes"]["central_pid"]


def test_a_disk_graph_runs_through_the_sims_radio_with_access_control_and_faults(tmp_path):
    """A disk graph on PyBullet (``sim_server.radio``): access control on by default, every agent
    subscribed to its own pose and radio inbox only (no other robot's message key), 20% packet loss
    counted in the summary, and the run judged as any other. Who hears whom: ``tests/test_radio.py``."""
    path = scenario_file(
        tmp_path,
        "cycle-local_consensus",
        topology__kind="disk",
        topology__radius=3.0,
        sim__duration=12,
    )
    data = yaml.safe_load(path.read_text())
    data["faults"] = [{"kind": "packet_loss", "p": 0.2}]
    path.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    code, stdout, stderr = Run(path, out).finish()
    metrics = json.loads((out / "metrics.json").read_text())
    assert code == (0 if metrics["converged"] else 1), stderr
    assert "access control: on" in stdout
    assert metrics["faults"]["messages"]["lost_by_fault"] > 0
    stats = json.loads((out / "server_stats.json").read_text())
    assert stats["radio"]["relayed"] > 0 and stats["radio"]["lost_by_fault"] > 0
    assert stats["radio"]["lost_by_fault"] == metrics["faults"]["messages"]["lost_by_fault"]
    for i in range(6):
        record = json.loads((out / "logs" / f"agent_{i}.json").read_text())
        keys = wire.Keys(record["run"])
        assert record["subscriptions"] == [keys.pose(i), keys.inbox(i)]
        assert record["radio"]["missing"] == 0 and record["radio"]["received"] == 240


def test_two_triangles_meet_per_component_but_not_globally(tmp_path):
    out = tmp_path / "out"
    code, stdout, _ = Run(scenario_file(tmp_path, "weak-local_consensus", sim__duration=3.0), out).finish()
    assert code == 1 and "NOT converged" in stdout and "2 components" in stdout
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["converged"] is False and metrics["graph_connected"] is False
    assert [c["robots"] for c in metrics["components"]] == [[0, 1, 2], [3, 4, 5]]
    assert all(component["converged"] for component in metrics["components"])
