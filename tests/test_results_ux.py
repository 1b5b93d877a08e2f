"""What a user sees of a run: safe results directories, typo suggestions, warnings for scenario keys that
do nothing, recordings (MCAP, rerun) that read back with their libraries' own readers, a sim server
started by hand that writes its results, and the Gymnasium id without importing the package.

Runs are real ``swarm run`` processes (kinematic engine, seconds each) and a real PyBullet server with
real agent processes over Zenoh on loopback.
"""

from __future__ import annotations

import json
import math
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import swarm_run
import yaml
from test_runtime import max_pairwise_of

from swarm.cli import main
from swarm.core import metrics
from swarm.runtime.procs import free_tcp_port
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import ScenarioError, load_scenario, parse_scenario

PROJECT_ROOT = Path(__file__).resolve().parent.parent
FAULTS = PROJECT_ROOT / "scenarios" / "faults"
THESIS = PROJECT_ROOT / "scenarios" / "thesis"


def swarm(*args: str, cwd: Path = PROJECT_ROOT, timeout_s: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "swarm.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=timeout_s,
        stdin=subprocess.DEVNULL,
    )


def short_scenario(tmp_path: Path, source: Path, name: str = "s.yaml", **sim: object) -> Path:
    data = yaml.safe_load(source.read_text())
    data.setdefault("sim", {}).update({"engine": "kinematic", "duration": 3.0, **sim})
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


# ----------------------------------------------------------------------------- results directories


def test_out_into_a_non_empty_directory_is_refused_unless_force_clears_it(tmp_path, capsys):
    # in-process (swarm.cli.main): kinematic runs, and the one line of the refusal
    scenario = short_scenario(tmp_path, THESIS / "cycle-local_consensus.yaml")
    out = tmp_path / "out"
    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) in (0, 1)
    (out / "stale.txt").write_text("from an earlier run")
    before = (out / "metrics.json").read_text()
    capsys.readouterr()

    assert main(["run", str(scenario), "--out", str(out), "--quiet"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"swarm run: error: --out {out}: directory is not empty (--force clears it first)"
    ]
    assert (out / "stale.txt").exists() and (out / "metrics.json").read_text() == before  # untouched

    assert main(["run", str(scenario), "--out", str(out), "--quiet", "--force"]) in (0, 1)
    assert not (out / "stale.txt").exists() and (out / "metrics.json").is_file()


@pytest.mark.slow
def test_default_results_directories_never_collide(tmp_path):
    scenario = short_scenario(tmp_path, THESIS / "cycle-local_consensus.yaml", duration=0.5)
    for _ in range(2):
        result = swarm("run", str(scenario), "--quiet", cwd=tmp_path)
        assert result.returncode in (0, 1), result.stderr
    runs = sorted((tmp_path / "runs").iterdir())
    assert len(runs) == 2 and all(run.name.startswith("thesis-cycle-6-") for run in runs)
    assert all((run / "metrics.json").is_file() for run in runs)


# ----------------------------------------------------------------------------- scenario files


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ({"topology": {"knd": "cycle"}}, "topology.knd: unknown key 'knd', did you mean 'kind'?"),
        ({"robots": {"cont": 3}}, "robots.cont: unknown key 'cont', did you mean 'count'?"),
        ({"sim": {"engin": "kinematic"}}, "sim.engin: unknown key 'engin', did you mean 'engine'?"),
        ({"robot": {"v_maxx": 1.0}}, "robot.v_maxx: unknown key 'v_maxx', did you mean 'v_max'?"),
        ({"bogus": 1}, "bogus: unknown key"),  # nothing close: no suggestion
    ],
)
def test_a_typo_names_the_unknown_key_and_the_closest_known_one(section, expected):
    data = {"name": "x", "robots": {"count": 3}, "topology": {"kind": "cycle"}, **section}
    with pytest.raises(ScenarioError) as error:
        parse_scenario(data, "typo.yaml")
    assert str(error.value) == f"typo.yaml: {expected}"  # the misspelt key's "missing" is not repeated


