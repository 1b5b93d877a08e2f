"""The agent's receive rings (``robot_agent.agent.Inlet``) on a real Zenoh session.

A put to a subscriber of the same session is delivered before ``put`` returns, so what sits in the
ring is known from what was put: the oracle is the list of puts and the ring's capacity (Zenoh's
ring keeps the newest ``capacity`` samples), never the inlet's own counters.
"""

from __future__ import annotations

import signal
import threading

import pytest
import zenoh

from robot_agent.agent import Inlet
from swarm.runtime import wire

CAPACITY = 4


@pytest.fixture
def session():
    session = zenoh.open(wire.session_config("peer"))
    yield session
    session.close()


def _drain(inlet: Inlet) -> list[bytes]:
    taken = []
    while (sample := inlet.take()) is not None:
        payload, attachment = sample
        assert attachment is None  # these tests put none
        taken.append(payload)
    return taken


def test_a_drain_below_capacity_proves_nothing_was_pushed_out(session) -> None:
    inlet = Inlet(session, "test/inlet/a", CAPACITY)
    for round_ in range(5):
        sent = [bytes([round_, k]) for k in range(CAPACITY - 1)]
        for payload in sent:
            session.put("test/inlet/a", payload)
        assert _drain(inlet) == sent  # all of them, in order
    assert inlet.ring_full == 0 and inlet.taken == 5 * (CAPACITY - 1)


def test_a_flood_between_drains_is_flagged(session) -> None:
    inlet = Inlet(session, "test/inlet/b", CAPACITY)
    sent = [bytes([k]) for k in range(CAPACITY + 3)]
    for payload in sent:
        session.put("test/inlet/b", payload)
    assert _drain(inlet) == sent[-CAPACITY:]  # the ring kept the newest: three were pushed out
    assert inlet.ring_full == 1
    session.put("test/inlet/b", b"x")  # a quiet drain afterwards adds nothing
    assert _drain(inlet) == [b"x"] and inlet.ring_full == 1
    for payload in sent[:CAPACITY]:  # exactly full: a drop cannot be excluded, so it counts
        session.put("test/inlet/b", payload)
    assert _drain(inlet) == sent[:CAPACITY] and inlet.ring_full == 2


def test_unread_samples_are_counted_when_it_is_undeclared(session) -> None:
    inlet = Inlet(session, "test/inlet/c", CAPACITY)
    for k in range(3):
        session.put("test/inlet/c", bytes([k]))
    assert inlet.take() == (b"\x00", None)
    inlet.undeclare()
    assert inlet.unread == 2 and inlet.taken == 1


class _Wake(BaseException):
    pass


def test_a_signal_handler_interrupts_the_blocking_recv(session) -> None:
    inlet = Inlet(session, "test/inlet/d", CAPACITY)
    waiting, woken = threading.Event(), threading.Event()

    def handler(*_: object) -> None:
        if waiting.is_set():
            raise _Wake

    previous = signal.signal(signal.SIGUSR1, handler)
    main = threading.get_ident()

    def kick() -> None:  # until the main thread has left recv: no guess at when it entered it
        while not woken.wait(0.05):
            signal.pthread_kill(main, signal.SIGUSR1)

    kicker = threading.Thread(target=kick)
    kicker.start()
    try:
        with pytest.raises(_Wake):
            waiting.set()
            inlet.recv()  # nothing is ever put: only the signal ends the wait
    finally:
        waiting.clear()
        woken.set()
        kicker.join()
        signal.signal(signal.SIGUSR1, previous)
    session.put("test/inlet/d", b"after")
    assert inlet.recv() == (b"after", None) and inlet.taken == 1


def test_a_sample_comes_with_its_attachment(session) -> None:
    """The run key's tag travels in the attachment (swarm.runtime.wire.RunKey): the inlet hands it over."""
    inlet = Inlet(session, "test/inlet/e", CAPACITY)
    session.put("test/inlet/e", b"payload", attachment=b"tag")
    session.put("test/inlet/e", b"bare")
    assert [inlet.take(), inlet.take(), inlet.take()] == [(b"payload", b"tag"), (b"bare", None), None]
