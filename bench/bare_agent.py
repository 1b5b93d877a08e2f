"""The floor of a robot agent's per-tick CPU: the same I/O as ``robot_agent``, nothing else.

A bare agent uses only zenoh, msgpack and numpy (no project code at all): a client session to the
sim server's router; it fetches ``swarm/<run>/config/<i>`` once (for its graph neighbours, the
mode, the robot's offset and the run's length), subscribes to its own pose
``swarm/<run>/robot/<i>/pose`` (the real key: it shadows the real agent of robot i) and to its
neighbours' messages, and for every pose, in order, decodes it and every message that came (msgpack), runs
local consensus (thesis eq. 3.1) as a small numpy forward, and puts a message and a command of the
real payload layout and size (msgpack maps ``{v, k, m: 16 bytes}`` and ``{v, k, l, r}``). It never
waits for its neighbours (it uses each one's latest message) and one that falls behind computes the
queued poses after one wake-up: if anything, a cheaper floor than the real agent.

Roles (``--role``):

- ``floor`` (default): it publishes under ``swarm/<run>/floor/<i>/msg`` and ``.../cmd`` (same key
  lengths as ``agent/<i>/msg``; nothing of the real run listens there), so it can run beside the real
  agents of the same run: ``bench/bench_runtime.py`` starts one per robot and compares the CPU per tick
  of both over the same ticks, which holds on a loaded machine where absolute figures do not.
- ``stand-in``: it *is* robot i's agent: the same work on the real keys (``agent/<i>/msg``,
  ``robot/<i>/cmd``, neighbours' ``agent/<j>/msg``), the real publisher settings (lockstep blocks on
  congestion, realtime drops; express) and, declared last as the real agent does, the liveliness
  token ``alive/agent/<i>`` the server waits for: a sim server started alone runs the real run with
  no ``robot_agent`` process (``bench/runtime_limit.py``).
- ``answer``: the lightest agent the server accepts: its pose, the token and a constant command per
  pose (turn on the spot, ``ANSWER_WHEELS_MPS``), no messages, no neighbours: what the server and its
  Zenoh router cost with the agents' work taken away.

Stand-ins and answerers also exit when the sim's token ``alive/sim`` goes (a realtime run may drop
the last pose).

``python bench/bare_agent.py --robots 0-99 --connect tcp/127.0.0.1:7447 --run RUN --log-dir DIR``:
one process per robot, forked from one launcher before any session exists (as ``robot_agent``
does); each writes ``DIR/floor_<i>.json`` (role, ticks, CPU at ready and at exit). It exits after the
run's last tick, on SIGTERM, or when its launcher dies.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import zenoh

POSE_RING = 256
"""Poses buffered (robot_agent keeps 4): the lockstep sim waits for the real agents only, so a bare
agent may fall behind; it computes every pose it got, in order, and must not lose any meanwhile."""
MESSAGE_RING = 8192  # as robot_agent.agent
ANSWER_WHEELS_MPS = (-0.1, 0.1)
"""The ``answer`` role's command (left, right): every robot turns on the spot, so the bodies stay awake
and never touch (starts are 0.4 m apart, bumpers 0.12 m)."""
ROLES = ("floor", "stand-in", "answer")
_PR_SET_PDEATHSIG = 1

SIM_GONE_WAIT_S = 30.0
"""Stand-ins and answerers that computed the last tick wait this long at most for the sim's token to
go before they exit, as ``robot_agent`` does: 100 agents leaving at once would load the server's last
tick."""

_in_loop = False
"""The tick loop runs: the sim's token going sends this process SIGTERM."""
_in_recv = False
"""SIGTERM interrupts only the tick loop's blocking ``recv`` (elsewhere it is remembered: ``_stopping``,
and the loop stops once every pose it already got is computed: a bare agent lagging behind the lockstep
sim had been stopped 4 poses short of the last tick when the sim's token went)."""
_stopping = False
_sim_gone = threading.Event()


class _Stop(BaseException):
    """Raised by the SIGTERM handler into a blocking ``recv``."""


def _stop(*_: object) -> None:
    global _stopping
    _stopping = True
    _sim_gone.set()  # ends the wait after the last tick
    if _in_recv:
        raise _Stop


