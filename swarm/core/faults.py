"""Link faults as a pure function of (sender, receiver, tick); the results of faulty runs are
``swarm.scenarios.fault_results``.

The design (docs/design.md) asks for runs that prove the decentralization under faults.
The scenario's ``faults`` list holds two families:

- link faults (``drop_link``, ``restore_link``, ``packet_loss``, ``delay``) act on what a robot hears.
  :class:`LinkFaults` turns them into a schedule that both engines read the same way: the robot agents
  of the PyBullet runtime at their transport layer (``robot_agent.agent``) and the batched kinematic
  engine (``swarm.sim.kinematic``), so a fault scenario runs alike on both.
- process faults (``kill_agent``, ``hang_agent``, ``restart_agent``, ``kill_server``) are done to the real
  processes by the runner (``swarm.runtime.distributed``), which logs each one to ``events.jsonl``.

The schedule, in control ticks (sim time ``tick * control_period_s``; a fault at ``at`` seconds acts from
the first tick at or after it, ``until`` ends it before the first tick at or after that time):

- ``heard(sender, receiver, m)``: whether the message ``sender`` broadcast at tick ``m`` reaches
  ``receiver``. Not when the directed link is down at tick ``m`` (``drop_link`` until a ``restore_link``;
  ``direction: one`` on ``link: [i, j]`` means only j stops hearing i) or when a ``packet_loss`` fault active
  at tick ``m`` covering that link draws a loss. The draw is ``u < p`` with ``u`` uniform in [0, 1) from a
  hash of ``(faults_seed, fault index, sender, receiver, m)`` (splitmix64's finaliser chained over the
  key): no shared state and no random stream, so lockstep runs repeat exactly, each agent decides alone
  what it lost, and both engines lose the same packets.
- ``delay_ticks(sender, receiver, k)``: at receiving tick ``k`` the newest message a robot may use from
  that neighbour is the one of tick ``k - 1 - d`` instead of ``k - 1`` (the largest ``ticks`` of the
  ``delay`` faults active at ``k`` that cover the link).

Which message a robot uses (:func:`usable`, :func:`select_message`): the newest heard one among the ticks
``k - 1 - d, ..., k - d - A`` with ``A = sim.message_max_age_ticks`` (default 1 in lockstep: exactly the
message of tick ``k - 1 - d``, as docs/design.md's timing says; 10 in realtime, where messages arrive
when they arrive). A neighbour with no usable message is left out of that tick: the controllers then
normalise by the neighbours actually heard, and a robot that heard nobody holds still.

Importable by a robot agent (numpy only).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np


@dataclass(frozen=True)
class FaultKind:
    """One kind of fault: a ``link`` fault acts in the receiving robots (:class:`LinkFaults`), a
    ``process`` fault is done by the runner of the pybullet engine (``swarm.runtime.distributed``). Keys by
    their short scenario names; every other fault key is refused for that kind."""

    kind: str
    family: Literal["link", "process"]
    required: tuple[str, ...]
    optional: tuple[str, ...] = ()


FAULT_KINDS: dict[str, FaultKind] = {
    fault.kind: fault
    for fault in (
        FaultKind("drop_link", "link", ("at", "link"), ("direction",)),
        FaultKind("restore_link", "link", ("at", "link"), ("direction",)),
        FaultKind("packet_loss", "link", ("p",), ("link", "direction", "at", "until")),
        FaultKind("delay", "link", ("ticks",), ("link", "direction", "at", "until")),
        FaultKind("kill_agent", "process", ("at", "robot")),
        FaultKind("hang_agent", "process", ("at", "robot", "duration")),
        FaultKind("restart_agent", "process", ("at", "robot")),
        FaultKind("kill_server", "process", ("at",)),
    )
}
"""The registry of fault kinds (README, "Faults"): the scenario schema and both engines read it."""

LINK_FAULTS = tuple(kind for kind, fault in FAULT_KINDS.items() if fault.family == "link")
PROCESS_FAULTS = tuple(kind for kind, fault in FAULT_KINDS.items() if fault.family == "process")

HEARD, DROPPED, LOST = 0, 1, 2
"""Why a message did (not) reach its receiver: :meth:`LinkFaults.reason`."""

DEFAULT_MAX_AGE_TICKS = {"lockstep": 1, "realtime": 10}
"""``sim.message_max_age_ticks`` when the scenario leaves it out, per timing mode."""

_MASK64 = (1 << 64) - 1
_GOLDEN, _MIX1, _MIX2 = 0x9E3779B97F4A7C15, 0xBF58476D1CE4E5B9, 0x94D049BB133111EB
_UNIT = 2.0**-53


def _mix(x: int) -> int:
    """splitmix64's step and finaliser (Steele, Lea and Flood 2014) on a 64-bit integer."""
    x = (x + _GOLDEN) & _MASK64
    x = ((x ^ (x >> 30)) * _MIX1) & _MASK64
    x = ((x ^ (x >> 27)) * _MIX2) & _MASK64
    return x ^ (x >> 31)


