"""``python -m robot_agent.central``: a centralized controller as ONE process (label: centralized).

``centralized`` (thesis eq. 3.1 on the complete graph), ``centralized_mec`` (full speed toward
the minimum enclosing circle's centre of the current positions, ``swarm.core.experts``) and the
experts of the other tasks (every central kind of ``swarm.sim.controller_kinds`` whose task is not
rendezvous, run as the kinematic engine's own batched form on one swarm: the formation expert ``capt``,
CAPT assignment of the start and time-synchronized drive to the slots; the coverage expert ``lloyd``,
every robot to its Voronoi cell's centroid) need every robot's pose at
tick k, so they cannot run on board the robots: this single process subscribes to
every pose (``swarm/<run>/robot/*/pose``, the one wildcard over robots in the runtime, and the
reason the controller is not decentralized), waits for all poses of tick k, and publishes every
robot's wheel command for tick k. It holds the liveliness token of every robot's controller
(``alive/agent/<i>``), so the sim waits for it as for N agents, and records itself in
``<log-dir>/central.json``. With ``safety`` in the scenario it also hears every robot's sensor reading
(``robot/*/sense``) and filters each robot's command with that robot's reading alone, as the robot's
own agent would (``swarm.core.safety.filter_reading``; a robot without its reading brakes).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from robot_agent.agent import filter_step, take_reading
from swarm.core import safety
from swarm.core.exit_codes import ExitCode
from swarm.core.experts import centralized_mec_velocity, complete_consensus_velocity
from swarm.core.robot import RobotParams, controlled_point, point_velocity_to_wheels
from swarm.runtime import wire
from swarm.runtime.procs import die_with_parent
from swarm.runtime.ticks import step_s_of, tick_limit
from swarm.runtime.usage import EXIT_BAD_INPUT, OneLineArgumentParser, configure_logging, one_line

POSE_DEADLINE_S = 1.0
"""Longest the central controller waits for the rest of a tick's poses once the first one came."""


