"""One robot's controller as its own process (docs/design.md, "Processes").

The agent knows its robot id, the run id and an endpoint of the sim server; it fetches everything
else (graph neighbours, controller, policy) from ``swarm/<run>/config/<i>``. It then subscribes to
exactly its own pose key and to the message keys of its graph neighbours (never a wildcard over
robots), runs its onboard controller (:mod:`swarm.sim.onboard`, numpy only) and publishes, each tick,
its message to its neighbours and its saturated wheel speeds to the sim. With ``safety`` in the
scenario it also subscribes to its own sensor reading ``robot/<i>/sense`` and passes its controller's
command through the barrier filter (:class:`SenseReader`, docs/safety.md).

Timing (docs/design.md, "Information timing"): at tick k the agent acts on its pose of tick k and on its
neighbours' messages of tick k-1. ``lockstep``: it waits up to ``sim.neighbour_deadline_s`` (from
receiving pose k) for the message of tick k-1 of every neighbour whose liveliness token is up; a
message that misses it counts as lost and the neighbour is left out of that tick, as a dropped
packet would be. ``realtime``: no waiting; each neighbour's latest message counts while it is at
most ``sim.message_max_age_ticks`` (default 10) old.

Link faults (``swarm.core.faults``, from the scenario in the agent's config) act here, at the receiving
end: the message of tick m from neighbour j counts only if the schedule says this robot heard it (link
up, packet not lost), and under a delay d the newest usable message at tick k is that of tick k-1-d.
A neighbour with no usable message is left out of the tick (the controller normalises over the
neighbours heard; a robot that heard nobody holds still). The record counts each reason:
``messages.dropped_by_fault`` (link down), ``lost_by_fault`` (packet loss), ``delayed_by_fault``
(heard with a delay), ``lost`` (a message that did not come: a dead neighbour, a missed deadline).

Nothing assumes the agent starts at tick 0: a restarted agent joins at the tick of the first pose it
gets (it does not wait for messages of earlier ticks), and a neighbour whose liveliness token comes
back after the first tick is waited for only from the first message it sends again.

Receiving runs no Python outside the main thread: the pose, the neighbours' messages and their
liveliness arrive in Zenoh ring channels (:class:`Inlet`), which Zenoh's receiving threads fill
without the GIL; the main thread blocks in the pose channel's ``recv`` and drains the others once
per tick. (A Python callback in Zenoh's threads costs a GIL hand-off per sample: ~0.2 ms of a
0.6 ms tick at N = 6, measured against the floor by ``bench/bench_runtime.py``.) A pose or message
is accepted only inside the window the agent's own clock justifies (:mod:`swarm.runtime.ticks`);
every rejection is counted by reason (invalid, old, future) in the record, and so is every drain
that found a ring full (``ring_full``: samples may have been pushed out; 0: none was). Only the
sim's liveliness has a callback (it fires once or twice a run); a stop request or the sim going
away interrupts the pose ``recv`` with a signal (``run`` from the main thread; elsewhere the agent
polls). In lockstep a neighbour's message
of tick k-1 reaches the agent before its pose k (both pass the server's router in order), so the
agent rarely waits; when it must, it polls the channels until the deadline.

With a run key in its environment (``SWARM_RUN_KEY``: ``swarm.runtime.wire.RunKey``, given by ``swarm
run``) the agent checks the tag of every pose, message and config reply before anything else (one
without a valid tag is *unauthenticated*; it takes its configuration only from a reply with the sim's
tag, reading every reply: ``config_source``, ``config_rejected``) and tags what it sends. In lockstep
a neighbour whose token is up but whose message missed ``HUNG_AFTER_DEADLINES`` neighbour deadlines in
a row is not waited for until it talks again (``neighbour_events``): a token alone cannot stall it.

Where the pose comes from and where the command goes are three methods (``_open_pose``,
``_decode_pose``, ``_declare_command``): the project's keys here, ROS 2 topics in
:mod:`robot_agent.ros2` (``robot-agent --ros2``).

The agent holds the token ``swarm/<run>/alive/agent/<i>``, exits cleanly (session closed) on SIGTERM
or SIGINT and when the sim's token ``swarm/<run>/alive/sim`` goes away (after the run's last tick at
once, else when it stays away ``sim.server_lost_s``: a brief partition is survived), and records what it
subscribed to and received in ``<log-dir>/agent_<i>.json`` (once it is ready, and again at exit).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from swarm.core import safety, tasks, topologies
from swarm.core.exit_codes import ExitCode
from swarm.core.faults import DROPPED, HEARD, LOST, LinkFaults, message_max_age_ticks, select_message
from swarm.core.files import write_atomically
from swarm.core.robot import RobotParams
from swarm.runtime import wire
from swarm.runtime.ticks import ACCEPT, OLD, PoseWindow, step_s_of
from swarm.sim.controller_kinds import robot_controller
from swarm.sim.onboard import wheels_one

SERVER_LOST_S = 5.0
"""How long the sim's token may be gone before the agent takes the sim as gone (until its config
says ``sim.server_lost_s``): a brief network partition or a frozen process must not end the agent.
Once the agent has computed the run's last tick it exits at once."""

SIM_UNSEEN_S = 10.0
"""An agent that has not seen the sim's liveliness token for this long (after fetching its
config from it) takes the sim as gone."""

INBOX_TICKS = 8
"""Messages kept per neighbour (by tick), at least: a fast neighbour's tick-k message must not hide
its k-1 (more under a delay fault or a longer message age)."""

POSE_RING = 8192
"""Poses buffered by the pose inlet; the newest is used, older ones count as skipped (a full ring
pushes out its oldest: ``Inlet.ring_full``). Large enough that a flood of forged samples on the
key (rejected by their tag at ~1 us each) cannot push the genuine one out between two drains: at
12,000 samples/s a ring of 8192 holds 0.68 s of it, more than a neighbour deadline (an empty ring
costs nothing; a full one ~4 MiB: docs/distributed-runtime.md, "The run key")."""