def _mix_array(x: np.ndarray) -> np.ndarray:
    """:func:`_mix` on a uint64 array (wrapping arithmetic, same bits)."""
    with np.errstate(over="ignore"):
        x = x + np.uint64(_GOLDEN)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(_MIX1)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(_MIX2)
        return x ^ (x >> np.uint64(31))


def loss_uniform(seed: int, fault: int, sender: int, receiver: int, tick: int) -> float:
    """The loss draw of one message: uniform in [0, 1), a pure function of its five integers."""
    h = _mix(_mix(int(seed) & _MASK64) ^ int(fault))
    h = _mix(h ^ int(sender))
    h = _mix(h ^ int(receiver))
    h = _mix(h ^ int(tick))
    return (h >> 11) * _UNIT


def loss_uniform_array(
    seed: int, fault: int, senders: np.ndarray, receivers: np.ndarray, tick: int
) -> np.ndarray:
    """:func:`loss_uniform` for arrays of senders and receivers (broadcast), bit for bit the same."""
    prefix = np.uint64(_mix(_mix(int(seed) & _MASK64) ^ int(fault)))
    h = _mix_array(prefix ^ np.asarray(senders).astype(np.uint64))
    h = _mix_array(h ^ np.asarray(receivers).astype(np.uint64))
    h = _mix_array(h ^ np.uint64(tick))
    return (h >> np.uint64(11)).astype(np.float64) * _UNIT


def tick_of(time_s: float, control_period_s: float) -> int:
    """The first control tick at or after ``time_s``."""
    return max(0, math.ceil(time_s / control_period_s - 1e-9))


def default_max_age_ticks(mode: str) -> int:
    return DEFAULT_MAX_AGE_TICKS.get(mode, 1)


def message_max_age_ticks(sim: Mapping[str, Any] | Any) -> int:
    """``sim.message_max_age_ticks`` of a scenario's ``sim`` (mapping or model), its default if unset."""
    get = sim.get if isinstance(sim, Mapping) else lambda key, default=None: getattr(sim, key, default)
    value = get("message_max_age_ticks")
    return int(value) if value is not None else default_max_age_ticks(get("mode", "lockstep"))


@dataclass(frozen=True)
class _Window:
    """A loss or delay fault over ticks ``[start, end)`` (``end`` None: to the end of the run)."""

    index: int  # position in the scenario's faults list (a key of the loss draw)
    start: int
    end: int | None
    pairs: frozenset[tuple[int, int]] | None  # (sender, receiver); None: every link
    p: float = 0.0
    ticks: int = 0

    def active(self, tick: int) -> bool:
        return self.start <= tick and (self.end is None or tick < self.end)

    def covers(self, sender: int, receiver: int) -> bool:
        return self.pairs is None or (sender, receiver) in self.pairs

    def cover_mask(self, senders: np.ndarray, receivers: np.ndarray) -> np.ndarray | bool:
        if self.pairs is None:
            return True
        mask = np.zeros(np.broadcast_shapes(senders.shape, receivers.shape), dtype=bool)
        for sender, receiver in self.pairs:
            mask |= (senders == sender) & (receivers == receiver)
        return mask


def _directed_pairs(link: Sequence[int], direction: str | None) -> frozenset[tuple[int, int]]:
    """``link: [i, j]`` as (sender, receiver) pairs: both ways, or (``one``) only j hearing i."""
    i, j = int(link[0]), int(link[1])
    return frozenset({(i, j)}) if direction == "one" else frozenset({(i, j), (j, i)})


def _get(fault: Mapping[str, Any] | Any, key: str) -> Any:
    if isinstance(fault, Mapping):
        return fault.get(key)
    return getattr(fault, key, None)