def _on_sim_alive(sample: zenoh.Sample) -> None:
    """The sim's token went: stop (the handler interrupts the loop's blocking ``recv``)."""
    if sample.kind == zenoh.SampleKind.DELETE:
        _sim_gone.set()
        if _in_loop:
            os.kill(os.getpid(), signal.SIGTERM)


def _config(connect: list[str]) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps(connect))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tx/lease", "1000")
    return config


def _fetch_config(session: zenoh.Session, key: str, deadline_s: float) -> dict | None:
    while time.monotonic() < deadline_s and not _stopping:
        for reply in session.get(key, timeout=1.0):
            if reply.ok is not None:
                return msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
        time.sleep(0.05)
    return None


def run_agent(
    robot: int, run: str, connect: list[str], log_dir: Path, timeout_s: float, role: str = "floor"
) -> int:
    """One bare agent in ``role`` (``ROLES``); returns its exit status (0: it ran to the end or was
    stopped)."""
    global _in_loop, _in_recv
    started_s = time.monotonic()
    signal.signal(signal.SIGTERM, _stop)
    ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)  # die with the launcher
    prefix = f"swarm/{run}"
    record: dict = {"robot": robot, "role": role, "pid": os.getpid(), "ticks": 0}
    path = log_dir / f"floor_{robot}.json"
    session = None
    while session is None and not _stopping and time.monotonic() - started_s < timeout_s:
        try:
            session = zenoh.open(_config(connect))
        except zenoh.ZError:
            time.sleep(0.05)
    if session is None:
        record["exit_reason"] = "could not connect"
        path.write_text(json.dumps(record) + "\n")
        return 1
    try:
        config = _fetch_config(session, f"{prefix}/config/{robot}", started_s + timeout_s)
        if config is None:
            record["exit_reason"] = "no config"
            return 1
        neighbours = list(config["neighbours"])
        offset_m = float(config["robot_params"]["offset_m"])
        half_axle_m = float(config["robot_params"]["half_axle_m"])
        v_max_mps = float(config["robot_params"]["v_max_mps"])
        gain = float(config["gain"])
        final_tick = round(config["scenario"]["sim"]["duration_s"] / config["control_period_s"]) - 1
        congestion = (
            zenoh.CongestionControl.BLOCK if config["mode"] == "lockstep" else zenoh.CongestionControl.DROP
        )
        ring = zenoh.handlers.RingChannel
        out = "floor" if role == "floor" else "agent"  # a stand-in answers on the real keys
        cmd_key = f"{prefix}/floor/{robot}/cmd" if role == "floor" else f"{prefix}/robot/{robot}/cmd"
        if role == "answer":
            neighbours = []
        entities: list = []
        if role != "floor":
            entities.append(session.liveliness().declare_subscriber(f"{prefix}/alive/sim", _on_sim_alive))
        pose_sub = session.declare_subscriber(f"{prefix}/robot/{robot}/pose", ring(POSE_RING))
        msg_subs = [
            session.declare_subscriber(f"{prefix}/{out}/{j}/msg", ring(MESSAGE_RING)) for j in neighbours
        ]
        msg_pub = (
            None
            if role == "answer"
            else session.declare_publisher(
                f"{prefix}/{out}/{robot}/msg", congestion_control=congestion, express=True
            )
        )
        cmd_pub = session.declare_publisher(cmd_key, congestion_control=congestion, express=True)
        if role != "floor":  # last, as robot_agent does: once the sim sees it, everything above is in place
            entities.append(session.liveliness().declare_token(f"{prefix}/alive/agent/{robot}"))
        record.update(neighbours=neighbours, cpu_ready_s=time.process_time())
        path.write_text(json.dumps(record) + "\n")
        state = {"ticks": 0, "tick": -1, "first_tick": None}
        unpackb, packb = msgpack.unpackb, msgpack.packb
        latest: list[bytes | None] = [None] * len(neighbours)
        reason = "done"
        answer_l, answer_r = ANSWER_WHEELS_MPS
        try:
            _in_loop = True
            if _stopping:
                raise _Stop
            while state["tick"] < final_tick:
                _in_recv = True  # before the check: a SIGTERM from here on interrupts the wait
                if _stopping:  # every pose already got is computed
                    raise _Stop
                sample = pose_sub.recv()
                _in_recv = False
                while sample is not None:  # every pose queued, in order: the same work per tick as the sim's
                    pose = unpackb(sample.payload.to_bytes())
                    tick = state["tick"] = pose["k"]
                    if state["first_tick"] is None:
                        state["first_tick"] = tick
                    if role == "answer":
                        cmd_pub.put(packb({"v": 1, "k": tick, "l": answer_l, "r": answer_r}))
                        state["ticks"] += 1
                        sample = pose_sub.try_recv()
                        continue
                    for index, subscriber in enumerate(msg_subs):
                        while (message := subscriber.try_recv()) is not None:
                            latest[index] = unpackb(message.payload.to_bytes())["m"]
                    heard = [raw for raw in latest if raw is not None]
                    theta = pose["th"]
                    c, s = math.cos(theta), math.sin(theta)
                    point = np.array([pose["x"] + offset_m * c, pose["y"] + offset_m * s])
                    if heard:
                        points = np.frombuffer(b"".join(heard), dtype="<f8").reshape(-1, 2)
                        u = -gain * (len(heard) * point - points.sum(axis=0))
                    else:
                        u = np.zeros(2)
                    v, w = c * u[0] + s * u[1], (-s * u[0] + c * u[1]) / offset_m
                    left, right = v - half_axle_m * w, v + half_axle_m * w
                    scale = min(1.0, v_max_mps / max(abs(left), abs(right), 1e-12))
                    msg_pub.put(packb({"v": 1, "k": tick, "m": point.tobytes()}))  # type: ignore[union-attr]
                    cmd_pub.put(
                        packb({"v": 1, "k": tick, "l": float(left * scale), "r": float(right * scale)})
                    )
                    state["ticks"] += 1
                    sample = pose_sub.try_recv()
        except _Stop:
            reason = "stopped"
        finally:
            _in_loop = _in_recv = False
        if reason == "done" and role != "floor":
            _sim_gone.wait(SIM_GONE_WAIT_S)  # idle; SIGTERM ends it too
        for entity in reversed(entities):
            entity.undeclare()
        record.update(ticks=state["ticks"], first_tick=state["first_tick"], last_tick=state["tick"])
        record["exit_reason"] = reason
        return 0
    finally:
        record["cpu_s"] = time.process_time()
        session.close()
        path.write_text(json.dumps(record) + "\n")