MESSAGE_RING = 8192
"""Samples buffered per neighbour inlet (a ring: a slow agent drops, never stalls its session);
drained every tick and while waiting, sized for floods as ``POSE_RING``."""

LIVELINESS_RING = 16

SENSE_RING = 64
"""Sensing samples buffered (one a tick from the sim; drained every tick)."""

INBOX_RING = 64
"""Radio inboxes buffered (a disk graph: one a tick from the sim; drained every tick)."""

HUNG_AFTER_DEADLINES = 3
"""lockstep: a live neighbour (its token up) whose message missed this many neighbour deadlines in a
row is *hung*: not waited for until a message of it comes again (a token alone, a zombie's, cannot
stall this agent). Both are events in the record (``neighbour_events``)."""

POLL_S = 0.0005
"""lockstep: channel polling period while a live neighbour's message of the last tick is missing."""

WAKE_SIGNAL = signal.SIGUSR1
"""Sent to the main thread when the sim goes away, to interrupt its blocking ``recv``."""

EXIT_DONE, EXIT_FAILED = ExitCode.SUCCESS, ExitCode.NOT_MET


class _Wake(BaseException):
    """Raised by a signal handler into the main thread's blocking ``recv`` (stop, sim gone)."""


class Inlet:
    """The payloads of one subscription, in a Zenoh ring channel read by the main thread only.

    Zenoh's receiving thread fills the ring without the GIL; a full ring drops its oldest sample
    without telling anyone. What can be known is when that may have happened: a ring found empty
    (``take`` gave None) and then drained of fewer than ``capacity`` samples before it was found
    empty again dropped none in between (a drop leaves the ring full, and every sample then in it
    is taken before it is empty again). ``ring_full`` counts the drains that reached ``capacity``
    samples: 0 means nothing was pushed out. ``unread``: samples still queued when it was closed."""

    __slots__ = ("_streak", "capacity", "ring_full", "subscriber", "taken", "unread")

    def __init__(self, session: zenoh.Session, key: str, capacity: int):
        self.capacity = capacity
        self.subscriber = session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))
        self.taken = self.ring_full = self.unread = 0
        self._streak = 0  # samples taken since the ring was last found empty

    def take(self) -> tuple[bytes, bytes | None] | None:
        """The oldest queued ``(payload, attachment)``, or None (the ring is empty now)."""
        sample = self.subscriber.try_recv()
        if sample is None:
            self._streak = 0
            return None
        self._count()
        attachment = sample.attachment
        return sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()

    def recv(self) -> tuple[bytes, bytes | None]:
        """Block for the next ``(payload, attachment)`` (a signal handler that raises interrupts the wait)."""
        sample = self.subscriber.recv()
        self._count()
        attachment = sample.attachment
        return sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()

    def _count(self) -> None:
        self.taken += 1
        self._streak += 1
        if self._streak == self.capacity:
            self.ring_full += 1

    def undeclare(self) -> None:
        """Count what is still queued (``unread``), then undeclare the subscriber."""
        while self.subscriber.try_recv() is not None:
            self.unread += 1
        self.subscriber.undeclare()


class CommandSink:
    """The project's command stream: a :func:`wire.encode_command` per tick, tagged with the run key."""

    __slots__ = ("key", "publisher", "run_key")

    def __init__(self, publisher: zenoh.Publisher, key: str, run_key: wire.RunKey | None):
        self.publisher, self.key, self.run_key = publisher, key, run_key

    def send(self, tick: int, wheels: Sequence[float]) -> None:
        payload = wire.encode_command(tick, wheels)
        if self.run_key is None:
            self.publisher.put(payload)
        else:
            self.publisher.put(payload, attachment=self.run_key.tag(self.key, payload))

    def undeclare(self) -> None:
        self.publisher.undeclare()


def take_reading(
    key: str, payload: bytes, tag: bytes | None, run_key: wire.RunKey | None, counts: dict[str, int]
) -> wire.Sensing | None:
    """A sensor reading that came on ``key``, if its tag is the run's and it decodes (counted in
    ``counts``: received, unauthenticated, invalid); None otherwise."""
    if run_key is not None and not run_key.check(key, payload, tag):
        counts["unauthenticated"] += 1
        return None
    reading = wire.decode_sensing(payload)
    counts["invalid" if reading is None else "received"] += 1
    return reading


def filter_step(
    reading: wire.Sensing | None,
    u_world,
    theta_rad: float,
    robot: RobotParams,
    params: safety.SafetyParams,
    counts: dict[str, int],
) -> tuple[tuple[float, float], bool]:
    """One robot's command through its barrier filter with its own reading (``safety.filter_reading``),
    counted in ``counts``: the safe world command and whether the robot must brake (no reading, or no
    safe command)."""
    if reading is None:
        counts["missing"] += 1
        return (0.0, 0.0), True
    safe, status = safety.filter_reading(
        np.asarray(u_world, dtype=np.float64), theta_rad, reading.bodies, reading.obstacles, robot, params
    )
    if status == safety.CHANGED:
        counts["interventions"] += 1
    elif status == safety.INFEASIBLE:
        counts["infeasible"] += 1
        return (0.0, 0.0), True
    return (float(safe[0]), float(safe[1])), False


