"""The sim server: PyBullet physics of the robots behind Zenoh (docs/design.md, "Processes").

Every control tick k it reads the axle-centre poses, streams them to ``trajectory.jsonl`` and
publishes robot i's pose on ``swarm/<run>/robot/<i>/pose`` (its own key), and with ``safety`` first
its range-sensor reading on ``robot/<i>/sense`` (docs/safety.md); it applies the wheel
commands that came back on ``robot/<i>/cmd`` (saturated again here, for safety) and advances the
physics by one control period.

``lockstep`` (deterministic): after publishing tick k it waits until every *live* agent's command
for tick k has arrived, or ``sim.deadline_s`` has passed, then steps. A command that misses the
deadline is dropped (counted); the robot keeps its last command until ``sim.watchdog_s`` of sim
time without a fresh one, then stops. An agent whose liveliness token disappears (crash, SIGKILL,
lease expiry of a frozen process or a cut network link) is not waited for and its robot stops at
the next tick; when a token of that robot appears again (a restarted agent, a thawed one, the link
back) the server waits for its commands again from the next tick on.

``realtime``: physics runs on the wall clock, one control period per period of wall time: the poses
of tick k go out at its wall-clock boundary ``k * period``; the latest command of each robot applies
from tick k to k+1 (the server steps as soon as every live agent's command of tick k is in, else at
boundary k+1 with what it has); a robot without a fresh command for ``sim.watchdog_s`` of wall
time, or whose agent died, stops.

The server also answers ``swarm/<run>/config/<i>`` queries with robot i's configuration
(``swarm.runtime.wire.AgentConfig``: scenario, robot parameters, graph neighbours, controller, policy
file) and holds the liveliness token ``swarm/<run>/alive/sim``; agents exit when it goes away
(for good: ``sim.server_lost_s``). A command that does not decode (``swarm.runtime.wire``) is dropped and
counted as invalid, one whose tick is not newer than the last accepted from that robot as old.
With a run key (``ServerOptions.run_key``, from ``SWARM_RUN_KEY``) it tags every pose and config
reply and counts a command without a valid tag as unauthenticated (``swarm.runtime.wire.RunKey``). In
lockstep an agent whose token is up but whose command missed ``HUNG_AFTER_DEADLINES`` deadlines in a
row is *hung*: not waited for until it answers again (``hung`` and ``answering`` agent events).
Each ``trajectory.jsonl`` line also carries ``wheels``: the (saturated) wheel speeds applied from
that tick to the next, so the controller's timing can be checked after the run. Per-tick statistics
(ticks served, command latency) go to ``server_stats.json``, with, per robot, the ticks without a
command of that tick, the ticks its agent was gone, and the sim times its agent went and came back;
the file is rewritten every ``STATS_EVERY_S`` while the run goes on (a killed server leaves it), with
``contacts``: the robot-robot and robot-obstacle pairs PyBullet found touching at any substep of a tick.
"""

from __future__ import annotations

import itertools
import json
import logging
import math
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from sim_server.physics import PhysicsWorld
from sim_server.radio import Radio
from swarm.core.exit_codes import ExitCode
from swarm.core.faults import LinkFaults, message_max_age_ticks, tick_of
from swarm.core.files import write_atomically
from swarm.core.obstacles import Capsules
from swarm.core.robot import controlled_point, saturate_wheels
from swarm.runtime import wire
from swarm.runtime.agent_config import agent_configs
from swarm.scenarios.results import TrajectoryWriter, prepare_results_dir
from swarm.scenarios.scenario import Scenario
from swarm.sim.sensing import robot_reading, sense

log = logging.getLogger(__name__)

EXIT_DONE, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = (
    ExitCode.SUCCESS,
    ExitCode.NOT_MET,
    ExitCode.BAD_INPUT,
    ExitCode.INTERRUPTED,
)

TRAJECTORY_FLUSH_S = 0.1
"""Trajectory lines are batched and written at most this long after the oldest (every tick when the
scenario has process faults: the runner follows the server's progress in the file to time them)."""

HUNG_AFTER_DEADLINES = 3
"""lockstep: an agent whose token is up but whose command missed this many deadlines in a row is
*hung*: the server stops waiting for it (its robot keeps its last command for ``sim.watchdog_s``,
then stops) until a command of it comes again; both are agent events (``hung``, ``answering``) in
``server_stats.json``."""

SILENT_SPAN_MIN_TICKS = HUNG_AFTER_DEADLINES
"""A run of at least this many ticks in a row without a command of a robot is kept in ``silent_spans``
of ``server_stats.json`` (robot, first tick, length; ``to_end``: still silent when the run ended), which
``swarm.runtime.health`` judges (an agent that froze or died). At most ``SILENT_SPANS_KEPT`` are kept."""

SILENT_SPANS_KEPT = 1000

STATS_EVERY_S = 1.0
"""While the run goes on, ``server_stats.json`` is rewritten (atomically) at the first tick and then
at most this often, so a killed server still leaves its counters of a moment ago."""


