"""Which ticks a receiver can believe: the acceptance window of poses, messages and commands.

Every sample carries the tick it belongs to, and nothing on the wire proves who sent it (without
access control anyone may publish on any key; with it, a robot may still publish anything on its
own keys). A receiver therefore accepts a tick only inside a window it can justify from its own
clock, so that one sample dated far ahead can neither become "the newest" (which would make every
genuine sample after it look old) nor be waited for:

* The sim server publishes the poses of tick k+1 only once every live agent's command of tick k is
  in or ``sim.deadline_s`` has passed (lockstep), or at the wall-clock boundary of tick k+1 and not
  before (realtime). An agent that received the pose of tick k at time t_k and has sent its command
  of tick k therefore sees, at time t, no genuine tick beyond

      k + 1 + floor((t - t_k) / step_s),   step_s = min(sim.deadline_s, sim.control_period_s)   (1)

  (while its liveliness token is up; a neighbour is never ahead of the sim). :func:`tick_limit`
  adds one tick of margin (sending and receiving are not instantaneous).
* The server knows its own tick: a command dated after it is *future* (``sim_server.server``).

A genuine jump beyond (1) happens only when the server stopped waiting for this agent: its token
went (the process was frozen past its lease, the network was cut) or it is a restarted agent whose
first pose is that of a later tick. :class:`PoseWindow` accepts such a jump only once a second pose
confirms it (a later tick within (1) counted from the first), so one forged pose cannot move the
agent's clock: it stays a *candidate* until a pose inside the window supersedes it and is then
counted as *future*. Tick 0 needs no confirmation (every run starts there); before its first pose
an agent believes no other tick (:meth:`PoseWindow.limit` is 0).

The window only bounds what one forged pose can do. Where anyone may publish on a pose key (no access
control) and samples are not authenticated (no run key: ``swarm.runtime.wire.RunKey``), a burst of
poses each inside the window of the one before can still walk it ahead, and the genuine poses then
look *old*. The window therefore recovers: ``RECOVER_AFTER`` consecutive old poses whose ticks
advance one by one (the sim's sequence; a replay does not advance) are taken as the genuine clock
and the window falls back to them (``recovered``), so such a walk freezes a robot for about
``RECOVER_AFTER`` ticks. With the run key forged poses never reach the window.
"""

from __future__ import annotations

import math

RECOVER_AFTER = 3
"""Consecutive old poses, each one tick after the one before, after which the window falls back to them."""

MARGIN_TICKS = 1
"""Added to (1): a sample is on its way while the receiver reads its clock."""


def tick_limit(tick: int, elapsed_s: float, step_s: float) -> int:
    """The largest genuine tick a receiver that got tick ``tick`` ``elapsed_s`` ago can see, eq. (1)."""
    return tick + 1 + MARGIN_TICKS + math.floor(max(elapsed_s, 0.0) / step_s)


def step_s_of(sim: dict) -> float:
    """``step_s`` of eq. (1) from a scenario's ``sim`` block (as served in the agent's config)."""
    period_s = float(sim.get("control_period_s", 0.05))
    return min(float(sim.get("deadline_s", 1.0)), period_s)


JUMP_TICKS_KEPT = 100
"""How many of the ticks an agent's clock jumped to (``PoseWindow.jump_ticks``) its record keeps."""

ACCEPT, OLD, FUTURE, CANDIDATE = "accept", "old", "future", "candidate"


class PoseWindow:
    """The agent's clock: the tick of its newest genuine pose and when it came (eq. 1).

    :meth:`offer` classifies a pose tick: ``ACCEPT`` (newer and inside the window, confirming the
    candidate, or the ``RECOVER_AFTER``-th of a run of old poses one tick apart), ``OLD`` (not newer
    than the newest accepted), ``CANDIDATE`` (beyond the window, held until a second pose confirms
    it). ``future`` counts candidates that were superseded (forged, or dated ahead for any other
    reason), ``confirmed`` those a later pose confirmed (genuine, received but skipped),
    ``recovered`` the falls back to a run of old poses; :meth:`close` counts a candidate still
    pending as future.
    """

    __slots__ = (
        "at_s",
        "candidate",
        "candidate_at_s",
        "confirmed",
        "future",
        "jump_ticks",
        "old_run",
        "old_tick",
        "recovered",
        "step_s",
        "tick",
    )

    def __init__(self, step_s: float):
        self.step_s = step_s
        self.tick = -1  # the newest accepted tick
        self.at_s = 0.0  # when it came (receiver's monotonic clock)
        self.candidate: int | None = None
        self.candidate_at_s = 0.0
        self.future = 0
        self.confirmed = 0  # candidates a later pose confirmed: genuine, counted as received
        self.jump_ticks: list[int] = []  # the first JUMP_TICKS_KEPT confirmed candidates: clock jumps
        self.recovered = 0  # times RECOVER_AFTER consecutive old poses became the clock again
        self.old_tick = -1  # the tick of the last old pose, and how many in a row came one tick apart
        self.old_run = 0

    def limit(self, now_s: float) -> int:
        """The largest tick a genuine sample may carry now (messages use it too)."""
        if self.tick < 0:
            return 0  # before the first pose: only tick 0 is believed without confirmation
        return tick_limit(self.tick, now_s - self.at_s, self.step_s)

    def offer(self, tick: int, now_s: float) -> str:
        if tick <= self.tick:
            self.old_run = self.old_run + 1 if tick == self.old_tick + 1 else 1
            self.old_tick = tick
            if self.old_run < RECOVER_AFTER:
                return OLD
            self.recovered += 1  # the window had been walked ahead: back to the sequence that goes on
            self.candidate, self.old_run = None, 0
            self.tick, self.at_s = tick, now_s
            return ACCEPT
        self.old_run = 0
        candidate = self.candidate
        if tick <= self.limit(now_s) or (
            candidate is not None
            and candidate < tick <= tick_limit(candidate, now_s - self.candidate_at_s, self.step_s)
        ):
            if candidate is not None:  # confirmed (an earlier tick: genuine) or superseded
                if candidate < tick:
                    self.confirmed += 1
                    if len(self.jump_ticks) < JUMP_TICKS_KEPT:
                        self.jump_ticks.append(candidate)
                else:
                    self.future += 1
            self.candidate = None
            self.tick, self.at_s = tick, now_s
            return ACCEPT
        if candidate is not None:
            self.future += 1  # replaced by a newer candidate
        self.candidate, self.candidate_at_s = tick, now_s
        return CANDIDATE

    def close(self) -> None:
        if self.candidate is not None:
            self.future += 1
            self.candidate = None
