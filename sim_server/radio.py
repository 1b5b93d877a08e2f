"""The sim's radio: who hears whom on a disk graph in the PyBullet runtime.

On a fixed graph each agent subscribes to its graph neighbours' message keys, and the Zenoh router's
access control enforces that it hears no one else. A disk graph's links follow the robots, so no
fixed subscription can say who is in range: here the sim server plays the radio medium. Every agent
publishes its message on its own key as always; only the server may subscribe to those keys (the
access-control policy, ``swarm.runtime.acl``). For tick k the server sends robot i, on
``robot/<i>/inbox`` (a key only agent i may read), the messages of the robots it hears, by the
kinematic engine's rule (``swarm.sim.kinematic``, docs/design.md): robot i hears robot j's message of
tick m when their axles were within the disk radius at tick m (the poses the server published for m)
and the link faults let it through; of those it uses the newest that ``swarm.core.faults.select_message``
admits (tick k-1, or k-1-d under a delay fault, or an older one within the message age when that did
not come), exactly as an agent on a fixed graph picks from its own subscriptions.

Counts per inbox (``swarm.runtime.wire.INBOX_COUNTS``): messages of in-range robots that a link fault
dropped or lost, that came late under a delay fault, and that never reached the radio (a dead or silent
sender); the agents add them to their own counters, so the run's summary counts them as on a fixed
graph.
"""

from __future__ import annotations

import numpy as np

from swarm.core import graphs
from swarm.core.faults import DROPPED, HEARD, LOST, LinkFaults, select_message


class Radio:
    """Messages by sender and tick, the disk graph of every recent tick, and each robot's inbox."""

    def __init__(self, count: int, radius_m: float, faults: LinkFaults, max_age_ticks: int):
        self.count = int(count)
        self.radius_m = float(radius_m)
        self.faults = faults
        self.max_age_ticks = int(max_age_ticks)
        self.keep_ticks = faults.max_delay_ticks + self.max_age_ticks + 2
        self.boxes: list[dict[int, np.ndarray]] = [{} for _ in range(self.count)]
        self.links: dict[int, np.ndarray] = {}  # tick -> (N, N) bool: within the radius at that tick

    def positions(self, tick: int, axles_m: np.ndarray) -> None:
        """The axle positions ``(N, 2)`` published for ``tick``: its disk graph."""
        self.links[tick] = graphs.disk(np.asarray(axles_m, dtype=np.float64), self.radius_m) > 0
        for old in [k for k in self.links if k < tick - self.keep_ticks]:
            del self.links[old]

    def offer(self, sender: int, tick: int, values: np.ndarray) -> None:
        """Robot ``sender``'s message of ``tick``."""
        box = self.boxes[sender]
        box[tick] = values
        for old in [k for k in box if k < tick - self.keep_ticks]:
            del box[old]

    def _linked(self, sender: int, receiver: int, tick: int) -> bool:
        graph = self.links.get(tick)
        return graph is not None and bool(graph[receiver, sender])

    def inbox(self, receiver: int, tick: int) -> tuple[list[int], list[np.ndarray], list[int]]:
        """Robot ``receiver``'s inbox for ``tick``: the senders it hears (index order), their messages
        and the counts of ``INBOX_COUNTS`` (module docstring)."""
        faults, empty = self.faults, self.faults.empty
        senders, messages = [], []
        dropped = lost_by_fault = delayed = lost = 0
        in_range = np.zeros(self.count, dtype=bool)
        for graph in self.links.values():  # a robot never in range in the kept ticks sends it nothing
            in_range |= graph[receiver]
        in_range[receiver] = False
        for sender in np.flatnonzero(in_range).tolist():
            box = self.boxes[sender]
            delay = 0 if empty else faults.delay_ticks(sender, receiver, tick)

            def came(sent: int, sender: int = sender, box: dict = box) -> bool:
                return (
                    sent in box
                    and self._linked(sender, receiver, sent)
                    and (empty or faults.heard(sender, receiver, sent))
                )

            sent = select_message(tick, delay, self.max_age_ticks, came)
            needed = tick - 1 - delay  # what the timing names; older ones only stand in for it
            if needed >= 0 and self._linked(sender, receiver, needed):
                reason = HEARD if empty else faults.reason(sender, receiver, needed)
                if reason == DROPPED:
                    dropped += 1
                elif reason == LOST:
                    lost_by_fault += 1
                elif sent is None:
                    lost += 1
            if sent is not None:
                senders.append(sender)
                messages.append(box[sent])
                delayed += delay > 0
        return senders, messages, [dropped, lost_by_fault, delayed, lost]