@dataclass
class ServerOptions:
    run: str
    out_dir: Path
    listen: list[str]
    connect: list[str] = field(default_factory=list)
    zenoh_mode: str = "router"
    lease_ms: int = 1000
    startup_timeout_s: float = 60.0
    policy: bytes | None = None
    quiet: bool = False
    zenoh_settings: dict = field(default_factory=dict)  # more session settings (swarm.runtime.acl)
    run_key: wire.RunKey | None = None  # tags poses and configs, checks commands (None: off)
    ros2: bool = False  # also a ROS 2 face: odom, cmd_vel, /clock (sim_server.ros2_face, docs/ros2.md)


def _percentiles_ms(samples_s: list[float]) -> dict[str, float | int | None]:
    if not samples_s:
        return {"count": 0, "p50": None, "p90": None, "p99": None, "max": None, "mean": None}
    values = np.asarray(samples_s) * 1e3
    p50, p90, p99 = np.percentile(values, [50, 90, 99])
    return {
        "count": len(values),
        "p50": round(float(p50), 4),
        "p90": round(float(p90), 4),
        "p99": round(float(p99), 4),
        "max": round(float(values.max()), 4),
        "mean": round(float(values.mean()), 4),
    }


LATE_BINS = ((0, 0), (1, 1), (2, 4), (5, 19), (20, None))
"""Bins of :func:`_late_histogram`: agents whose command of a tick was not in when the server stepped."""


def _late_histogram(late_per_tick: list[int]) -> dict[str, int]:
    """Ticks by how many agents' commands were missing at the step ("0", "1", "2-4", "5-19", "20+")."""
    out = {}
    for low, high in LATE_BINS:
        name = str(low) if high == low else f"{low}+" if high is None else f"{low}-{high}"
        out[name] = sum(1 for n in late_per_tick if n >= low and (high is None or n <= high))
    return out


LATENCY_BINS_MS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0)
"""Lower edges of the command-latency histogram (``latency_histogram_ms``; the last bin is open)."""


def _latency_histogram_ms(samples_s: list[float]) -> dict[str, int]:
    """Commands by latency (pose published -> command received), bins ``"lo-hi"`` ms, last ``"256+"``."""
    counts = np.histogram(np.asarray(samples_s) * 1e3, bins=[*LATENCY_BINS_MS, np.inf])[0]
    names = [f"{lo:g}-{hi:g}" for lo, hi in itertools.pairwise(LATENCY_BINS_MS)]
    return dict(zip([*names, f"{LATENCY_BINS_MS[-1]:g}+"], counts.tolist(), strict=True))