@pytest.mark.slow
def test_the_kinematic_engine_warns_about_keys_it_ignores(tmp_path):
    scenario = short_scenario(tmp_path, THESIS / "cycle-local_consensus.yaml", acl=True, watchdog_s=0.5)
    result = swarm("run", str(scenario), "--out", str(tmp_path / "out"), "--quiet")
    assert result.returncode in (0, 1), result.stderr
    warned = re.findall(r"(sim\.\w+): \S+ does not apply to the kinematic engine", result.stderr)
    assert warned == ["sim.watchdog_s", "sim.acl"]
    quiet = swarm(
        "run",
        str(THESIS / "cycle-local_consensus.yaml"),
        "--engine",
        "kinematic",
        "--duration",
        "1",
        "--out",
        str(tmp_path / "out2"),
        "--quiet",
    )
    assert "does not apply" not in quiet.stderr


def _hexagonal_cluster(count: int, radius_m: float) -> np.ndarray:
    """``count`` centres of a hexagonal packing of touching discs, nearest the origin first."""
    rows = range(-count, count + 1)
    points = np.array(
        [(2 * radius_m * (i + 0.5 * j), 2 * radius_m * j * math.sqrt(3) / 2) for i in rows for j in rows]
    )
    return points[np.argsort(np.hypot(points[:, 0], points[:, 1]), kind="stable")[:count]]


@pytest.mark.parametrize("count", [2, 3, 4, 5, 6, 7, 8, 12, 20, 50])
def test_packed_bodies_bound_is_reached_or_never_beaten(count):
    radius_m = 0.25
    bound_m = metrics.min_gathered_max_pairwise_m(count, radius_m)
    # Never beaten: no placement of touching or separated bodies has a smaller diameter (random search,
    # and the hexagonal packing, the densest there is).
    rng = np.random.default_rng(count)
    hexagonal = _hexagonal_cluster(count, radius_m)
    assert max_pairwise_of(hexagonal[None, :, :])[0] >= bound_m - 1e-9
    for _ in range(200):
        points = hexagonal * rng.uniform(1.0, 1.3) + rng.normal(0, 0.1 * radius_m, hexagonal.shape)
        gaps = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)) + np.eye(count) * 1e9
        if gaps.min() >= 2 * radius_m:
            assert max_pairwise_of(points[None])[0] >= bound_m - 1e-9
    # Reached where it is exact: a regular polygon (and its centre, for 6 and 7) with 2r apart.
    if 3 <= count <= 7:
        sides = {6: 5, 7: 6}.get(count, count)
        circumradius = radius_m / math.sin(math.pi / sides) if count < 6 else 2 * radius_m
        angles = 2 * math.pi * np.arange(sides) / sides
        points = np.c_[circumradius * np.cos(angles), circumradius * np.sin(angles)]
        if count >= 6:
            points = np.vstack([points, [0.0, 0.0]])
        gaps = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)) + np.eye(count) * 1e9
        assert gaps.min() >= 2 * radius_m - 1e-9
        assert max_pairwise_of(points[None])[0] == pytest.approx(bound_m)


def test_a_threshold_below_what_the_bodies_allow_is_warned_about(tmp_path, caplog):
    data = yaml.safe_load((THESIS / "cycle-local_consensus.yaml").read_text())
    data["robot"] = {"body_radius_m": 0.35}
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(data))
    with caplog.at_level("WARNING", logger="swarm.scenarios.scenario"):
        load_scenario(path)
    expected = metrics.min_gathered_max_pairwise_m(6, 0.35)
    assert expected > 1.3
    assert [record.getMessage() for record in caplog.records] == [
        f"{path}: success.threshold: 1.3 m is below what 6 bodies of radius 0.35 m allow on the pybullet"
        f" engine (max_pairwise {expected:.3f} m when packed); the run cannot converge there"
    ]
    caplog.clear()
    with caplog.at_level("WARNING", logger="swarm.scenarios.scenario"):
        load_scenario(THESIS / "cycle-local_consensus.yaml")  # 1.3 m for 0.12 m bodies: fine
    assert caplog.records == []


# ----------------------------------------------------------------------------- recordings