def parse_robots(text: str) -> list[int]:
    """``"0-5"`` or ``"0,2,4"`` -> robot ids."""
    robots: list[int] = []
    for part in text.split(","):
        low, _, high = part.partition("-")
        robots += range(int(low), int(high or low) + 1)
    return robots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=parse_robots, required=True, help="robot ids: 0-99 or 0,2,4")
    parser.add_argument("--connect", required=True, help="Zenoh endpoint of the sim server")
    parser.add_argument("--run", required=True, help="run id (the key prefix swarm/<run>/)")
    parser.add_argument("--log-dir", type=Path, required=True, help="write floor_<i>.json here")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds to connect and get the config")
    parser.add_argument("--nice", type=int, default=0, help="niceness added before forking (as robot-agent)")
    parser.add_argument(
        "--role",
        choices=ROLES,
        default="floor",
        help="floor: shadow the real agents on floor/ keys; stand-in: be the agents (real keys, token);"
        " answer: a constant command per pose, nothing else",
    )
    args = parser.parse_args(argv)
    args.log_dir.mkdir(parents=True, exist_ok=True)
    if args.nice:
        os.nice(args.nice)  # the real agents' priority: the floor competes for the cores as they do
    children = []
    sys.stdout.flush()
    sys.stderr.flush()
    for robot in args.robots:  # fork before any session exists (forking after one hangs the child)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                code = run_agent(robot, args.run, [args.connect], args.log_dir, args.timeout, args.role)
            finally:
                os._exit(code)
        children.append(pid)

    def forward(*_: object) -> None:
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)

    signal.signal(signal.SIGTERM, forward)
    worst = 0
    for pid in children:
        while True:
            try:
                _, status = os.waitpid(pid, 0)
                break
            except InterruptedError:
                continue
        worst = max(worst, os.waitstatus_to_exitcode(status) != 0)
    return worst


if __name__ == "__main__":
    sys.exit(main())