class SenseReader:
    """The robot's own range-sensor readings (``swarm/<run>/robot/<i>/sense``, scenarios with
    ``safety``) and its safety filter (:func:`filter_step`) on the controller's command.

    The reading of tick k goes out just before pose k, so it is normally in when the pose is; lockstep
    waits for it up to the neighbour deadline. A tick without its reading (lost, late, forged) brakes
    the robot (``missing``): driving blind is not safe. Counts: ``swarm.core.safety.FILTER_COUNTS``."""

    def __init__(self, inlet: Inlet, key: str, params: safety.SafetyParams, robot: RobotParams):
        self.inlet, self.key, self.params, self.robot = inlet, key, params, robot
        self.readings: dict[int, wire.Sensing] = {}
        self.counts = dict.fromkeys(safety.FILTER_COUNTS, 0)

    def drain(self, tick: int, run_key: wire.RunKey | None) -> bool:
        """Take what is queued; whether the reading of ``tick`` is in."""
        counts, readings = self.counts, self.readings
        while (taken := self.inlet.take()) is not None:
            reading = take_reading(self.key, *taken, run_key, counts)
            if reading is not None and reading.tick >= tick:  # an older one can no longer be used
                readings[reading.tick] = reading
        for old in [k for k in readings if k < tick]:
            del readings[old]
        return tick in readings

    def filtered(self, tick: int, u_world, theta_rad: float) -> tuple[tuple[float, float], bool]:
        """The safe command of this tick, and whether the robot must brake (no reading, infeasible)."""
        return filter_step(self.readings.get(tick), u_world, theta_rad, self.robot, self.params, self.counts)


class InboxReader:
    """On a disk graph, what the sim's radio relays to this robot (``swarm/<run>/robot/<i>/inbox``,
    ``sim_server.radio``): the messages of the robots in range that it hears, one inbox a tick, sent
    just before the pose; lockstep waits for it up to the neighbour deadline. A tick without its inbox
    hears nobody (``inboxes_missing``)."""

    def __init__(self, inlet: Inlet, key: str, dim: int, robot_count: int):
        self.inlet, self.key, self.dim, self.robot_count = inlet, key, dim, robot_count
        self.inboxes: dict[int, wire.Inbox] = {}
        self.counts = {"received": 0, "invalid": 0, "unauthenticated": 0, "missing": 0}

    def drain(self, tick: int, run_key: wire.RunKey | None) -> bool:
        """Take what is queued; whether the inbox of ``tick`` is in."""
        counts, inboxes = self.counts, self.inboxes
        while (taken := self.inlet.take()) is not None:
            payload, tag = taken
            if run_key is not None and not run_key.check(self.key, payload, tag):
                counts["unauthenticated"] += 1
                continue
            inbox = wire.decode_inbox(payload, self.dim, self.robot_count)
            counts["invalid" if inbox is None else "received"] += 1
            if inbox is not None and inbox.tick >= tick:  # an older one can no longer be used
                inboxes[inbox.tick] = inbox
        for old in [k for k in inboxes if k < tick]:
            del inboxes[old]
        return tick in inboxes


@dataclass
class AgentOptions:
    robot: int
    run: str | None  # None: discover it (the one run whose sim serves this robot)
    connect: list[str]
    zenoh_mode: str = "client"
    lease_ms: int = 1000
    startup_timeout_s: float = 60.0
    log_dir: Path | None = None
    zenoh_settings: dict = field(default_factory=dict)  # more session settings (acl credentials)


@dataclass
class Counters:
    poses_received: int = 0
    poses_invalid: int = 0
    poses_unauthenticated: int = 0  # no valid run-key tag: forged (or a sender without the run key)
    poses_old: int = 0  # tick not newer than the newest pose seen: a replay or reordered
    # poses dated beyond the agent's window (swarm.runtime.ticks) are counted by its PoseWindow
    poses_skipped: int = 0
    messages_received: int = 0
    messages_invalid: int = 0
    messages_unauthenticated: int = 0
    messages_old: int = 0  # tick not newer than the newest accepted from that neighbour
    messages_future: int = 0  # tick beyond the agent's window (swarm.runtime.ticks): forged or dated ahead
    messages_lost: int = 0
    messages_dropped_by_fault: int = 0
    messages_lost_by_fault: int = 0
    messages_delayed_by_fault: int = 0
    messages_late: int = 0
    ticks: int = 0
    ticks_waited: int = 0
    commands_sent: int = 0
    neighbour_wait_s: list[float] = field(default_factory=list)
    compute_s: list[float] = field(default_factory=list)


def _stats_ms(samples_s: list[float]) -> dict[str, float | None]:
    if not samples_s:
        return {"p50": None, "p99": None, "max": None}
    values = np.asarray(samples_s) * 1e3
    p50, p99 = np.percentile(values, [50, 99])
    return {"p50": round(float(p50), 4), "p99": round(float(p99), 4), "max": round(float(values.max()), 4)}


def _came_under_faults(box: dict, faults: LinkFaults, sender: int, me: int) -> Callable[[int], bool]:
    """Whether the message of tick k from ``sender`` is in ``box`` and the link faults let it through."""
    return lambda k: k in box and faults.heard(sender, me, k)