@pytest.mark.slow
def test_recordings_read_back_with_every_tick(tmp_path):
    """A kinematic run with a dropped link, recorded as MCAP (read back with mcap_ros2's reader) and,
    when rerun-sdk is installed, as .rrd (read back with rerun's reader)."""
    scenario = short_scenario(tmp_path, FAULTS / "drop-link.yaml", duration=4.0)
    data = yaml.safe_load(scenario.read_text())
    data["faults"] = [
        {"at": 1.0, "kind": "drop_link", "link": [0, 1]},
        {"at": 3.0, "kind": "restore_link", "link": [0, 1]},
    ]
    scenario.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    formats = ["mcap"]
    try:
        import rerun  # noqa: F401

        formats.append("rerun")
    except ImportError:
        pass
    result = swarm("run", str(scenario), "--out", str(out), "--quiet", "--record", *formats)
    assert result.returncode in (0, 1), result.stderr
    assert f"recording: {out / 'recording.mcap'}" in result.stdout
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    ticks = len(times_s)
    assert ticks == 81

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(out / "recording.mcap", "rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "ros2"
        schemas = {schema.name for schema in reader.get_summary().schemas.values()}
        outcome = json.loads(next(reader.iter_metadata()).metadata["metrics.json"])
    assert schemas >= {
        "geometry_msgs/msg/PoseArray",
        "visualization_msgs/msg/MarkerArray",
        "std_msgs/msg/Float64",
    }
    assert outcome == json.loads((out / "metrics.json").read_text())
    by_topic: dict[str, list] = {}
    log_times: dict[str, list] = {}
    with open(out / "recording.mcap", "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append(decoded)
            log_times.setdefault(channel.topic, []).append(message.log_time)
    per_tick = ["/robots/poses", "/robots/markers", "/graph/edges", "/metric"] + [
        f"/robot_{i}/cmd_vel" for i in range(6)
    ]
    for topic in per_tick:
        assert len(by_topic[topic]) == ticks, topic
        assert log_times[topic] == [round(t * 1e9) for t in times_s], topic
    for tick in (0, 40, ticks - 1):
        pose_array = by_topic["/robots/poses"][tick]
        assert pose_array.header.frame_id == "world"
        xy = [(p.position.x, p.position.y) for p in pose_array.poses]
        assert np.allclose(xy, poses[tick, :, :2], atol=1e-12)
        theta = [2 * math.atan2(p.orientation.z, p.orientation.w) for p in pose_array.poses]
        assert np.allclose(np.angle(np.exp(1j * (np.array(theta) - poses[tick, :, 2]))), 0, atol=1e-9)
    assert [m.data for m in by_topic["/metric"]] == pytest.approx(max_pairwise_of(poses).tolist(), abs=1e-9)

    def edges(tick: int, ns: str) -> set:
        marker = next(m for m in by_topic["/graph/edges"][tick].markers if m.ns == ns)
        ends = [(round(p.x, 9), round(p.y, 9)) for p in marker.points]
        index = {(round(x, 9), round(y, 9)): i for i, (x, y) in enumerate(poses[tick, :, :2].tolist())}
        return {tuple(sorted((index[a], index[b]))) for a, b in zip(ends[::2], ends[1::2], strict=True)}

    cycle = {(i, (i + 1) % 6) if i < 5 else (0, 5) for i in range(6)}
    assert edges(10, "live") == cycle and edges(10, "down") == set()
    assert edges(40, "down") == {(0, 1)} and edges(40, "live") == cycle - {(0, 1)}  # dropped 1-3 s
    assert edges(70, "down") == set()
    assert [json.loads(m.data)["kind"] for m in by_topic["/faults"]] == ["drop_link", "restore_link"]
    # Commands from the motion: a robot's recorded (v, w) carries it to its next pose.
    dt = 0.05
    for msg, now, after in zip(by_topic["/robot_2/cmd_vel"][:-1], poses[:-1, 2], poses[1:, 2], strict=True):
        assert msg.twist.angular.z * dt == pytest.approx(np.angle(np.exp(1j * (after[2] - now[2]))), abs=1e-9)
        assert abs(msg.twist.linear.x) * dt >= np.hypot(*(after[:2] - now[:2])) - 1e-12
    if "rerun" in formats:
        from rerun.chunk import RrdReader

        rows: dict[str, int] = {}
        for chunk in RrdReader(out / "recording.rrd").stream():
            if not chunk.is_static:
                rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        assert rows == {
            "/world/robots": ticks,
            "/world/edges/live": ticks,
            "/world/edges/down": ticks,
            "/metric": ticks,
        }


# ----------------------------------------------------------------------------- a sim server started by hand


@pytest.mark.runtime
def test_a_sim_server_started_by_hand_writes_its_results_and_says_where(tmp_path):
    """The sim server and the agents started by hand (as on several hosts, here on loopback); Ctrl-C to
    the server mid-run: it writes metrics.json and the plots from the ticks on disk, marked partial,
    and prints the summary and the results directory."""
    data = yaml.safe_load((THESIS / "cycle-local_consensus.yaml").read_text())
    data["sim"]["duration"] = 60.0
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump(data))
    out, endpoint = tmp_path / "results", f"tcp/127.0.0.1:{free_tcp_port()}"
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sim_server",
            "--scenario",
            str(scenario),
            "--out",
            str(out),
            "--listen",
            endpoint,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=PROJECT_ROOT,
    )
    agents = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "robot_agent",
            "--robots",
            "0-5",
            "--connect",
            endpoint,
            "--log-dir",
            str(tmp_path / "agent-logs"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=PROJECT_ROOT,
    )
    try:
        deadline = time.monotonic() + 120
        trajectory = out / "trajectory.jsonl"
        while not (trajectory.exists() and trajectory.read_bytes().count(b"\n") >= 20):
            assert server.poll() is None, server.communicate()
            assert time.monotonic() < deadline, "no ticks"
            time.sleep(0.05)
        server.send_signal(signal.SIGINT)
        stdout, stderr = server.communicate(timeout=120)
        agents.wait(timeout=60)
    finally:
        for process in (server, agents):
            if process.poll() is None:
                process.kill()
    assert server.returncode != 0, stderr
    times_s, poses, _ = read_trajectory(out / "trajectory.jsonl")
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["partial"] is True and "the sim server was interrupted" in outcome["incomplete"]
    assert outcome["ticks"] == len(times_s) - 1 < 1200
    assert outcome["final_metric"] == pytest.approx(max_pairwise_of(poses)[-1], abs=1e-9)
    assert f"results: {out}" in stdout and "PARTIAL: the sim server was interrupted" in stdout
    plot = json.loads((out / "convergence.png.json").read_text())
    assert plot["title"].startswith("PARTIAL: ")
    assert (out / "convergence.png").stat().st_size > 0 and (out / "animation.gif").stat().st_size > 0