class SimServer:
    """One run of the sim server; :meth:`serve` returns the process exit status."""

    def __init__(self, scenario: Scenario, options: ServerOptions):
        self.scenario = scenario
        self.options = options
        self.keys = wire.Keys(options.run)
        self.count = scenario.robots.count
        self.dt_s = scenario.sim.control_period_s
        self._configs = [wire.encode_config(c) for c in agent_configs(scenario, options.run, options.policy)]
        key = options.run_key
        self._config_tags = (
            None if key is None else [key.tag(self.keys.config(i), c) for i, c in enumerate(self._configs)]
        )
        self._pose_keys = [self.keys.pose(i) for i in range(self.count)]
        self._sense_keys = [self.keys.sense(i) for i in range(self.count)]
        self._obstacles = Capsules(scenario.obstacles)
        safety = scenario.safety
        self._sense_rng = None if safety is None else np.random.default_rng(safety.seed)
        self._contacts = {"robot_robot": 0, "robot_obstacle": 0, "ticks": 0}
        self._sense_publishers: list = []
        self._radio, self._msg_dim = self._make_radio(scenario, options)
        self._inbox_keys = [self.keys.inbox(i) for i in range(self.count)]
        self._inbox_publishers: list = []
        self._msg_fresh: set[int] = set()  # lockstep, disk graph: robots whose message of this tick is in
        self._hung: set[int] = set()  # lockstep: live agents not waited for (HUNG_AFTER_DEADLINES)
        self._missed_in_row = np.zeros(self.count, dtype=int)
        self._robot_of_cmd = {self.keys.cmd(i): i for i in range(self.count)}
        self._cond = threading.Condition()
        self._stop = False
        self._tick = -1
        self._alive: set[int] = set()
        self._tokens: dict[int, set[str]] = {}  # robot -> the liveliness tokens of its controller now up
        self.ros2_face: Any = None  # sim_server.ros2_face.Ros2Face with --ros2
        self._expected: set[int] = set()  # live agents when this tick's poses went out: waited for
        self._seen: set[int] = set()  # robots whose agent was alive at some point
        self._started_s = time.perf_counter()
        self._ticks_without_command = np.zeros(self.count, dtype=int)
        self._ticks_dead = np.zeros(self.count, dtype=int)
        self._cmds: dict[int, tuple[wire.Command, float]] = {}  # lockstep: this tick's; realtime: latest
        self._fresh: set[int] = set()  # robots whose command of the current tick is in
        self._published_at_s: dict[int, float] = {}
        self.applied_wheels = np.zeros((self.count, 2))  # saturated wheel speeds applied now (m/s)
        self._encoder = wire.PoseEncoder(self.count)  # pose payloads packed into buffers made once
        self._timing = {"publish": [0.0, 0.0], "trajectory": [0.0, 0.0]}  # part -> [wall s, CPU s]
        self._newest_cmd_tick: dict[int, int] = {}  # robot -> tick of the newest command accepted
        self._stats_written_s = -math.inf  # written at the first tick: a server killed early leaves it too
        self._back_ticks: dict[int, list[int]] = {}  # robot -> ticks of its "back" events (a new token)
        self._restart_ticks: dict[int, list[int]] = {}  # lockstep: robot -> ticks of its restart_agent faults
        for fault in scenario.faults:
            if fault.kind == "restart_agent" and fault.robot is not None:
                self._restart_ticks.setdefault(fault.robot, []).append(tick_of(fault.at_s or 0.0, self.dt_s))
        self._restarts_given_up = np.zeros(self.count, dtype=int)
        self._silent_from = np.full(self.count, -1)  # first tick of a robot's current run without a command
        self._ticks_tracked = 0  # ticks given to _track_silence
        self.stats: dict[str, Any] = {
            "authentication": "run key" if key is not None else "off",
            "access_control": "transport/auth/usrpwd" in options.zenoh_settings,  # swarm.runtime.acl
            "invalid_commands": 0,
            "unauthenticated_commands": 0,
            "late_commands": 0,
            "future_commands": 0,
            "old_commands": 0,
            "callback_errors": 0,
            "accepted_commands": 0,
            "config_queries": 0,
            "agent_events": [],
            "silent_spans": [],
            "contacts": self._contacts,  # (pair, tick) touches in PyBullet, any substep (docs/safety.md)
        }
        if self._radio is not None:  # a disk graph: the server relays the messages (sim_server.radio)
            self.stats["radio"] = {
                "radius_m": self._radio.radius_m,
                "messages_in": 0,
                "invalid_messages": 0,
                "unauthenticated_messages": 0,
                "future_messages": 0,
                "relayed": 0,
                **dict.fromkeys(wire.INBOX_COUNTS, 0),
            }

    @staticmethod
    def _make_radio(scenario: Scenario, options: ServerOptions) -> tuple[Radio | None, int]:
        """The radio of a disk graph run by robot agents (a central kind hears every pose: none), and
        the length of the agents' messages (that of robot 0's onboard controller)."""
        from swarm.core import tasks
        from swarm.sim.controller_kinds import controller_kind, robot_controller

        if not scenario.topology.proximity or controller_kind(scenario.controller.kind).central:
            return None, 0
        data = scenario.model_dump(mode="json")
        controller = robot_controller(
            scenario.controller.kind,
            scenario.robot,
            scenario.controller.gain,
            options.policy,
            scenario.robots.count,
            scenario.sim.control_period_s,
            data["controller"],
            tasks.parse_section(data.get("task")),
            0,
        )
        faults = LinkFaults.from_scenario_dict(data)
        max_age = message_max_age_ticks({"mode": scenario.sim.mode, **data["sim"]})
        assert scenario.topology.radius_m is not None  # a proximity topology has one
        return Radio(
            scenario.robots.count, scenario.topology.radius_m, faults, max_age
        ), controller.message_dim

    # ------------------------------------------------------------------ callbacks (zenoh threads)
    def _on_cmd(self, sample: zenoh.Sample) -> None:
        now_s = time.perf_counter()
        key_expr = str(sample.key_expr)
        robot = self._robot_of_cmd.get(key_expr)
        payload = sample.payload.to_bytes()
        run_key = self.options.run_key
        if run_key is not None and not run_key.check(key_expr, payload, wire.attachment_of(sample)):
            with self._cond:
                self.stats["unauthenticated_commands"] += 1
            return
        self._accept_command(robot, wire.decode_command(payload), now_s)

    def _on_msg(self, sample: zenoh.Sample) -> None:
        """An agent's message (a disk graph: the radio relays it, ``sim_server.radio``)."""
        key_expr = str(sample.key_expr)
        robot = self.keys.robot_of(key_expr, "msg")
        payload = sample.payload.to_bytes()
        run_key = self.options.run_key
        radio, counts = self._radio, self.stats["radio"]
        assert radio is not None
        if run_key is not None and not run_key.check(key_expr, payload, wire.attachment_of(sample)):
            with self._cond:
                counts["unauthenticated_messages"] += 1
            return
        decoded = wire.decode_message_values(payload, self._msg_dim)
        with self._cond:
            if decoded is None or robot is None or robot >= self.count:
                counts["invalid_messages"] += 1
                return
            tick, values = decoded
            if tick > self._tick:
                counts["future_messages"] += 1
                return
            counts["messages_in"] += 1
            radio.offer(robot, tick, np.asarray(values, dtype=np.float64))
            if tick == self._tick:
                self._msg_fresh.add(robot)
                if self._all_fresh():
                    self._cond.notify_all()

    def _accept_command(self, robot: int | None, cmd: wire.Command | None, now_s: float) -> None:
        """A decoded command of ``robot`` (None: invalid) from the project's keys or ROS 2's cmd_vel."""
        with self._cond:
            if cmd is None or robot is None:
                self.stats["invalid_commands"] += 1
                return
            if robot in self._hung:  # it answers again: waited for from the next tick on
                self._hung.discard(robot)
                self._event(robot, "answering")
            lockstep = self.scenario.sim.mode == "lockstep"
            if cmd.tick > self._tick:
                self.stats["future_commands"] += 1
                return
            if cmd.tick <= self._newest_cmd_tick.get(robot, -1):
                self.stats["old_commands"] += 1  # not newer than one accepted: a replay or reordered
                return
            if lockstep and cmd.tick < self._tick:
                self.stats["late_commands"] += 1
                return
            self._cmds[robot] = (cmd, now_s)
            self._newest_cmd_tick[robot] = cmd.tick
            self.stats["accepted_commands"] += 1
            if cmd.tick == self._tick:
                self._fresh.add(robot)
                if self._all_fresh():  # wake the main thread once per tick, not once per command
                    self._cond.notify_all()

    def _all_fresh(self) -> bool:
        """Every expected agent's command of the current tick is in (lock held). An agent that
        (re)joined after this tick's poses went out is waited for from the next tick on."""
        if self._radio is not None and not self._expected.issubset(self._msg_fresh):
            return False  # a disk graph: the radio needs every expected message of this tick too
        return len(self._fresh) >= len(self._expected) and self._expected.issubset(self._fresh)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        robot = self.keys.robot_of(str(sample.key_expr), "alive")
        if robot is None or robot >= self.count:
            return
        self._agent_token(robot, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    def _agent_token(self, robot: int, token: str, put: bool) -> None:
        """A token of robot ``robot``'s controller came (``put``) or went: its agent's, or with
        ``--ros2`` a ROS 2 publisher's on its cmd_vel. The controller is alive while any is up."""
        with self._cond:
            tokens = self._tokens.setdefault(robot, set())
            was_up = bool(tokens)
            (tokens.add if put else tokens.discard)(token)
            if bool(tokens) == was_up:
                return
            if put:
                event = "back" if robot in self._seen else "alive"
                if event == "back":
                    self._back_ticks.setdefault(robot, []).append(self._tick)
                self._alive.add(robot)
                self._seen.add(robot)
            else:
                self._alive.discard(robot)
                self._expected.discard(robot)
                self._hung.discard(robot)
                event = "gone"
            self._event(robot, event)
            self._cond.notify_all()

    def _event(self, robot: int, event: str) -> None:
        """An agent event (lock held): alive, gone, back, hung, answering."""
        self.stats["agent_events"].append(
            {
                "robot": robot,
                "event": event,
                "tick": self._tick,
                "time_s": round(max(self._tick, 0) * self.dt_s, 9),
                "wall_s": round(time.perf_counter() - self._started_s, 4),
            }
        )

    def _on_query(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        robot = self.keys.robot_of(key, "config")
        last = key.rsplit("/", 1)[-1]
        if robot is None and last.isdigit() and len(last) <= 6:  # a wildcard query, e.g. swarm/*/config/3
            robot = int(last)
            if robot < self.count and not query.key_expr.intersects(zenoh.KeyExpr(self.keys.config(robot))):
                return  # not about this run's keys
        with self._cond:
            self.stats["config_queries"] += 1
        if robot is None or robot >= self.count:
            query.reply_err(f"no robot {robot} in this run of {self.count} robots".encode())
            return
        if self._config_tags is None:
            query.reply(self.keys.config(robot), self._configs[robot])
        else:
            query.reply(self.keys.config(robot), self._configs[robot], attachment=self._config_tags[robot])

    # ------------------------------------------------------------------ main thread
    def request_stop(self, *_: object) -> None:
        self._stop = True  # read by the main loop; waits are sliced so it reacts within 0.1 s

    def _log(self, text: str) -> None:
        if not self.options.quiet:
            log.info("sim_server: %s", text)

    def _wait(self, ready, until_s: float) -> bool:
        """Wait (lock held by the caller) until ``ready()`` or the deadline or a stop request."""
        while not ready():
            remaining = until_s - time.perf_counter()
            if remaining <= 0 or self._stop:
                return False
            self._cond.wait(min(remaining, 0.1))
        return True

    def serve(self) -> int:
        scenario, options = self.scenario, self.options
        sim = scenario.sim
        prepare_results_dir(options.out_dir, scenario)
        started_s = self._started_s = time.perf_counter()
        world = PhysicsWorld(
            scenario.robot,
            scenario.initial_poses(),
            sim.physics_hz,
            sim.solver_iterations,
            obstacles=tuple(spec.capsule() for spec in scenario.obstacles),
            count_contacts=True,
        )
        config = wire.session_config(
            options.zenoh_mode, options.connect, options.listen, options.lease_ms, options.zenoh_settings
        )
        outcome: int = EXIT_FAILED
        try:
            with zenoh.open(config) as session:
                token = session.liveliness().declare_token(self.keys.alive_sim)
                guard = lambda callback: wire.guarded(callback, self.stats, "sim_server")  # noqa: E731
                queryable = session.declare_queryable(self.keys.all_configs, guard(self._on_query))
                cmd_sub = session.declare_subscriber(self.keys.all_cmds, guard(self._on_cmd))
                alive_sub = session.liveliness().declare_subscriber(
                    self.keys.all_alive_agents, guard(self._on_alive), history=True
                )
                stream = wire.publisher_options(sim.mode)
                publishers = [
                    session.declare_publisher(self.keys.pose(i), **stream) for i in range(self.count)
                ]
                if scenario.safety is not None:  # each robot's range sensor, on a key of its own
                    self._sense_publishers = [
                        session.declare_publisher(key, **stream) for key in self._sense_keys
                    ]
                msg_sub = None
                if self._radio is not None:  # a disk graph: the radio hears every agent, tells each its own
                    msg_sub = session.declare_subscriber(self.keys.all_msgs, guard(self._on_msg))
                    self._inbox_publishers = [
                        session.declare_publisher(key, **stream) for key in self._inbox_keys
                    ]
                if options.ros2:
                    from sim_server.ros2_face import Ros2Face

                    self.ros2_face = Ros2Face(self, session, stream)
                self._log(f"run {options.run}: {self.count} robots, listening on {options.listen}")
                with self._cond:
                    everyone = self._wait(
                        lambda: len(self._alive) == self.count, started_s + options.startup_timeout_s
                    )
                    alive_at_start = len(self._alive)
                self.stats["startup_s"] = time.perf_counter() - started_s
                self.stats["agents_ready_unix_s"] = (
                    time.time()
                )  # the runner's start-up clock is the wall clock
                self.stats["cpu_ready_s"] = time.process_time()
                self.stats["main_thread_cpu_ready_s"] = time.thread_time()
                if not everyone:
                    why = "interrupted" if self._stop else f"after {options.startup_timeout_s:g} s"
                    self._log(f"only {alive_at_start} of {self.count} agents came up ({why})")
                    outcome = EXIT_INTERRUPTED if self._stop else EXIT_FAILED
                else:
                    self._log(f"all {self.count} agents alive after {self.stats['startup_s']:.2f} s")
                    loop = self._lockstep if sim.mode == "lockstep" else self._realtime
                    outcome = loop(world, publishers)
                radio_entities = [] if msg_sub is None else [msg_sub, *self._inbox_publishers]
                for entity in (
                    alive_sub,
                    cmd_sub,
                    queryable,
                    token,
                    *publishers,
                    *self._sense_publishers,
                    *radio_entities,
                ):
                    entity.undeclare()
                if self.ros2_face is not None:
                    self.ros2_face.undeclare()
        finally:
            world.close()
            self.stats["wall_s"] = time.perf_counter() - started_s
            self.stats["cpu_s"] = time.process_time()  # every thread of this process, since it started
            self.stats["main_thread_cpu_s"] = time.thread_time()
            self._write_stats(outcome)
        return outcome

    def _publish(self, publishers: list, tick: int, poses: np.ndarray) -> None:
        start_s, start_cpu_s = time.perf_counter(), time.thread_time()
        time_s = tick * self.dt_s
        with self._cond:
            self._tick = tick
            self._expected = self._alive - self._hung
            self._fresh.clear()
            self._msg_fresh.clear()
            if self.scenario.sim.mode == "lockstep":
                self._cmds.clear()
            self._published_at_s[tick] = time.perf_counter()
        run_key = self.options.run_key
        if self._radio is not None:  # before the poses, as the sensing: in when the pose comes
            self._publish_inboxes(tick, poses, run_key)
        if self._sense_publishers:  # before the poses: an agent has its reading when its pose comes
            self._publish_sensing(tick, poses, run_key)
        payloads = self._encoder.encode(tick, time_s, poses.tolist())
        if run_key is None:
            for publisher, payload in zip(publishers, payloads, strict=True):
                publisher.put(payload)
        else:
            for publisher, key, payload in zip(publishers, self._pose_keys, payloads, strict=True):
                publisher.put(payload, attachment=run_key.tag(key, payload))
        if self.ros2_face is not None:
            self.ros2_face.publish(time_s, poses)
        self._add_time("publish", start_s, start_cpu_s)

    def _publish_inboxes(self, tick: int, poses: np.ndarray, run_key: wire.RunKey | None) -> None:
        """Robot i's inbox of this tick on its own key (``sim_server.radio``); then this tick's disk
        graph, from the poses going out now."""
        radio, counts = self._radio, self.stats["radio"]
        assert radio is not None
        with self._cond:  # the zenoh threads add messages under the lock
            inboxes = [radio.inbox(i, tick) for i in range(self.count)]
            radio.positions(tick, poses[:, :2])
        for publisher, key, (senders, messages, lost) in zip(
            self._inbox_publishers, self._inbox_keys, inboxes, strict=True
        ):
            values = np.array(messages, dtype=np.float64).reshape(len(senders), self._msg_dim)
            payload = wire.encode_inbox(tick, senders, [1.0] * len(senders), values, lost)
            counts["relayed"] += len(senders)
            for name, number in zip(wire.INBOX_COUNTS, lost, strict=True):
                counts[name] += number
            if run_key is None:
                publisher.put(payload)
            else:
                publisher.put(payload, attachment=run_key.tag(key, payload))

    def _publish_sensing(self, tick: int, poses: np.ndarray, run_key: wire.RunKey | None) -> None:
        """Robot i's range-sensor reading of this tick on its own key (``swarm.sim.sensing`` from the
        exact PyBullet poses, with the scenario's noise and dropout from a generator seeded once)."""
        safety = self.scenario.safety
        assert safety is not None
        readings = sense(
            poses[None],
            controlled_point(poses[None], self.scenario.robot.offset_m),
            self._obstacles,
            safety.sensing_radius_m,
            safety.noise_m,
            safety.dropout,
            self._sense_rng,
        )
        for i, (publisher, key) in enumerate(zip(self._sense_publishers, self._sense_keys, strict=True)):
            payload = wire.encode_sensing(tick, *robot_reading(readings, i))
            if run_key is None:
                publisher.put(payload)
            else:
                publisher.put(payload, attachment=run_key.tag(key, payload))

    def _add_time(self, part: str, start_s: float, start_cpu_s: float) -> None:
        spent = self._timing[part]
        spent[0] += time.perf_counter() - start_s
        spent[1] += time.thread_time() - start_cpu_s

    def _timing_stats(self, steps: int) -> dict[str, float]:
        """Wall and main-thread CPU ms per tick of publishing the poses and writing the trajectory."""
        out = {}
        for part, (wall_s, cpu_s) in self._timing.items():
            out[f"{part}_ms_per_tick"] = 1e3 * wall_s / max(steps, 1)
            out[f"{part}_cpu_ms_per_tick"] = 1e3 * cpu_s / max(steps, 1)
        return out

    def _apply_and_step(self, world, trajectory, tick: int, poses, wheels) -> tuple[float, float]:
        """Saturate and apply the wheels of tick k, log the tick, advance physics one control
        period; returns the physics step's wall and CPU seconds."""
        wheels = saturate_wheels(wheels, self.scenario.robot.v_max_mps)
        start_s, start_cpu_s = time.perf_counter(), time.thread_time()
        trajectory.write(tick, tick * self.dt_s, poses, wheels=wheels.tolist())
        self._add_time("trajectory", start_s, start_cpu_s)
        world.set_wheel_speeds(wheels)
        self.applied_wheels = wheels
        start_s, start_cpu_s = time.perf_counter(), time.thread_time()
        world.step(self.dt_s)
        robots, walls = world.take_contacts()
        self._contacts["robot_robot"] += len(robots)
        self._contacts["robot_obstacle"] += len(walls)
        self._contacts["ticks"] += bool(robots or walls)
        return time.perf_counter() - start_s, time.thread_time() - start_cpu_s

    def _trajectory(self) -> TrajectoryWriter:
        flush_every_s = 0.0 if self.scenario.faults else TRAJECTORY_FLUSH_S
        return TrajectoryWriter(self.options.out_dir / "trajectory.jsonl", flush_every_s)

    def _lockstep(self, world: PhysicsWorld, publishers: list) -> int:
        sim = self.scenario.sim
        steps = self.scenario.steps
        wheels = np.zeros((self.count, 2))
        last_fresh_tick = np.zeros(self.count, dtype=int)
        watchdog_ticks = max(1, math.ceil(sim.watchdog_s / self.dt_s - 1e-9))
        served, latencies_s, missed_by_robot = 0, [], np.zeros(self.count, dtype=int)
        physics_s, physics_cpu_s = 0.0, 0.0
        start_s = time.perf_counter()
        tick_walls_s: list[float] = []  # publish to publish: the median is the expected tick (health)
        tick_started_s = start_s
        with self._trajectory() as trajectory:
            for tick in range(steps + 1):
                poses = world.poses()
                if tick:
                    tick_walls_s.append(time.perf_counter() - tick_started_s)
                tick_started_s = time.perf_counter()
                if tick == steps:
                    trajectory.write(tick, tick * self.dt_s, poses)
                    break
                if self._stop:
                    return EXIT_INTERRUPTED
                self._wait_for_restarted(tick)
                self._publish(publishers, tick, poses)
                deadline_s = self._published_at_s[tick] + sim.deadline_s
                with self._cond:
                    all_in = self._wait(self._all_fresh, deadline_s)  # lockstep takes this tick's only
                    cmds, alive = dict(self._cmds), set(self._alive)
                if self._stop:
                    return EXIT_INTERRUPTED
                served += all_in
                for i in range(self.count):
                    if i in cmds:
                        command, arrived_s = cmds[i]
                        wheels[i] = (command.left_mps, command.right_mps)
                        last_fresh_tick[i] = tick
                        latencies_s.append(arrived_s - self._published_at_s[tick])
                    elif i not in alive or tick - last_fresh_tick[i] >= watchdog_ticks:
                        wheels[i] = 0.0
                    if i in alive and i not in cmds:
                        missed_by_robot[i] += 1
                self._count_hung(cmds, alive)
                self._count_robot_ticks(cmds, alive)
                self._track_silence(tick, set(cmds))
                del self._published_at_s[tick]
                step_wall_s, step_cpu_s = self._apply_and_step(world, trajectory, tick, poses, wheels)
                physics_s += step_wall_s
                physics_cpu_s += step_cpu_s
                self._write_stats_now_and_then(tick)
        self.stats.update(
            ticks=steps,
            ticks_served=served,
            ticks_missed=steps - served,
            missed_commands_by_robot=missed_by_robot.tolist(),
            tick_wall_ms=_percentiles_ms(tick_walls_s),
            latency_ms=_percentiles_ms(latencies_s),
            latency_histogram_ms=_latency_histogram_ms(latencies_s),
            physics_ms_per_tick=1e3 * physics_s / max(steps, 1),
            physics_cpu_ms_per_tick=1e3 * physics_cpu_s / max(steps, 1),
            **self._timing_stats(steps),
        )
        loop_wall_s = time.perf_counter() - start_s
        self.stats.update(loop_wall_s=loop_wall_s, realtime_factor=steps * self.dt_s / loop_wall_s)
        return EXIT_DONE

    def _realtime(self, world: PhysicsWorld, publishers: list) -> int:
        sim = self.scenario.sim
        steps = self.scenario.steps
        wheels = np.zeros((self.count, 2))
        applied_tick = np.full(self.count, -1)
        last_fresh_s = np.full(self.count, -math.inf)
        served, latencies_s, overruns = 0, [], 0
        publish_lags_s, slowest_s, late_per_tick = [], [], []
        physics_s, physics_cpu_s = 0.0, 0.0
        start_s = time.perf_counter()
        with self._trajectory() as trajectory:
            for tick in range(steps + 1):
                tick_s = start_s + tick * self.dt_s  # the wall-clock boundary of this tick
                with self._cond:
                    self._wait(lambda: False, tick_s)  # its poses go out at its boundary, not before
                if self._stop:
                    return EXIT_INTERRUPTED
                overruns += time.perf_counter() > tick_s + 0.5 * self.dt_s
                poses = world.poses()
                if tick == steps:
                    trajectory.write(tick, tick * self.dt_s, poses)
                    break
                self._publish(publishers, tick, poses)
                publish_lags_s.append(self._published_at_s[tick] - tick_s)
                with self._cond:
                    # Step as soon as every live agent's command of this tick is in (the same commands
                    # as at the boundary, computed early), else at the next boundary with the latest.
                    # (Stepping one step's time before it, so that the next poses go out on their
                    # boundary, served fewer ticks: 31-89% against 70-97% at N = 30 under load.)
                    self._wait(self._all_fresh, tick_s + self.dt_s)
                    cmds, alive = dict(self._cmds), set(self._alive)
                if self._stop:
                    return EXIT_INTERRUPTED
                now_s = time.perf_counter()
                fresh, slowest = 0, 0.0
                commanded = set()  # a command newer than the one applied came
                for i in range(self.count):
                    if i in cmds and cmds[i][0].tick > applied_tick[i]:
                        commanded.add(i)
                        command, arrived_s = cmds[i]
                        wheels[i] = (command.left_mps, command.right_mps)
                        applied_tick[i] = command.tick
                        last_fresh_s[i] = arrived_s
                        sent_s = self._published_at_s.get(command.tick)
                        if sent_s is not None:
                            latencies_s.append(arrived_s - sent_s)
                        if command.tick == tick:
                            fresh += 1
                            slowest = max(slowest, arrived_s - self._published_at_s[tick])
                    if i not in alive or now_s - last_fresh_s[i] > sim.watchdog_s:
                        wheels[i] = 0.0
                served += fresh >= len(alive)
                late_per_tick.append(max(0, len(alive) - fresh))
                if fresh >= len(alive):
                    slowest_s.append(slowest)
                self._count_robot_ticks({i: c for i, c in cmds.items() if c[0].tick == tick}, alive)
                self._track_silence(tick, commanded)
                self._published_at_s.pop(tick - 20, None)
                step_wall_s, step_cpu_s = self._apply_and_step(world, trajectory, tick, poses, wheels)
                physics_s += step_wall_s
                physics_cpu_s += step_cpu_s
                self._write_stats_now_and_then(tick)
        wall_s = time.perf_counter() - start_s
        self.stats.update(
            ticks=steps,
            ticks_served=served,
            ticks_missed=steps - served,
            latency_ms=_percentiles_ms(latencies_s),
            latency_histogram_ms=_latency_histogram_ms(latencies_s),
            publish_lag_ms=_percentiles_ms(publish_lags_s),
            slowest_command_ms=_percentiles_ms(slowest_s),
            late_agents_per_tick=_late_histogram(late_per_tick),
            overruns=overruns,
            physics_ms_per_tick=1e3 * physics_s / max(steps, 1),
            physics_cpu_ms_per_tick=1e3 * physics_cpu_s / max(steps, 1),
            **self._timing_stats(steps),
            loop_wall_s=wall_s,
            realtime_factor=steps * self.dt_s / wall_s if wall_s > 0 else None,
        )
        return EXIT_DONE

    def _wait_for_restarted(self, tick: int) -> None:
        """lockstep: before publishing ``tick``, wait for every agent that a ``restart_agent`` fault due
        by now has killed and whose new process's token is not up yet (the runner kills the old agent
        once the server is on the fault's tick, then starts the new one, whose start-up takes seconds
        of wall time: without this wait a short run could end before the new agent ever drove its
        robot). Waits at most ``startup_timeout_s`` per restart, then goes on without it (the run's
        health then names the restart that never came back); ``restart_waits`` in the stats."""
        for robot, ticks in self._restart_ticks.items():
            due = [t for t in ticks if t <= tick]
            with self._cond:
                backs = sum(t >= due[0] for t in self._back_ticks.get(robot, [])) if due else 0
                if robot in self._alive or backs + self._restarts_given_up[robot] >= len(due):
                    continue  # none due, the old agent not killed yet, or the new one is up
                start_s = time.perf_counter()
                back = self._wait(lambda r=robot: r in self._alive, start_s + self.options.startup_timeout_s)
                if not back and not self._stop:
                    self._restarts_given_up[robot] += 1
                waited_s = round(time.perf_counter() - start_s, 4)
                self.stats.setdefault("restart_waits", []).append(
                    {"robot": robot, "tick": tick, "wall_s": waited_s, "back": back}
                )

    def _count_hung(self, cmds: dict, alive: set[int]) -> None:
        """lockstep: a live agent whose command missed ``HUNG_AFTER_DEADLINES`` deadlines in a row is
        hung (not waited for) until it answers again (:meth:`_on_cmd`)."""
        with self._cond:
            for i in range(self.count):
                if i in cmds or i not in alive or i in self._hung:
                    self._missed_in_row[i] = 0
                    continue
                self._missed_in_row[i] += 1
                if self._missed_in_row[i] >= HUNG_AFTER_DEADLINES:
                    self._hung.add(i)
                    self._missed_in_row[i] = 0
                    self._event(i, "hung")

    def _count_robot_ticks(self, cmds: dict, alive: set[int]) -> None:
        """Per robot: one more tick without a command of this tick, one more with its agent gone."""
        for i in range(self.count):
            self._ticks_without_command[i] += i not in cmds
            self._ticks_dead[i] += i not in alive

    def _track_silence(self, tick: int, commanded: set[int]) -> None:
        """Runs of ticks in a row without a command of a robot (``silent_spans``, lock held inside)."""
        with self._cond:
            for i in range(self.count):
                start = int(self._silent_from[i])
                if i in commanded:
                    if start >= 0:
                        self._silent_from[i] = -1
                        self._keep_silent_span(i, start, tick - start, to_end=False)
                elif start < 0:
                    self._silent_from[i] = tick
            self._ticks_tracked = tick + 1

    def _keep_silent_span(self, robot: int, start: int, ticks: int, to_end: bool) -> None:
        spans = self.stats["silent_spans"]
        if ticks >= SILENT_SPAN_MIN_TICKS and len(spans) < SILENT_SPANS_KEPT:
            spans.append({"robot": robot, "from_tick": start, "ticks": ticks, "to_end": to_end})

    def _open_silent_spans(self) -> list[dict]:
        """The runs without a command that go on at the last tick tracked (lock held)."""
        end = self._ticks_tracked
        return [
            {"robot": i, "from_tick": int(start), "ticks": end - int(start), "to_end": True}
            for i, start in enumerate(self._silent_from)
            if start >= 0 and end - start >= SILENT_SPAN_MIN_TICKS
        ]

    def _write_stats_now_and_then(self, tick: int) -> None:
        if time.perf_counter() >= self._stats_written_s + STATS_EVERY_S:
            self.stats["ticks_done"] = tick + 1
            self._write_stats(None)

    def _per_robot(self) -> list[dict]:
        """Ticks without a command (agent gone, late or hung) and when each agent went and came back."""
        with self._cond:
            events = list(self.stats["agent_events"])
        return [
            {
                "robot": i,
                "ticks_without_command": int(self._ticks_without_command[i]),
                "ticks_agent_gone": int(self._ticks_dead[i]),
                "gone_at_s": [e["time_s"] for e in events if e["robot"] == i and e["event"] == "gone"],
                "back_at_s": [e["time_s"] for e in events if e["robot"] == i and e["event"] == "back"],
                "hung_at_s": [e["time_s"] for e in events if e["robot"] == i and e["event"] == "hung"],
                "answering_at_s": [
                    e["time_s"] for e in events if e["robot"] == i and e["event"] == "answering"
                ],
            }
            for i in range(self.count)
        ]

    def _write_stats(self, outcome: int | None) -> None:
        """``server_stats.json``, replaced atomically; ``outcome`` None: the run goes on."""
        exits: dict[int | None, str] = {
            None: "running",
            EXIT_DONE: "done",
            EXIT_FAILED: "failed",
            EXIT_INTERRUPTED: "interrupted",
        }
        stats = {
            "run": self.options.run,
            "mode": self.scenario.sim.mode,
            "robots": self.count,
            "control_period_s": self.dt_s,
            "deadline_s": self.scenario.sim.deadline_s,
            "exit": exits.get(outcome),
        }
        with self._cond:  # the Zenoh threads append agent events
            stats.update(self.stats, agent_events=list(self.stats["agent_events"]))
            stats["silent_spans"] = [*self.stats["silent_spans"], *self._open_silent_spans()]
        stats["per_robot"] = self._per_robot()
        write_atomically(self.options.out_dir / "server_stats.json", json.dumps(stats, indent=2) + "\n")
        self._stats_written_s = time.perf_counter()


def install_signal_handlers(server: SimServer) -> None:
    """SIGTERM and SIGINT end the run cleanly: the loop stops and the Zenoh session is closed."""
    signal.signal(signal.SIGTERM, server.request_stop)
    signal.signal(signal.SIGINT, server.request_stop)