class RobotAgent:
    """The agent of one robot; :meth:`run` returns the process exit status."""

    def __init__(self, options: AgentOptions):
        self.options = options
        self.run_id = options.run
        self.keys = wire.Keys(options.run) if options.run is not None else None
        self.robot = options.robot
        self.counters = Counters()
        self._stop = False
        self._sim_alive: bool | None = None  # None: not seen yet
        self._sim_unseen = False
        self._sim_lost_at: float | None = None  # monotonic time the sim's token went, while it is gone
        self._server_lost_s = SERVER_LOST_S
        self._final_tick: int | None = None  # the run's last tick, from the config
        self._blocking = False  # the main thread sits in a recv that a signal may interrupt
        self._main_thread: int | None = None  # set when signals can interrupt the main thread
        self._inbox: dict[int, dict[int, Sequence[float]]] = {}  # neighbour -> tick -> message
        self._msg_inlets: dict[int, Inlet] = {}
        self._pose_inlet: Inlet | None = None
        self._sense: SenseReader | None = None  # scenarios with a safety filter
        self._pose_key = ""
        self._msg_keys: dict[int, str] = {}
        self._window = PoseWindow(1.0)
        self._run_key = wire.RunKey.from_env()  # None: authentication off (no SWARM_RUN_KEY)
        self._newest_message_tick: dict[int, int] = {}  # neighbour -> tick of its newest message accepted
        self._alive_subs: dict[int, zenoh.Subscriber] = {}
        self._neighbours_alive: set[int] = set()
        self._radio: InboxReader | None = None  # a disk graph: the sim's radio relays what it hears
        self._neighbours_gone: set[int] = set()  # neighbours whose token went away at least once
        self._neighbours_hung: set[int] = set()  # live but silent (HUNG_AFTER_DEADLINES): not waited for
        self._missed_in_row: dict[int, int] = {}  # neighbour -> neighbour deadlines missed in a row
        self._lockstep = True
        self._last_tick = -1
        self._first_tick: int | None = None  # the tick of the first pose this agent got (0 unless restarted)
        self._joined: dict[int, int | None] = {}  # neighbour -> first tick to wait for; None: not yet heard
        self._faults = LinkFaults([], 1.0)
        self._max_age = 1
        self._keep_ticks = 1  # how far back a message may still be used: largest delay + max age
        self._inbox_ticks = INBOX_TICKS
        self._dim = 0
        self._pose_tagged = True  # poses carry the run key's tag (not a ROS 2 robot's odometry)
        self._ticks_to_run: int | None = None  # ticks after which the agent ends (None: when the sim goes)
        self.config: wire.AgentConfig | None = None
        self.record: dict = {
            "robot": self.robot,
            "role": "agent",
            "pid": os.getpid(),
            "ppid": os.getppid(),
            "host": socket.gethostname(),
            "run": options.run,
            "connect": list(options.connect),
            "subscriptions": [],
            "liveliness_subscriptions": [],
            "publications": [],
            "liveliness_tokens": [],
            "queries": [],
            "exit_reason": None,
            "sim_lost": 0,  # times the sim's token went away (a partition, the sim's end)
            "neighbour_events": [],  # {"robot", "event": hung | answering, "tick"}
            # run key: every pose, message and the config must carry its tag; off: none is checked
            "authentication": "run key" if self._run_key is not None else "off",
            "config_source": None,
            "config_rejected": 0,  # config replies without a valid run-key tag (another answerer)
        }
        self._started_s = time.perf_counter()

    # ------------------------------------------------------------------ signals and the one callback
    def request_stop(self, *_: object) -> None:
        """SIGTERM / SIGINT handler (also callable from the main thread)."""
        self._stop = True
        self._interrupt()

    def _interrupt(self, *_: object) -> None:
        """In the main thread (signal handler): leave a blocking ``recv`` if it sits in one."""
        if self._blocking:
            self._blocking = False  # at most one _Wake per recv
            raise _Wake

    def _kick(self) -> None:
        """From another thread: make the main thread look at the flags now."""
        if self._main_thread is not None:
            signal.pthread_kill(self._main_thread, WAKE_SIGNAL)

    def _on_sim_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self._sim_alive, self._sim_lost_at = True, None
            return
        self._sim_lost_at = lost_at = time.monotonic()
        self.record["sim_lost"] += 1
        if self._final_tick is not None and self._last_tick >= self._final_tick:
            self._sim_gone()  # the run is over
            return

        def still_lost() -> None:
            if self._sim_lost_at == lost_at:
                self._sim_gone()

        grace = threading.Timer(self._server_lost_s, still_lost)
        grace.daemon = True
        grace.start()

    def _sim_gone(self) -> None:
        self._sim_alive = False
        self._kick()

    def _check_sim_seen(self) -> None:
        if self._sim_alive is None:
            self._sim_unseen = True
            self._kick()

    def _ended(self) -> bool:
        return self._stop or self._sim_alive is False or self._sim_unseen

    def _recv(self, inlet: Inlet) -> tuple[bytes, bytes | None] | None:
        """The next payload of the pose inlet; None once stopped or the sim is gone."""
        if self._main_thread is None:  # no signals here: poll
            while not self._ended():
                payload = inlet.take()
                if payload is not None:
                    return payload
                time.sleep(0.001)
            return None
        payload = inlet.take()
        if payload is not None:
            return payload
        try:
            try:
                self._blocking = True  # before the checks: a signal from here on interrupts the wait
                if self._ended():
                    return None
                return inlet.recv()  # Zenoh's recv runs the signal handlers while it waits
            finally:
                self._blocking = False
        except _Wake:
            return None

    # ------------------------------------------------------------------ channels (main thread)
    def _drain_liveliness(self) -> None:
        for j, subscriber in self._alive_subs.items():
            while (sample := subscriber.try_recv()) is not None:
                if sample.kind == zenoh.SampleKind.PUT:
                    if j not in self._neighbours_alive:  # back after a crash: wait once it talks again
                        self._joined[j] = None if j in self._neighbours_gone else 0
                    self._neighbours_alive.add(j)
                else:
                    self._neighbours_alive.discard(j)
                    self._neighbours_gone.add(j)

    def _drain_messages(self) -> None:
        counters, newest = self.counters, self._newest_message_tick
        limit = self._window.limit(time.perf_counter())  # no neighbour is ahead of the sim (ticks.py)
        run_key, keys = self._run_key, self._msg_keys
        for j, inlet in self._msg_inlets.items():
            box = self._inbox[j]
            while (taken := inlet.take()) is not None:
                payload, tag = taken
                if run_key is not None and not run_key.check(keys[j], payload, tag):
                    counters.messages_unauthenticated += 1
                    continue
                decoded = wire.decode_message_values(payload, self._dim)
                if decoded is None:
                    counters.messages_invalid += 1
                    continue
                tick, values = decoded
                if tick <= newest.get(j, -1):
                    counters.messages_old += 1
                    continue
                if tick > limit:
                    counters.messages_future += 1
                    continue
                newest[j] = tick
                counters.messages_received += 1
                if self._missed_in_row.get(j):
                    self._missed_in_row[j] = 0
                if j in self._neighbours_hung:  # it talks again: waited for from here on
                    self._neighbours_hung.discard(j)
                    self.record["neighbour_events"].append({"robot": j, "event": "answering", "tick": tick})
                if self._lockstep and tick < self._last_tick - self._keep_ticks:
                    counters.messages_late += 1  # every tick that could use it is computed already
                    continue
                box[tick] = values
                if self._joined.get(j, 0) is None:
                    self._joined[j] = tick  # a neighbour back from a crash: wait for it from here on
                if len(box) > self._inbox_ticks:
                    del box[min(box)]

    def _next_pose(self, inlet: Inlet) -> wire.Pose | None:
        """Block for a pose newer than the last one used and inside the agent's window (the newest
        if several are queued; one dated beyond it only once a second pose confirms it:
        swarm.runtime.ticks)."""
        counters, window, newest = self.counters, self._window, None
        run_key = self._run_key if self._pose_tagged else None
        pose_key, decode_pose = self._pose_key, self._decode_pose
        while newest is None:
            taken = self._recv(inlet)
            while taken is not None:
                payload, tag = taken
                taken = inlet.take()
                if run_key is not None and not run_key.check(pose_key, payload, tag):
                    counters.poses_unauthenticated += 1
                    continue
                pose = decode_pose(payload)
                if pose is None:
                    counters.poses_invalid += 1
                else:
                    verdict = window.offer(pose.tick, time.perf_counter())
                    if verdict == ACCEPT:
                        counters.poses_received += 1
                        if newest is not None:
                            counters.poses_skipped += 1  # a newer pose came before we used this one
                        newest = pose
                    elif verdict == OLD:
                        counters.poses_old += 1
            if self._ended():
                return None
        return newest

    def _waiting_for(self, tick: int) -> bool:
        """lockstep: whether a live neighbour's message that ``tick`` needs (that of tick k-1-delay)
        may still come: not from before this agent's first tick or the neighbour's return, not one the
        link faults drop anyway."""
        return bool(self._missing(tick, first_only=True))

    def _missing(self, tick: int, first_only: bool = False) -> list[int]:
        """The live, not hung neighbours whose message that ``tick`` needs may still come (see
        :meth:`_waiting_for`); only the first found with ``first_only``."""
        faults, me, first_tick = self._faults, self.robot, self._first_tick
        assert first_tick is not None  # called once a pose came
        hung, missing = self._neighbours_hung, []
        for j in self._neighbours_alive:
            needed = tick - 1 if faults.empty else tick - 1 - faults.delay_ticks(j, me, tick)
            joined = self._joined.get(j, 0)
            if joined is None or needed < first_tick or needed < joined or needed in self._inbox[j]:
                continue
            if j in hung:
                continue
            if faults.empty or faults.heard(j, me, needed):
                missing.append(j)
                if first_only:
                    break
        return missing

    def _wait_for_sample(self, reader: SenseReader | InboxReader, tick: int, until_s: float) -> None:
        """lockstep: poll until this tick's sample from the sim (the sensor reading; on a disk graph the
        radio's inbox) is in, or the deadline."""
        while not self._ended() and time.perf_counter() < until_s:
            time.sleep(POLL_S)
            if reader.drain(tick, self._run_key):
                return

    def _heard_by_radio(self, radio: InboxReader, tick: int) -> tuple[list[int], list, list[float]]:
        """The senders, messages and weights of this tick's inbox, its counts added to the agent's."""
        inbox = radio.inboxes.get(tick)
        if inbox is None:
            radio.counts["missing"] += 1
            return [], [], []
        counters = self.counters
        counters.messages_received += len(inbox.senders)
        counters.messages_dropped_by_fault += inbox.counts["dropped_by_fault"]
        counters.messages_lost_by_fault += inbox.counts["lost_by_fault"]
        counters.messages_delayed_by_fault += inbox.counts["delayed_by_fault"]
        counters.messages_lost += inbox.counts["lost"]
        rows = (
            [tuple(row) for row in inbox.values]
            if self._dim <= wire.SHORT_MESSAGE_DIM
            else list(inbox.values)
        )
        return list(inbox.senders), rows, list(inbox.weights)

    def _wait_for_messages(self, tick: int, until_s: float) -> None:
        """lockstep: poll until every live neighbour's needed message is in, or the deadline."""
        while True:
            self._drain_liveliness()
            self._drain_messages()
            if not self._waiting_for(tick):
                return
            if self._ended():
                return
            if time.perf_counter() >= until_s:
                for j in self._missing(tick):  # missed the deadline: hung after a few in a row
                    self._missed_in_row[j] = self._missed_in_row.get(j, 0) + 1
                    if self._missed_in_row[j] >= HUNG_AFTER_DEADLINES:
                        self._neighbours_hung.add(j)
                        self._missed_in_row[j] = 0
                        self.record["neighbour_events"].append({"robot": j, "event": "hung", "tick": tick})
                return
            time.sleep(POLL_S)

    # ------------------------------------------------------------------ main thread
    def _open(self) -> zenoh.Session | None:
        options = self.options
        config = lambda: wire.session_config(  # noqa: E731 (a fresh config per attempt)
            options.zenoh_mode, options.connect, (), options.lease_ms, options.zenoh_settings
        )
        deadline_s = self._started_s + self.options.startup_timeout_s
        delay_s = 0.01
        while not self._stop:
            try:
                return zenoh.open(config())
            except zenoh.ZError:
                if time.perf_counter() + delay_s > deadline_s:
                    return None
                time.sleep(delay_s)
                delay_s = min(2 * delay_s, 0.25)
        return None

    def _discover_run(self, session: zenoh.Session) -> str | None:
        """The run id of the one sim on this router that serves this robot (``--run`` not given)."""
        key = wire.Keys.any_run_config(self.robot)
        self.record["queries"].append(key)
        deadline_s = self._started_s + self.options.startup_timeout_s
        while not self._stop and time.perf_counter() < deadline_s:
            runs, errors = set(), []
            for reply in session.get(key, **wire.config_query_options()):
                if reply.ok is not None:
                    run = wire.Keys.run_of_config(str(reply.ok.key_expr))
                    if run is not None and self._config_genuine(reply.ok):
                        runs.add(run)
                else:
                    errors.append(reply.err.payload.to_bytes().decode(errors="replace"))
            if len(runs) == 1:
                return runs.pop()
            if runs:
                self.record["config_error"] = (
                    f"several runs serve robot {self.robot}: {sorted(runs)}; give --run"
                )
                return None
            if errors and self._run_key is None:  # with the key: anyone may answer an error, go on asking
                self.record["config_error"] = "; ".join(errors)
                return None
            time.sleep(0.05)  # no sim answers yet
        return None

    def _fetch_config(self, session: zenoh.Session) -> wire.AgentConfig | None:
        assert self.keys is not None  # a run id is known once a configuration is fetched
        key = self.keys.config(self.robot)
        self.record["queries"].append(key)
        deadline_s = self._started_s + self.options.startup_timeout_s
        while not self._stop and time.perf_counter() < deadline_s:
            chosen = None
            # Every reply is read (not only up to the first good one): an answerer other than the sim
            # is then always seen and counted (config_rejected), whichever answered first.
            for reply in session.get(key, **wire.config_query_options()):
                if reply.ok is not None:
                    if not self._config_genuine(reply.ok) or chosen is not None:
                        continue  # another answerer (counted), or the sim's is taken already
                    config = wire.decode_config(reply.ok.payload.to_bytes())
                    if config is not None and config.robot == self.robot and config.run == self.run_id:
                        chosen = config
                    else:
                        self.record["config_error"] = "invalid config reply"
                else:
                    self.record["config_error"] = reply.err.payload.to_bytes().decode(errors="replace")
                    if self._run_key is None and chosen is None:  # with the key anyone may answer an error
                        return None
            if chosen is not None:
                self.record["config_source"] = (
                    "sim (run-key tag checked)"
                    if self._run_key is not None
                    else "first reply (unauthenticated: no run key)"
                )
                return chosen
            time.sleep(0.05)  # no queryable yet: the sim is still starting
        return None

    # ------------------------------------------------------------------ where poses and commands go
    def _open_pose(self, session: zenoh.Session, keys: wire.Keys, entities: list[Any]) -> Inlet:
        """The inlet of this robot's pose (``robot/<i>/pose``; ``robot_agent.ros2``: its odometry)."""
        self._pose_key = keys.pose(self.robot)
        return Inlet(session, self._pose_key, POSE_RING)

    def _decode_pose(self, payload: bytes) -> wire.Pose | None:
        return wire.decode_pose(payload)

    def _declare_command(self, session: zenoh.Session, keys: wire.Keys, options: dict) -> CommandSink:
        """Where this robot's wheel commands go (``robot/<i>/cmd``; ``robot_agent.ros2``: cmd_vel)."""
        key = keys.cmd(self.robot)
        return CommandSink(session.declare_publisher(key, **options), key, self._run_key)

    def _config_genuine(self, sample: zenoh.Sample) -> bool:
        """Whether a config reply carries the run key's tag (always, with authentication off);
        counts the others in ``config_rejected``."""
        key = self._run_key
        if key is None:
            return True
        if key.check(str(sample.key_expr), sample.payload.to_bytes(), wire.attachment_of(sample)):
            return True
        self.record["config_rejected"] += 1
        return False

    def run(self) -> int:
        """Run the agent until the sim goes away or a stop request. From the main thread, it
        installs a ``WAKE_SIGNAL`` handler and sleeps in ``recv``; from another thread it polls."""
        if threading.current_thread() is threading.main_thread():
            signal.signal(WAKE_SIGNAL, self._interrupt)
            self._main_thread = threading.get_ident()
        session = self._open()
        if session is None:
            self.record["exit_reason"] = "stopped" if self._stop else "could not connect"
            self._write_record()
            return EXIT_FAILED
        try:
            return self._run(session)
        finally:
            self._main_thread = None  # no more signals: the sim callback may still fire while closing
            session.close()
            self._write_record()

    def _run(self, session: zenoh.Session) -> int:
        if self.keys is None:
            self.run_id = self._discover_run(session)
            if self.run_id is None:
                self.record["exit_reason"] = "stopped" if self._stop else "no sim serves this robot"
                return EXIT_FAILED
            self.keys = wire.Keys(self.run_id)
            self.record["run"] = self.run_id
        record, keys = self.record, self.keys
        on_sim_alive = wire.guarded(self._on_sim_alive, record, f"robot-agent {self.robot}")
        sim_sub = session.liveliness().declare_subscriber(keys.alive_sim, on_sim_alive, history=True)
        record["liveliness_subscriptions"].append(keys.alive_sim)
        config = self._fetch_config(session)
        if config is None:
            record["exit_reason"] = "stopped" if self._stop else "no config from the sim"
            sim_sub.undeclare()
            return EXIT_FAILED
        self.config = config
        sim_spec = config.scenario.get("sim", {})
        self._server_lost_s = float(sim_spec.get("server_lost_s", SERVER_LOST_S))
        self._final_tick = round(sim_spec.get("duration_s", 0) / config.control_period_s) - 1
        params = RobotParams(**config.robot_params)
        try:
            controller = robot_controller(
                config.controller,
                params,
                config.gain,
                config.policy,
                config.robot_count,
                config.control_period_s,
                config.scenario.get("controller"),
                tasks.parse_section(config.scenario.get("task")),
                self.robot,
            )
        except ValueError as error:  # swarm.sim.policy.PolicyFormatError is a ValueError
            record["exit_reason"] = f"bad controller: {error}"
            sim_sub.undeclare()
            return EXIT_FAILED
        self._dim = controller.message_dim
        self._lockstep = config.mode == "lockstep"
        try:
            self._faults = LinkFaults.from_scenario_dict(config.scenario)
            self._max_age = message_max_age_ticks({"mode": config.mode, **config.scenario.get("sim", {})})
        except (KeyError, TypeError, ValueError) as error:
            record["exit_reason"] = f"bad faults in the config: {error}"
            sim_sub.undeclare()
            return EXIT_FAILED
        self._keep_ticks = self._faults.max_delay_ticks + self._max_age
        self._window = PoseWindow(step_s_of({"control_period_s": config.control_period_s, **sim_spec}))
        self._inbox_ticks = max(INBOX_TICKS, self._keep_ticks + 2)
        record.update(
            controller=config.controller,
            mode=config.mode,
            neighbours=list(config.neighbours),
            config_s=round(time.perf_counter() - self._started_s, 4),
        )
        ring = zenoh.handlers.RingChannel
        entities: list[Any] = [sim_sub]
        pose_inlet = self._pose_inlet = self._open_pose(session, keys, entities)
        self._msg_keys = {j: keys.msg(j) for j in config.neighbours}
        entities.append(pose_inlet)  # undeclared last: it counts what is unread first
        record["subscriptions"].append(self._pose_key)
        if config.scenario.get("safety") is not None:
            sense_inlet = Inlet(session, keys.sense(self.robot), SENSE_RING)
            self._sense = SenseReader(
                sense_inlet, keys.sense(self.robot), safety.SafetyParams(**config.scenario["safety"]), params
            )
            entities.append(sense_inlet)
            record["subscriptions"].append(keys.sense(self.robot))
        topology = config.scenario.get("topology", {}).get("kind")
        if topology is not None and topologies.get(topology).proximity:  # a disk graph: the radio
            radio_inlet = Inlet(session, keys.inbox(self.robot), INBOX_RING)
            self._radio = InboxReader(radio_inlet, keys.inbox(self.robot), self._dim, config.robot_count)
            entities.append(radio_inlet)
            record["subscriptions"].append(keys.inbox(self.robot))
            record["radio"] = self._radio.counts
        for j in config.neighbours:
            self._inbox[j] = {}
            self._msg_inlets[j] = inlet = Inlet(session, keys.msg(j), MESSAGE_RING)
            entities.append(inlet)
            record["subscriptions"].append(keys.msg(j))
        for j in config.neighbours:
            self._alive_subs[j] = session.liveliness().declare_subscriber(
                keys.alive_agent(j), ring(LIVELINESS_RING), history=True
            )
            entities.append(self._alive_subs[j])
            record["liveliness_subscriptions"].append(keys.alive_agent(j))
        options = wire.publisher_options(config.mode)
        msg_pub = session.declare_publisher(keys.msg(self.robot), **options)
        cmd_pub = self._declare_command(session, keys, options)
        record["publications"] += [keys.msg(self.robot), cmd_pub.key]
        entities += [msg_pub, cmd_pub]
        # The token comes last: once the sim sees it, every declaration above is in place.
        entities.append(session.liveliness().declare_token(keys.alive_agent(self.robot)))
        record["liveliness_tokens"].append(keys.alive_agent(self.robot))
        record["ready_s"] = round(time.perf_counter() - self._started_s, 4)
        record["cpu_ready_s"] = round(time.process_time(), 4)
        record["nice"] = os.getpriority(os.PRIO_PROCESS, 0)
        self._write_record()
        watchdog = threading.Timer(SIM_UNSEEN_S, self._check_sim_seen)
        watchdog.daemon = True
        watchdog.start()
        try:
            return self._loop(controller, params, config, pose_inlet, msg_pub, cmd_pub)
        finally:
            watchdog.cancel()
            for entity in reversed(entities):
                entity.undeclare()

    def _loop(
        self, controller, params: RobotParams, config: wire.AgentConfig, pose_inlet: Inlet, msg_pub, cmd_pub
    ) -> int:
        lockstep = self._lockstep
        neighbours = list(config.neighbours)
        weight_of = dict(zip(config.neighbours, config.weights, strict=True))
        counters, dim = self.counters, controller.message_dim
        act_floats = getattr(controller, "act_floats", None)
        faults, me, max_age = self._faults, self.robot, self._max_age
        no_faults = faults.empty
        boxes = [(j, self._inbox[j]) for j in neighbours]  # each neighbour's inbox, kept for the run
        run_key = self._run_key
        assert self.keys is not None
        msg_key = self.keys.msg(me)
        while True:
            pose = self._next_pose(pose_inlet)
            if pose is None:
                self.record["exit_reason"] = "stopped" if self._stop else "sim gone"
                return EXIT_DONE
            tick = self._last_tick = pose.tick
            if self._first_tick is None:  # 0, or later for an agent restarted mid-run
                self._first_tick = self.record["first_tick"] = tick
            self._drain_liveliness()
            self._drain_messages()
            sense = self._sense
            if sense is not None and not sense.drain(tick, run_key) and lockstep:
                self._wait_for_sample(sense, tick, time.perf_counter() + config.neighbour_deadline_s)
            if lockstep and self._waiting_for(tick):
                wait_start_s = time.perf_counter()
                self._wait_for_messages(tick, wait_start_s + config.neighbour_deadline_s)
                counters.neighbour_wait_s.append(time.perf_counter() - wait_start_s)
                counters.ticks_waited += 1
            radio = self._radio
            if radio is not None and not radio.drain(tick, run_key) and lockstep:
                wait_start_s = time.perf_counter()
                self._wait_for_sample(radio, tick, wait_start_s + config.neighbour_deadline_s)
                counters.neighbour_wait_s.append(time.perf_counter() - wait_start_s)
                counters.ticks_waited += 1
            compute_start_s = time.perf_counter()
            heard: list[int] = []
            messages: list[Any] = []
            if radio is not None:
                heard, messages, weights = self._heard_by_radio(radio, tick)
            came: Callable[[int], bool]
            for j, box in boxes:
                if no_faults:
                    delay, came = 0, box.__contains__
                else:
                    delay = faults.delay_ticks(j, me, tick)
                    came = _came_under_faults(box, faults, j, me)
                sent = select_message(tick, delay, max_age, came)  # faults.py's rule, KinematicSim's too
                values = None if sent is None else box[sent]
                needed = tick - 1 - delay  # what the timing names; older ones only stand in for it
                reason = HEARD if no_faults or needed < 0 else faults.reason(j, me, needed)
                if reason == DROPPED:
                    counters.messages_dropped_by_fault += 1
                elif reason == LOST:
                    counters.messages_lost_by_fault += 1
                elif values is None and needed >= self._first_tick:
                    counters.messages_lost += 1  # did not come: a dead neighbour, a missed deadline
                if values is not None:
                    heard.append(j)
                    messages.append(values)
                    counters.messages_delayed_by_fault += delay > 0
            oldest = tick - self._keep_ticks
            for _, box in boxes:  # drop what can no longer be used
                if box and min(box) < oldest:
                    for k in [k for k in box if k < oldest]:
                        del box[k]
            if radio is None:
                weights = [weight_of[j] for j in heard]
            if act_floats is not None:  # plain floats, no numpy: most of an agent's Python time otherwise
                u_world, message = act_floats(pose.x_m, pose.y_m, pose.theta_rad, messages, weights)
            else:
                inbox = np.array(messages, dtype=np.float64).reshape(len(heard), dim)
                u_world, message = controller.act_one(pose.array(), inbox, np.array(weights))
            if sense is None:
                wheels = wheels_one(u_world, pose.theta_rad, params)
            else:
                u_safe, brake = sense.filtered(tick, u_world, pose.theta_rad)
                wheels = (0.0, 0.0) if brake else wheels_one(u_safe, pose.theta_rad, params)
            message_payload = wire.encode_message(tick, message)
            if run_key is None:
                msg_pub.put(message_payload)
            else:
                msg_pub.put(message_payload, attachment=run_key.tag(msg_key, message_payload))
            cmd_pub.send(tick, wheels)
            counters.compute_s.append(time.perf_counter() - compute_start_s)
            counters.ticks += 1
            counters.commands_sent += 1
            if self._ticks_to_run is not None and tick - self._first_tick + 1 >= self._ticks_to_run:
                self.record["exit_reason"] = "done"  # no sim server: the scenario's duration is over
                return EXIT_DONE

    def _write_record(self) -> None:
        counters, window = self.counters, self._window
        pose_inlet = self._pose_inlet
        self.record.update(
            ticks=counters.ticks,
            last_tick=self._last_tick,
            commands_sent=counters.commands_sent,
            poses={
                "received": counters.poses_received + window.confirmed,
                "invalid": counters.poses_invalid,
                "unauthenticated": counters.poses_unauthenticated,
                "old": counters.poses_old,
                "future": window.future + (window.candidate is not None),  # a pending candidate too
                "taken": pose_inlet.taken if pose_inlet is not None else 0,  # every sample read
                "ring_full": pose_inlet.ring_full if pose_inlet is not None else 0,
                "unread": pose_inlet.unread if pose_inlet is not None else 0,  # came after the last tick
                "skipped": counters.poses_skipped + window.confirmed,
                "jumps": window.confirmed,  # beyond the window, confirmed by the next pose: followed
                "jump_ticks": list(window.jump_ticks),  # the ticks it jumped to (the first ones)
                "recovered": window.recovered,  # old poses taken as the clock again (swarm.runtime.ticks)
            },
            messages={
                "received": counters.messages_received,
                "invalid": counters.messages_invalid,
                "unauthenticated": counters.messages_unauthenticated,
                "old": counters.messages_old,
                "future": counters.messages_future,
                "taken": sum(inlet.taken for inlet in self._msg_inlets.values()),
                "ring_full": sum(inlet.ring_full for inlet in self._msg_inlets.values()),
                "unread": sum(inlet.unread for inlet in self._msg_inlets.values()),
                "lost": counters.messages_lost,
                "late": counters.messages_late,
                "dropped_by_fault": counters.messages_dropped_by_fault,
                "lost_by_fault": counters.messages_lost_by_fault,
                "delayed_by_fault": counters.messages_delayed_by_fault,
            },
            safety_filter=None if self._sense is None else dict(self._sense.counts),
            ticks_waited=counters.ticks_waited,
            neighbour_wait_ms=_stats_ms(counters.neighbour_wait_s),
            compute_ms=_stats_ms(counters.compute_s),
            alive_s=round(time.perf_counter() - self._started_s, 4),
            cpu_s=round(time.process_time(), 4),  # every thread of this process (since the fork)
            main_thread_cpu_s=round(time.thread_time(), 4),  # of the thread running the agent
            heavy_modules=sorted(name for name in ("torch", "pybullet", "numba") if name in sys.modules),
        )
        if self.options.log_dir is None:
            return
        path = Path(self.options.log_dir) / f"agent_{self.robot}.json"
        write_atomically(path, json.dumps(self.record, indent=2) + "\n")