# ----------------------------------------------------------------------------- Gymnasium


def test_the_gymnasium_environment_needs_no_import_of_the_package():
    code = (
        "import gymnasium as gym\n"
        "env = gym.make('swarm.rl:swarm/Consensus-v0')\n"
        "observation, _ = env.reset(seed=0)\n"
        "print(env.spec.id, observation.shape)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd="/"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[0] == "swarm/Consensus-v0"


def test_the_package_declares_its_gymnasium_entry_point():
    from importlib.metadata import EntryPoint

    import gymnasium

    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    project = tomllib.loads((PROJECT_ROOT / "pyproject.toml").read_text())["project"]
    declared = project["entry-points"]["gymnasium.envs"]
    assert list(declared) == ["swarm"]
    register = EntryPoint("swarm", declared["swarm"], "gymnasium.envs").load()
    gymnasium.registry.pop("swarm/Consensus-v0", None)
    register()
    assert gymnasium.spec("swarm/Consensus-v0").entry_point == "swarm.rl.consensus_env:ConsensusEnv"


# ----------------------------------------------------------------------------- the animation


def test_the_animation_greys_dead_robots_dashes_dropped_links_and_zooms_in(tmp_path):
    """Synthetic run: robot 3 killed at tick 5, link 0-1 down from tick 5; the swarm shrinks to a
    tenth. The last frame shows the dead robot grey and the dropped links red, the first frame
    neither; the view of the last frame is the final cluster's size, not the start's."""
    from PIL import Image

    from swarm.scenarios import report

    count, ticks, body_m = 6, 20, 0.1
    angles = 2 * np.pi * np.arange(count) / count
    shrink = np.linspace(1.0, 0.1, ticks)[:, None]
    poses = np.zeros((ticks, count, 3))
    poses[..., 0], poses[..., 1] = 3 * shrink * np.cos(angles), 3 * shrink * np.sin(angles)
    events = [{"kind": "kill_agent", "robot": 3, "tick": 5, "at_s": 0.25}]
    states = report.robot_states({"faults": {"events": events}}, count, ticks)
    assert states[4].tolist() == [0] * 6 and states[5:, 3].tolist() == [report.KILLED] * 15

    def links_down(n: int, tick: int) -> np.ndarray:
        down = np.zeros((n, n), dtype=bool)
        down[0, 1] = down[1, 0] = tick >= 5
        return down

    cycle = np.roll(np.eye(count), 1, axis=1) + np.roll(np.eye(count), -1, axis=1)
    path = tmp_path / "a.gif"
    times = np.arange(ticks) * 0.05
    report.animation_gif(
        path, times, poses, cycle, None, body_m, states=states, links_down=links_down, title="t"
    )

    def colour_count(frame: int, colour: tuple) -> int:
        with Image.open(path) as gif:
            gif.seek(frame)
            pixels = np.asarray(gif.convert("RGB")).reshape(-1, 3)
        return int(np.sum(np.all(pixels == colour, axis=1)))

    assert colour_count(0, report.DOWN) == 0 and colour_count(0, report.DEAD) == 0
    assert colour_count(ticks - 1, report.DOWN) > 20 and colour_count(ticks - 1, report.DEAD) > 20
    spans = report.view_spans(poses[..., :2], list(range(ticks)), body_m)
    assert spans[0] == pytest.approx(6.0 + 6 * body_m)  # the start: 6 m across
    assert spans[-1] == pytest.approx(max(0.6 + 6 * body_m, 10 * body_m))  # the end: 0.6 m across
    assert np.all(np.diff(spans) <= 1e-12)  # never zooms out


# ----------------------------------------------------------------------------- benchmarks


def test_benchmarks_write_to_out_and_leave_the_committed_results_alone(tmp_path):
    committed = PROJECT_ROOT / "bench" / "results" / "inference.json"
    before = committed.read_bytes()
    command = [sys.executable, str(PROJECT_ROOT / "bench" / "bench_inference.py"), "--calls", "300"]
    result = subprocess.run(
        [*command, "--out", str(tmp_path)], capture_output=True, text=True, timeout=120, cwd=PROJECT_ROOT
    )
    assert result.returncode == 0, result.stderr
    written = json.loads((tmp_path / "inference.json").read_text())
    assert written["overall"]["calls"] == 300
    assert "bench_inference" in result.stderr  # the progress bar
    assert committed.read_bytes() == before
    both = subprocess.run(
        [*command, "--out", str(tmp_path), "--update-results"], capture_output=True, text=True
    )
    assert both.returncode != 0 and "not both" in both.stderr and committed.read_bytes() == before


@pytest.mark.slow
def test_an_interrupted_kinematic_run_ends_with_partial_results(tmp_path):
    scenario = short_scenario(tmp_path, THESIS / "line-local_consensus.yaml", duration=3000.0)
    out = tmp_path / "out"
    run = swarm_run.start(scenario, out, interruptible=True)
    trajectory = out / "trajectory.jsonl"
    deadline = time.monotonic() + 120
    while not (trajectory.exists() and trajectory.read_bytes().count(b"\n") >= 50):
        assert run.poll() is None and time.monotonic() < deadline, run.communicate()
        time.sleep(0.01)
    run.send_signal(signal.SIGINT)
    stdout, stderr = run.communicate(timeout=120)
    assert run.returncode == 130, stderr
    times_s, poses, _ = read_trajectory(trajectory)
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["partial"] is True and outcome["incomplete"].startswith("interrupted (Ctrl-C) after")
    assert outcome["ticks"] == len(times_s) - 1 < 60000
    assert outcome["final_metric"] == pytest.approx(max_pairwise_of(poses)[-1], abs=1e-9)
    assert "PARTIAL: interrupted (Ctrl-C)" in stdout
    assert json.loads((out / "convergence.png.json").read_text())["title"].startswith("PARTIAL: ")


def test_summary_of_one_robot_says_robot(tmp_path, capsys):
    scenario = tmp_path / "one.yaml"
    scenario.write_text(
        "name: one\nrobots: {count: 1}\ntopology: {kind: complete}\ncontroller: {kind: local_consensus}\n"
        "sim: {engine: kinematic, duration_s: 0.5}\n"
    )
    assert main(["run", str(scenario), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.endswith(", 1 robot"), first