class CentralController:
    def __init__(self, run: str, connect: list[str], lease_ms: int, startup_timeout_s: float, log_dir):
        self.keys = wire.Keys(run)
        self.connect = connect
        self.lease_ms = lease_ms
        self.startup_timeout_s = startup_timeout_s
        self.log_dir = Path(log_dir) if log_dir else None
        self._cond = threading.Condition()
        self._stop = False
        self._sim_alive: bool | None = None
        self._poses: dict[int, dict[int, wire.Pose]] = {}  # tick -> robot -> pose
        self._readings: dict[int, dict[int, wire.Sensing]] = {}  # tick -> robot -> sensor reading
        self._safety_on = False
        self.filter_counts = dict.fromkeys(safety.FILTER_COUNTS, 0)
        self._last_tick = -1  # the newest tick computed
        self._last_tick_at_s = 0.0  # when it was taken
        self._step_s = 1.0  # swarm.runtime.ticks eq. (1), from the config once fetched
        self._run_key = wire.RunKey.from_env()  # None: authentication off (no SWARM_RUN_KEY)
        self.record: dict = {
            "role": "centralized",
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "run": run,
            "subscriptions": [],
            "liveliness_subscriptions": [],
            "publications": [],
            "liveliness_tokens": [],
            "ticks": 0,
            "authentication": "run key" if self._run_key is not None else "off",
            "poses_invalid": 0,
            "poses_unauthenticated": 0,  # no valid run-key tag: forged
            "config_rejected": 0,
            "poses_old": 0,
            "poses_future": 0,  # beyond its own clock (swarm.runtime.ticks): forged or ahead
            "callback_errors": 0,
            "incomplete_ticks": 0,
            "exit_reason": None,
        }

    def request_stop(self, *_: object) -> None:
        self._stop = True

    def _on_sim_alive(self, sample: zenoh.Sample) -> None:
        with self._cond:
            self._sim_alive = sample.kind == zenoh.SampleKind.PUT
            self._cond.notify_all()

    def _on_pose(self, sample: zenoh.Sample) -> None:
        key_expr = str(sample.key_expr)
        robot = self.keys.robot_of(key_expr, "pose")
        payload = sample.payload.to_bytes()
        run_key = self._run_key
        if run_key is not None and not run_key.check(key_expr, payload, wire.attachment_of(sample)):
            with self._cond:
                self.record["poses_unauthenticated"] += 1
            return
        pose = wire.decode_pose(payload)
        with self._cond:
            if pose is None or robot is None:
                self.record["poses_invalid"] += 1
                return
            if pose.tick <= self._last_tick:
                self.record["poses_old"] += 1  # its tick is computed already: a replay or reordered
                return
            last = self._last_tick
            limit = (
                tick_limit(last, time.perf_counter() - self._last_tick_at_s, self._step_s) if last >= 0 else 0
            )
            if pose.tick > limit:  # would be taken as the next tick and freeze every robot
                self.record["poses_future"] += 1
                return
            self._poses.setdefault(pose.tick, {})[robot] = pose
            self._cond.notify_all()

    def _on_sense(self, sample: zenoh.Sample) -> None:
        key_expr = str(sample.key_expr)
        robot = self.keys.robot_of(key_expr, "sense")
        payload, tag = sample.payload.to_bytes(), wire.attachment_of(sample)
        with self._cond:
            if robot is None:  # not a robot's key of this run
                self.filter_counts["invalid"] += 1
                return
            reading = take_reading(key_expr, payload, tag, self._run_key, self.filter_counts)
            if reading is not None and reading.tick >= self._last_tick:
                self._readings.setdefault(reading.tick, {})[robot] = reading  # may still be waited for
                self._cond.notify_all()

    def _filtered(
        self, tick: int, robots: list[int], poses: np.ndarray, u_world: np.ndarray, params, safe_params
    ):
        """Each robot's command through the barrier filter with its own reading of ``tick`` (waited for
        up to ``POSE_DEADLINE_S``); a robot without one brakes."""
        with self._cond:
            self._wait(
                lambda: len(self._readings.get(tick, {})) >= len(robots),
                time.perf_counter() + POSE_DEADLINE_S,
            )
            readings = self._readings.pop(tick, {})
            for old in [k for k in self._readings if k <= tick]:
                del self._readings[old]
        out = u_world.copy()
        for row, i in enumerate(robots):  # as each robot's own agent filters (robot_agent.agent)
            out[row], _ = filter_step(
                readings.get(i), u_world[row], poses[row, 2], params, safe_params, self.filter_counts
            )
        return out

    def _wait(self, ready, until_s: float) -> bool:
        while not ready():
            remaining = until_s - time.perf_counter()
            if remaining <= 0 or self._stop or self._sim_alive is False:
                return False
            self._cond.wait(min(remaining, 0.1))
        return True

    def run(self) -> int:
        started_s = time.perf_counter()
        session = None
        while session is None and not self._stop and time.perf_counter() - started_s < self.startup_timeout_s:
            try:
                session = zenoh.open(wire.session_config("client", self.connect, (), self.lease_ms))
            except zenoh.ZError:
                time.sleep(0.05)
        if session is None:
            self.record["exit_reason"] = "could not connect"
            self._write_record()
            return ExitCode.NOT_MET
        try:
            return self._run(session, started_s)
        finally:
            session.close()
            self._write_record()

    def _fetch_config(self, session: zenoh.Session, started_s: float) -> wire.AgentConfig | None:
        while not self._stop and time.perf_counter() - started_s < self.startup_timeout_s:
            for reply in session.get(self.keys.config(0), **wire.config_query_options()):
                if reply.ok is not None:
                    payload, key = reply.ok.payload.to_bytes(), self._run_key
                    if key is not None and not key.check(
                        str(reply.ok.key_expr), payload, wire.attachment_of(reply.ok)
                    ):
                        self.record["config_rejected"] += 1  # another answerer than the sim
                        continue
                    return wire.decode_config(payload)
            time.sleep(0.05)
        return None

    def _run(self, session: zenoh.Session, started_s: float) -> int:
        keys, record = self.keys, self.record
        guard = lambda callback: wire.guarded(callback, record, "robot_agent.central")  # noqa: E731
        on_sim_alive = guard(self._on_sim_alive)
        alive_sim = session.liveliness().declare_subscriber(keys.alive_sim, on_sim_alive, history=True)
        entities: list[Any] = [alive_sim]
        record["liveliness_subscriptions"].append(keys.alive_sim)
        config = self._fetch_config(session, started_s)
        if config is None:
            record["exit_reason"] = "no config from the sim"
            return ExitCode.NOT_MET
        count, gain = config.robot_count, config.gain
        from swarm.sim.controller_kinds import CONTROLLER_KINDS

        kind = CONTROLLER_KINDS.get(config.controller)
        if kind is None or not kind.central:
            record["exit_reason"] = f"controller {config.controller!r} is not a central controller"
            return ExitCode.NOT_MET
        mec = config.controller == "centralized_mec"
        spec = config.scenario.get("controller") or {}
        reverse = bool(spec.get("reverse", True))
        record["controller"] = config.controller
        self._step_s = step_s_of(
            {"control_period_s": config.control_period_s, **config.scenario.get("sim", {})}
        )
        params = RobotParams(**config.robot_params)
        expert = None  # another task's expert (capt, lloyd): the kinematic engine's, on one swarm of all
        if kind.task != "rendezvous":
            from swarm.core import tasks
            from swarm.sim.controller_kinds import ControllerArgs, batched_controller

            try:
                task = tasks.parse_section(config.scenario.get("task"))
                args = ControllerArgs.from_spec(
                    spec, params, config.control_period_s, robot_count=count, task=task
                )
                expert = batched_controller(config.controller, args)
                last_poses = np.zeros((count, 3))
            except ValueError as error:
                record["exit_reason"] = f"bad controller: {error}"
                return ExitCode.NOT_MET
        entities.append(session.declare_subscriber(keys.all_poses, guard(self._on_pose)))
        record["subscriptions"].append(keys.all_poses)
        safe_params = None
        if config.scenario.get("safety") is not None:
            safe_params = safety.SafetyParams(**config.scenario["safety"])
            self._safety_on = True
            all_readings = f"{keys.prefix}/robot/*/sense"
            entities.append(session.declare_subscriber(all_readings, guard(self._on_sense)))
            record["subscriptions"].append(all_readings)
        options = wire.publisher_options(config.mode)
        publishers = [session.declare_publisher(keys.cmd(i), **options) for i in range(count)]
        record["publications"] = [keys.cmd(i) for i in range(count)]
        entities += publishers
        for i in range(count):
            entities.append(session.liveliness().declare_token(keys.alive_agent(i)))
            record["liveliness_tokens"].append(keys.alive_agent(i))
        record["ready_s"] = round(time.perf_counter() - started_s, 4)
        try:
            while True:
                last_tick = self._last_tick
                with self._cond:
                    self._wait(lambda last=last_tick: any(k > last for k in self._poses), float("inf"))
                    if self._stop or self._sim_alive is False:
                        record["exit_reason"] = "stopped" if self._stop else "sim gone"
                        return 0
                    tick = min(k for k in self._poses if k > last_tick)
                    self._wait(
                        lambda tick=tick: len(self._poses[tick]) == count,
                        time.perf_counter() + POSE_DEADLINE_S,
                    )
                    got = self._poses.pop(tick)
                    for old in [k for k in self._poses if k <= tick]:
                        del self._poses[old]
                    self._last_tick, self._last_tick_at_s = tick, time.perf_counter()
                robots = sorted(got)
                record["incomplete_ticks"] += len(robots) < count
                poses = np.array([got[i].array() for i in robots])
                if expert is not None:  # capt fixes its slots at its first tick; a missing pose: its last
                    for row, i in enumerate(robots):
                        last_poses[i] = poses[row]
                    full = last_poses[None]
                    points = controlled_point(full, params.offset_m)
                    u_world = expert.act(full, points, None, None)[0][0][robots]
                elif mec:  # centralized_mec: full speed toward the MEC centre of the current positions
                    u_world = centralized_mec_velocity(
                        poses, params.v_max_mps, config.control_period_s, reverse
                    )
                else:
                    u_world = complete_consensus_velocity(controlled_point(poses, params.offset_m), gain)
                if safe_params is not None:
                    u_world = self._filtered(tick, robots, poses, u_world, params, safe_params)
                wheels = point_velocity_to_wheels(u_world, poses[:, 2], params)
                for row, i in enumerate(robots):
                    payload = wire.encode_command(tick, wheels[row])
                    if self._run_key is None:
                        publishers[i].put(payload)
                    else:
                        publishers[i].put(payload, attachment=self._run_key.tag(keys.cmd(i), payload))
                record["ticks"] += 1
        finally:
            for entity in reversed(entities):
                entity.undeclare()

    def _write_record(self) -> None:
        if self.log_dir is None:
            return
        with self._cond:
            self.record["safety_filter"] = dict(self.filter_counts) if self._safety_on else None
        path = self.log_dir / "central.json"
        path.write_text(json.dumps(self.record, indent=2) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = OneLineArgumentParser(
        prog="python -m robot_agent.central",
        description="The centralized expert (eq. 3.1 on the complete graph) as one process for all robots.",
    )
    parser.add_argument("--connect", action="append", help="sim endpoint (default: tcp/127.0.0.1:7447)")
    parser.add_argument("--run", default="run", help="run id (default: run)")
    parser.add_argument("--lease-ms", type=int, default=1000)
    parser.add_argument("--startup-timeout", type=float, default=60.0)
    parser.add_argument("--log-dir", help="write central.json here")
    parser.add_argument("--die-with-parent", action="store_true")
    args = parser.parse_args(argv)
    configure_logging()
    if args.die_with_parent:
        die_with_parent()
    connect = args.connect or ["tcp/127.0.0.1:7447"]
    try:
        if not 0 < args.startup_timeout < float("inf"):
            raise ValueError(f"--startup-timeout must be > 0 seconds, got {args.startup_timeout:g}")
        wire.session_config("client", connect, (), args.lease_ms)  # endpoints of the right form
        central = CentralController(args.run, connect, args.lease_ms, args.startup_timeout, args.log_dir)
        if central.log_dir is not None:
            central.log_dir.mkdir(parents=True, exist_ok=True)
    except (ValueError, OSError, zenoh.ZError) as error:
        print(f"robot_agent.central: error: {one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    signal.signal(signal.SIGTERM, central.request_stop)
    signal.signal(signal.SIGINT, central.request_stop)
    code = central.run()
    if code != 0:
        reason = central.record["exit_reason"]
        if reason == "could not connect":
            reason = f"could not connect to {', '.join(connect)} within {args.startup_timeout:g} s"
        elif reason == "no config from the sim":
            reason = f"no config of run {args.run} from the sim within {args.startup_timeout:g} s"
        print(f"robot_agent.central: error: {reason}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
