"""Recordings of a run for the tools robotics people use, written from its results directory.

``mcap``: ``recording.mcap`` with ROS 2 messages (CDR, the ``ros2`` profile; ``mcap`` +
``mcap-ros2-support``), which Foxglove opens. Sim time is the log time (tick k at
``k * control_period_s`` after t = 0); every message is in the frame ``world``. Per tick:

    /robots/poses      geometry_msgs/msg/PoseArray          axle-centre poses, robot i at index i
    /robots/markers    visualization_msgs/msg/MarkerArray   each robot's body (cylinder) and id (text);
                                                            dead or hung robots grey
    /graph/edges       visualization_msgs/msg/MarkerArray   graph edges (LINE_LIST): ns "live" grey,
                                                            ns "down" red (link down or a dead end)
    /robot_<i>/cmd_vel geometry_msgs/msg/TwistStamped       robot i's applied command (v, w): from
                                                            the wheel speeds the server applied, or
                                                            (kinematic engine) from its motion
    /metric            std_msgs/msg/Float64                 the success metric (live robots; a task: its own)
and ``/faults`` (std_msgs/msg/String, a JSON object per fault, at the tick it happened) and the run's
``metrics.json`` as MCAP metadata ``outcome``.

``rerun``: ``recording.rrd`` (``rerun-sdk``), the same poses, edges and metric on a ``sim_time``
timeline, when the package is installed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from swarm.core import metrics, tasks

STAMPED = """std_msgs/Header header
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
POSE = """================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
VECTOR3 = """================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""
SCHEMAS = {
    "geometry_msgs/msg/PoseArray": STAMPED.replace(
        "std_msgs/Header header\n", "std_msgs/Header header\nPose[] poses\n", 1
    )
    + POSE,
    "geometry_msgs/msg/TwistStamped": STAMPED.replace(
        "std_msgs/Header header\n", "std_msgs/Header header\nTwist twist\n", 1
    )
    + """================================================================================
MSG: geometry_msgs/Twist
Vector3 linear
Vector3 angular
"""
    + VECTOR3,
    "visualization_msgs/msg/MarkerArray": """Marker[] markers
================================================================================
MSG: visualization_msgs/Marker
int32 ARROW=0
int32 CUBE=1
int32 SPHERE=2
int32 CYLINDER=3
int32 LINE_STRIP=4
int32 LINE_LIST=5
int32 CUBE_LIST=6
int32 SPHERE_LIST=7
int32 POINTS=8
int32 TEXT_VIEW_FACING=9
int32 MESH_RESOURCE=10
int32 TRIANGLE_LIST=11
int32 ADD=0
int32 MODIFY=0
int32 DELETE=2
int32 DELETEALL=3
std_msgs/Header header
string ns
int32 id
int32 type
int32 action
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
std_msgs/ColorRGBA color
builtin_interfaces/Duration lifetime
bool frame_locked
geometry_msgs/Point[] points
std_msgs/ColorRGBA[] colors
string texture_resource
sensor_msgs/CompressedImage texture
UVCoordinate[] uv_coordinates
string text
string mesh_resource
MeshFile mesh_file
bool mesh_use_embedded_materials
"""
    + STAMPED.split("\n", 1)[1]
    + POSE
    + VECTOR3
    + """================================================================================
MSG: std_msgs/ColorRGBA
float32 r
float32 g
float32 b
float32 a
================================================================================
MSG: builtin_interfaces/Duration
int32 sec
uint32 nanosec
================================================================================
MSG: sensor_msgs/CompressedImage
std_msgs/Header header
string format
uint8[] data
================================================================================
MSG: visualization_msgs/UVCoordinate
float32 u
float32 v
================================================================================
MSG: visualization_msgs/MeshFile
string filename
uint8[] data
""",
    "std_msgs/msg/Float64": "float64 data\n",
    "std_msgs/msg/String": "string data\n",
}
"""ROS 2 (Humble) message definitions, each with its dependencies, as Foxglove and ``ros2 bag`` store them."""