class LinkFaults:
    """The link-fault schedule of a scenario (see the module docstring); immutable, cheap to query.

    ``faults``: the scenario's fault list (``FaultSpec`` objects or their ``model_dump`` mappings, keys
    ``kind, at_s, until_s, link, direction, p, ticks``); process faults are ignored here.
    """

    def __init__(self, faults: Sequence[Mapping[str, Any] | Any], control_period_s: float, seed: int = 0):
        self.control_period_s = float(control_period_s)
        self.seed = int(seed)
        self._losses: list[_Window] = []
        self._delays: list[_Window] = []
        self._down: dict[
            tuple[int, int], list[tuple[int, int | None, int]]
        ] = {}  # pair -> (start, end, fault)
        # (tick, fault index, drop?, pairs)
        link_events: list[tuple[int, int, bool, frozenset[tuple[int, int]]]] = []
        for index, fault in enumerate(faults):
            kind = _get(fault, "kind")
            start = tick_of(_get(fault, "at_s") or 0.0, self.control_period_s)
            until_s = _get(fault, "until_s")
            end = None if until_s is None else tick_of(until_s, self.control_period_s)
            link = _get(fault, "link")
            pairs = None if link is None else _directed_pairs(link, _get(fault, "direction"))
            if kind == "packet_loss":
                self._losses.append(_Window(index, start, end, pairs, p=float(_get(fault, "p"))))
            elif kind == "delay":
                self._delays.append(_Window(index, start, end, pairs, ticks=int(_get(fault, "ticks"))))
            elif kind in ("drop_link", "restore_link"):
                assert pairs is not None  # the schema requires their link
                link_events.append((start, index, kind == "drop_link", pairs))
        down_since: dict[tuple[int, int], tuple[int, int]] = {}  # pair -> (tick, fault index)
        for tick, index, drop, pairs in sorted(link_events, key=lambda event: event[:2]):
            for pair in sorted(pairs):
                if drop and pair not in down_since:
                    down_since[pair] = (tick, index)
                elif not drop and pair in down_since:
                    since, by = down_since.pop(pair)
                    if tick > since:
                        self._down.setdefault(pair, []).append((since, tick, by))
        for pair, (since, by) in down_since.items():
            self._down.setdefault(pair, []).append((since, None, by))

    @classmethod
    def packet_loss(cls, p: float, control_period_s: float, seed: int = 0) -> LinkFaults:
        """Every message on every link lost with probability ``p``, all run long (what the sweeps, the
        benchmarks and the training mean by a packet loss)."""
        return cls([{"kind": "packet_loss", "p": p}], control_period_s, seed)

    @classmethod
    def from_scenario(cls, scenario: Any) -> LinkFaults:
        """From a validated ``swarm.scenarios.scenario.Scenario``."""
        return cls(scenario.faults, scenario.sim.control_period_s, scenario.faults_seed)

    @classmethod
    def from_scenario_dict(cls, data: Mapping[str, Any]) -> LinkFaults:
        """From a resolved scenario mapping (what an agent receives in its ``AgentConfig``)."""
        sim = data.get("sim") or {}
        return cls(data.get("faults") or [], sim.get("control_period_s", 0.05), data.get("faults_seed") or 0)

    @property
    def empty(self) -> bool:
        """No link fault at all: every message is heard at once."""
        return not (self._losses or self._delays or self._down)

    @property
    def max_delay_ticks(self) -> int:
        return max((window.ticks for window in self._delays), default=0)

    # ------------------------------------------------------------------ one link (an agent)
    def reason(self, sender: int, receiver: int, tick: int) -> int:
        """``HEARD``, ``DROPPED`` (link down) or ``LOST`` (packet loss) for the message of ``tick``."""
        for start, end, _ in self._down.get((sender, receiver), ()):
            if start <= tick and (end is None or tick < end):
                return DROPPED
        for window in self._losses:
            if (
                window.active(tick)
                and window.covers(sender, receiver)
                and loss_uniform(self.seed, window.index, sender, receiver, tick) < window.p
            ):
                return LOST
        return HEARD

    def heard(self, sender: int, receiver: int, tick: int) -> bool:
        """Whether ``receiver`` hears the message ``sender`` broadcast at ``tick``."""
        return self.reason(sender, receiver, tick) == HEARD

    def delay_ticks(self, sender: int, receiver: int, tick: int) -> int:
        """Extra ticks of age of the newest message ``receiver`` may use from ``sender`` at ``tick``."""
        return max(
            (w.ticks for w in self._delays if w.active(tick) and w.covers(sender, receiver)), default=0
        )

    # ------------------------------------------------------------------ many links (the batched engine)
    def reasons_array(self, senders: np.ndarray, receivers: np.ndarray, tick: int) -> np.ndarray:
        """:meth:`reason` for broadcast arrays of senders and receivers (int8 codes)."""
        senders, receivers = np.asarray(senders, dtype=np.int64), np.asarray(receivers, dtype=np.int64)
        reasons = np.zeros(np.broadcast_shapes(senders.shape, receivers.shape), dtype=np.int8)
        for (sender, receiver), intervals in self._down.items():
            if any(start <= tick and (end is None or tick < end) for start, end, _ in intervals):
                reasons[(senders == sender) & (receivers == receiver)] = DROPPED
        for window in self._losses:
            if window.active(tick) and window.p > 0:
                draws = loss_uniform_array(self.seed, window.index, senders, receivers, tick)
                reasons[(reasons == HEARD) & window.cover_mask(senders, receivers) & (draws < window.p)] = (
                    LOST
                )
        return reasons

    def delay_array(self, senders: np.ndarray, receivers: np.ndarray, tick: int) -> np.ndarray:
        """:meth:`delay_ticks` for broadcast arrays of senders and receivers."""
        senders, receivers = np.asarray(senders, dtype=np.int64), np.asarray(receivers, dtype=np.int64)
        delays = np.zeros(np.broadcast_shapes(senders.shape, receivers.shape), dtype=np.int64)
        for window in self._delays:
            if window.active(tick):
                delays = np.where(
                    window.cover_mask(senders, receivers), np.maximum(delays, window.ticks), delays
                )
        return delays

    def down_matrix(self, count: int, tick: int) -> np.ndarray:
        """``(N, N)`` bool, ``[receiver, sender]``: the link certainly carries nothing at ``tick``
        (dropped, or a packet loss with ``p = 1``)."""
        senders, receivers = np.arange(count)[None, :], np.arange(count)[:, None]
        down = self.reasons_array(senders, receivers, tick) == DROPPED
        for window in self._losses:
            if window.active(tick) and window.p >= 1.0:
                down |= np.broadcast_to(window.cover_mask(senders, receivers), down.shape)
        np.fill_diagonal(down, False)
        return down

    def live_adjacency(self, adjacency: np.ndarray, tick: int) -> np.ndarray:
        """The graph without the edges that carry nothing either way at ``tick``. An edge down in one
        direction only stays: information still flows the other way."""
        adjacency = np.asarray(adjacency, dtype=np.float64)
        down = self.down_matrix(len(adjacency), tick)
        return np.where(down & down.T, 0.0, adjacency)