FRAME = "world"
CYLINDER, LINE_LIST, TEXT_VIEW_FACING = 3, 5, 9


def _stamp(time_s: float) -> dict:
    nanoseconds = round(time_s * 1e9)
    return {"stamp": {"sec": nanoseconds // 10**9, "nanosec": nanoseconds % 10**9}, "frame_id": FRAME}


def _colour(rgb: tuple[int, int, int], alpha: float = 1.0) -> dict:
    return {"r": rgb[0] / 255, "g": rgb[1] / 255, "b": rgb[2] / 255, "a": alpha}


def _quaternion(theta: float) -> dict:
    return {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2), "w": math.cos(theta / 2)}


def commands(records: list[dict], poses: np.ndarray, dt_s: float, half_axle_m: float) -> np.ndarray:
    """``(T, N, 2)`` command ``(v m/s, w rad/s)`` applied from each tick to the next: from the wheel
    speeds in the trajectory (``v = (vL + vR) / 2``, ``w = (vR - vL) / (2 d)``, thesis eq. 2.4), else from
    the motion between ticks (constant wheel speeds move the axle along an arc: its length is the chord
    ``c`` times ``(dtheta / 2) / sin(dtheta / 2)``; the last tick repeats the one before)."""
    count = poses.shape[1]
    out = np.zeros((len(poses), count, 2))
    wheels = [record.get("wheels") for record in records]
    if wheels and wheels[-1] is None:  # the last tick of a run applies nothing: zero
        wheels[-1] = np.zeros((count, 2))
    if wheels and all(w is not None and np.shape(w) == (count, 2) for w in wheels):
        w = np.asarray(wheels, dtype=float)
        out[..., 0] = 0.5 * (w[..., 0] + w[..., 1])
        out[..., 1] = (w[..., 1] - w[..., 0]) / (2 * half_axle_m)
        return out
    if len(poses) < 2:
        return out
    delta = poses[1:] - poses[:-1]
    turn = (delta[..., 2] + np.pi) % (2 * np.pi) - np.pi
    chord = np.hypot(delta[..., 0], delta[..., 1])
    mid = poses[:-1, :, 2] + turn / 2
    sign = np.sign(np.cos(mid) * delta[..., 0] + np.sin(mid) * delta[..., 1])
    half = turn / 2
    arc = chord * np.where(np.abs(half) > 1e-9, half / np.where(np.abs(half) > 1e-9, np.sin(half), 1.0), 1.0)
    out[:-1, :, 0] = sign * arc / dt_s
    out[:-1, :, 1] = turn / dt_s
    out[-1] = out[-2]
    return out


def _run(out_dir: Path):
    """What a recording is made of, read back from a results directory."""
    from swarm.core.faults import LinkFaults
    from swarm.scenarios.report import KILLED, robot_states
    from swarm.scenarios.results import read_trajectory
    from swarm.scenarios.scenario import load_scenario

    scenario = load_scenario(out_dir / "scenario.yaml")
    times_s, poses, records = read_trajectory(out_dir / "trajectory.jsonl")
    if not len(times_s):
        raise ValueError(f"{out_dir / 'trajectory.jsonl'}: no complete tick to record")
    outcome = json.loads((out_dir / "metrics.json").read_text())
    count = poses.shape[1]
    states = robot_states(outcome, count, len(times_s))
    schedule = LinkFaults.from_scenario(scenario) if scenario.faults else None
    adjacency = scenario.adjacency()
    live = (outcome.get("faults") or {}).get("live_robots") or list(range(count))
    series = tasks.get(scenario.task.kind).series  # a task's own metric (every body), or the success one
    if series is not None:
        values = series(poses[..., :2], scenario.task)
    elif len(live) > 1:
        values = metrics.METRICS[outcome["metric"]](poses[:, live, :2])
    else:
        values = np.zeros(len(times_s))

    def edges(tick: int) -> tuple[list, list]:
        from swarm.core import graphs

        graph = (
            adjacency
            if adjacency is not None
            else graphs.disk(poses[tick, :, :2], scenario.topology.radius_m or 0.0)
        )
        down = schedule.down_matrix(count, tick) if schedule is not None else np.zeros((count, count), bool)
        up: list[tuple[int, int]] = []
        cut: list[tuple[int, int]] = []
        for i, j in zip(*np.nonzero(np.triu(graph)), strict=True):
            broken = down[i, j] or down[j, i] or states[tick, i] == KILLED or states[tick, j] == KILLED
            (cut if broken else up).append((int(i), int(j)))
        return up, cut

    dt_s = scenario.sim.control_period_s
    cmds = commands(records, poses, dt_s, scenario.robot.half_axle_m)
    return scenario, times_s, poses, outcome, states, edges, values, cmds


def write_mcap(out_dir: Path, path: Path | None = None) -> Path:
    """``recording.mcap`` of the run in ``out_dir`` (see the module docstring); returns its path."""
    from mcap_ros2.writer import Writer

    from swarm.scenarios.report import ALIVE, ROBOT_COLOURS, fault_marks

    out_dir = Path(out_dir)
    path = Path(path) if path is not None else out_dir / "recording.mcap"
    scenario, times_s, poses, outcome, states, edges, values, cmds = _run(out_dir)
    count, radius_m = poses.shape[1], scenario.robot.body_radius_m
    grey = (160, 160, 160)
    faults_by_tick: dict[int, list[dict]] = {}
    dt_s = scenario.sim.control_period_s
    for mark in fault_marks(outcome, times_s):
        tick = min(len(times_s) - 1, round(mark["time_s"] / dt_s))
        faults_by_tick.setdefault(tick, []).append(mark)
    with open(path, "wb") as stream, Writer(stream) as writer:
        schemas = {name: writer.register_msgdef(name, text) for name, text in SCHEMAS.items()}
        writer.add_metadata("outcome", {"metrics.json": json.dumps(outcome)})
        for tick, time_s in enumerate(times_s):
            stamp, log_time = _stamp(float(time_s)), round(float(time_s) * 1e9)

            def write(topic: str, schema: str, message: dict, stamp_time: int = log_time) -> None:
                writer.write_message(
                    topic, schemas[schema], message, log_time=stamp_time, publish_time=stamp_time
                )

            pose_list = [
                {"position": {"x": x, "y": y, "z": 0.0}, "orientation": _quaternion(theta)}
                for x, y, theta in poses[tick].tolist()
            ]
            write("/robots/poses", "geometry_msgs/msg/PoseArray", {"header": stamp, "poses": pose_list})
            markers = []
            for robot in range(count):
                alive = states[tick, robot] == ALIVE
                colour = _colour(ROBOT_COLOURS[robot % len(ROBOT_COLOURS)] if alive else grey, 0.8)
                common = {"header": stamp, "id": robot, "action": 0, "frame_locked": False}
                body = {
                    "position": {**pose_list[robot]["position"], "z": 0.05},
                    "orientation": pose_list[robot]["orientation"],
                }
                markers.append(
                    {
                        **common,
                        "ns": "body",
                        "type": CYLINDER,
                        "pose": body,
                        "scale": {"x": 2 * radius_m, "y": 2 * radius_m, "z": 0.1},
                        "color": colour,
                    }
                )
                label = {
                    "position": {**pose_list[robot]["position"], "z": 0.25},
                    "orientation": _quaternion(0.0),
                }
                markers.append(
                    {
                        **common,
                        "ns": "id",
                        "type": TEXT_VIEW_FACING,
                        "pose": label,
                        "scale": {"x": 0.0, "y": 0.0, "z": 0.15},
                        "color": _colour((0, 0, 0)),
                        "text": str(robot) if alive else f"{robot} (dead)",
                    }
                )
            write("/robots/markers", "visualization_msgs/msg/MarkerArray", {"markers": markers})
            edge_markers = []
            for number, (ns, pairs, rgb) in enumerate(
                zip(("live", "down"), edges(tick), ((150, 150, 150), (220, 60, 60)), strict=True)
            ):
                points = [
                    {"x": float(poses[tick, robot, 0]), "y": float(poses[tick, robot, 1]), "z": 0.02}
                    for pair in pairs
                    for robot in pair
                ]
                edge_markers.append(
                    {
                        "header": stamp,
                        "ns": ns,
                        "id": number,
                        "type": LINE_LIST,
                        "action": 0,
                        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": _quaternion(0.0)},
                        "scale": {"x": 0.02, "y": 0.0, "z": 0.0},
                        "color": _colour(rgb),
                        "points": points,
                    }
                )
            write("/graph/edges", "visualization_msgs/msg/MarkerArray", {"markers": edge_markers})
            for robot in range(count):
                v, w = cmds[tick, robot]
                twist = {
                    "linear": {"x": float(v), "y": 0.0, "z": 0.0},
                    "angular": {"x": 0.0, "y": 0.0, "z": float(w)},
                }
                write(
                    f"/robot_{robot}/cmd_vel",
                    "geometry_msgs/msg/TwistStamped",
                    {"header": stamp, "twist": twist},
                )
            write("/metric", "std_msgs/msg/Float64", {"data": float(values[tick])})
            for mark in faults_by_tick.get(tick, []):
                write("/faults", "std_msgs/msg/String", {"data": json.dumps(mark)})
    return path


def write_rerun(out_dir: Path, path: Path | None = None) -> Path:
    """``recording.rrd`` of the run (``rerun-sdk``): robots as points with their ids, graph edges as line
    strips, the metric as a scalar, on the ``sim_time`` timeline."""
    try:
        import rerun as rr
    except ImportError:
        raise ValueError(
            "--record rerun needs the rerun-sdk package (pip install 'gnn-swarm[record]')"
        ) from None
    from swarm.scenarios.report import ALIVE, ROBOT_COLOURS

    out_dir = Path(out_dir)
    path = Path(path) if path is not None else out_dir / "recording.rrd"
    scenario, times_s, poses, _, states, edges, values, _ = _run(out_dir)
    count = poses.shape[1]
    stream = rr.RecordingStream("swarm-" + "".join(ch if ch.isalnum() else "-" for ch in scenario.name))
    stream.save(str(path))
    for tick, time_s in enumerate(times_s):
        stream.set_time("sim_time", duration=float(time_s))
        colours = [
            ROBOT_COLOURS[i % len(ROBOT_COLOURS)] if states[tick, i] == ALIVE else (160, 160, 160)
            for i in range(count)
        ]
        stream.log(
            "world/robots",
            rr.Points2D(
                poses[tick, :, :2],
                radii=scenario.robot.body_radius_m,
                colors=colours,
                labels=[str(i) for i in range(count)],
            ),
        )
        up, cut = edges(tick)
        stream.log("world/edges/live", rr.LineStrips2D([poses[tick, list(pair), :2] for pair in up]))
        stream.log(
            "world/edges/down",
            rr.LineStrips2D([poses[tick, list(pair), :2] for pair in cut], colors=(220, 60, 60)),
        )
        stream.log("metric", rr.Scalars(float(values[tick])))
    stream.flush()
    return path


WRITERS = {"mcap": write_mcap, "rerun": write_rerun}
PACKAGES = {"mcap": ("mcap", "mcap_ros2"), "rerun": ("rerun",)}
"""The modules each format needs (the ``record`` extra: ``pip install 'gnn-swarm[record]'``)."""


def check_formats(formats: list[str]) -> None:
    """Raise ``ValueError`` (one line) when a format's package is not installed: before the run starts."""
    import importlib.util

    for name in formats:
        missing = [module for module in PACKAGES[name] if importlib.util.find_spec(module) is None]
        if missing:
            raise ValueError(
                f"--record {name} needs the {missing[0]} package (pip install 'gnn-swarm[record]')"
            )


def write_recordings(out_dir: Path, formats: list[str]) -> list[Path]:
    """Each recording of ``formats`` (``WRITERS``) of the run in ``out_dir``; their paths."""
    return [WRITERS[name](Path(out_dir)) for name in dict.fromkeys(formats)]