def usable_ticks(tick: int, delay_ticks: int, max_age_ticks: int) -> range:
    """Message ticks a robot may use from a neighbour at receiving ``tick``, newest first:
    ``tick - 1 - delay`` back to ``tick - delay - max_age`` (never below 0)."""
    newest = tick - 1 - delay_ticks
    return range(newest, max(newest - max_age_ticks, -1), -1)


def usable(age_ticks: Any, delay_ticks: Any, max_age_ticks: int, heard: Any) -> Any:
    """The message-selection rule, elementwise (ints and bools, or numpy arrays): a message a neighbour
    sent ``age_ticks`` before the receiving tick may be used when it was heard (it came, and the
    schedule neither dropped nor lost it), it is not newer than the link's delay allows
    (``age >= 1 + delay``) and not older than the age limit beyond that (``age <= delay + max_age``).
    A robot uses the newest usable message of each neighbour (:func:`select_message`); both engines
    apply this rule, the robot agents per neighbour and ``KinematicSim`` over whole arrays."""
    return heard & (age_ticks >= 1 + delay_ticks) & (age_ticks <= delay_ticks + max_age_ticks)


def select_message(
    tick: int, delay_ticks: int, max_age_ticks: int, heard: Callable[[int], bool]
) -> int | None:
    """Which message robot i uses from neighbour j at receiving ``tick``: the tick of the newest one
    :func:`usable` admits, ``heard(m)`` saying whether j's message of tick m came and was not lost
    to a fault; None: j is left out of this tick."""
    for sent in usable_ticks(tick, delay_ticks, max_age_ticks):
        if usable(tick - sent, delay_ticks, max_age_ticks, heard(sent)):
            return sent
    return None
