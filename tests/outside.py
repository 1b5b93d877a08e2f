"""An outside Zenoh client that imports none of the project's code.

It knows only what ``docs/distributed-runtime.md`` documents: the key space ``swarm/<run>/...`` and the
msgpack payloads (``"v": 1``; pose ``k t x y th``, command ``k l r``, message ``k m`` with ``m``
little-endian float64 bytes). Tests and ``bench/chaos.py`` use it to send forged, replayed and
malformed samples from a process of their own, so that what the receivers count is checked against
what an independent sender did, not against the project's own decoders.

As a script: ``python tests/outside.py forge --endpoint E --run R --at-tick T --ahead A --pose 1
--msg 2 --cmd 3 [--credentials FILE] --out sent.json`` waits for robot ``--watch``'s pose of tick T,
then puts, once each, a genuine sample it received (robot 1's pose, agent 2's message, robot 3's
command) with its tick moved ``A`` ticks ahead, and writes what it sent.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import struct
import sys
import time
from pathlib import Path

import msgpack
import zenoh

SCHEMA_VERSION = 1


def pose_key(run: str, robot: int) -> str:
    return f"swarm/{run}/robot/{robot}/pose"


def cmd_key(run: str, robot: int) -> str:
    return f"swarm/{run}/robot/{robot}/cmd"


def msg_key(run: str, robot: int) -> str:
    return f"swarm/{run}/agent/{robot}/msg"


def pack(body: dict) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def pose(tick: int, x: float, y: float, theta: float) -> bytes:
    return pack({"v": SCHEMA_VERSION, "k": tick, "t": tick * 0.05, "x": x, "y": y, "th": theta})


def command(tick: int, left: float, right: float) -> bytes:
    return pack({"v": SCHEMA_VERSION, "k": tick, "l": left, "r": right})


def message(tick: int, values: list[float]) -> bytes:
    return pack({"v": SCHEMA_VERSION, "k": tick, "m": struct.pack(f"<{len(values)}d", *values)})


def tick_of(payload: bytes) -> int | None:
    try:
        body = msgpack.unpackb(payload, raw=False)
        return int(body["k"])
    except Exception:
        return None


def moved(payload: bytes, ahead: int) -> bytes:
    """The same sample with its tick ``ahead`` ticks later."""
    body = msgpack.unpackb(payload, raw=False)
    body["k"] = int(body["k"]) + ahead
    return pack(body)


def open_session(endpoint: str, credentials: str | None = None, deadline_s: float = 60.0) -> zenoh.Session:
    """A client session to ``endpoint``, retried until ``deadline_s`` from now (a loaded machine may
    refuse a connection for a moment: "Unable to connect")."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    if credentials:
        user, password = Path(credentials).read_text().strip().split(":", 1)
        config.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": password}))
    give_up_s, delay_s = time.monotonic() + deadline_s, 0.05
    while True:
        try:
            return zenoh.open(config)
        except zenoh.ZError:
            if time.monotonic() + delay_s > give_up_s:
                raise
            time.sleep(delay_s)
            delay_s = min(2 * delay_s, 1.0)


def latest(subscriber) -> bytes | None:
    payload = None
    while (sample := subscriber.try_recv()) is not None:
        payload = sample.payload.to_bytes()
    return payload


def server_address(log: Path, timeout_s: float = 120.0) -> tuple[str, str]:
    """``(endpoint, run)`` from the sim server's first log line, once it is there
    (``sim_server: run R: N robots, listening on ['E']``)."""
    pattern = re.compile(r"run (\S+): \d+ robots, listening on \['([^']+)'")
    give_up_s = time.monotonic() + timeout_s
    while time.monotonic() < give_up_s:
        match = pattern.search(log.read_text(errors="replace")) if log.exists() else None
        if match:
            return match.group(2), match.group(1)
        time.sleep(0.01)
    raise SystemExit(f"{log}: no sim server address within {timeout_s:g} s")


def forge(args: argparse.Namespace) -> dict:
    """Wait for tick ``at_tick`` on robot ``watch``'s pose, then put the forged samples once each."""
    if args.server_log is not None:  # started beside the run: connect as soon as the server listens
        args.endpoint, args.run = server_address(args.server_log)
    run, ahead = args.run, args.ahead
    session = open_session(args.endpoint, args.credentials)
    ring = zenoh.handlers.RingChannel
    watch = session.declare_subscriber(pose_key(run, args.watch), ring(4))
    sources = {}
    for kind, key_of, robot in (
        ("pose", pose_key, args.pose),
        ("msg", msg_key, args.msg),
        ("cmd", cmd_key, args.cmd),
    ):
        if robot is not None:
            sources[kind] = (key_of(run, robot), session.declare_subscriber(key_of(run, robot), ring(4)))
    sent: dict[str, dict] = {}
    give_up_s = time.monotonic() + args.timeout
    genuine: dict[str, bytes] = {}
    last_pose_s = time.monotonic()
    while time.monotonic() < give_up_s and len(sent) < len(sources):
        payload = latest(watch)
        tick = tick_of(payload) if payload is not None else None
        if tick is not None:
            last_pose_s = time.monotonic()
        elif time.monotonic() - last_pose_s > args.quiet_s:
            break  # the run is over (or never started): nothing to forge into
        for kind, (_, subscriber) in sources.items():
            newest = latest(subscriber)
            if newest is not None:
                genuine[kind] = newest
        if tick is not None and tick >= args.at_tick:
            for kind, (key, _) in sources.items():
                if kind in sent:
                    continue
                if kind not in genuine:  # under access control the rogue may not see this key
                    if not args.blind:
                        continue
                    genuine[kind] = {
                        "pose": pose(tick, 0.0, 0.0, 0.0),
                        "cmd": command(tick, 0.4, -0.4),
                        "msg": message(tick, [0.0] * args.dim),
                    }[kind]
                forged = moved(genuine[kind], ahead)
                tag = None  # without the run key the tag cannot be made: a receiver drops it unread
                if args.run_key is not None:  # an insider: keyed BLAKE2b-128 of key, NUL and payload
                    digest = hashlib.blake2b(key=bytes.fromhex(args.run_key), digest_size=16)
                    digest.update(key.encode() + b"\x00" + forged)
                    tag = digest.digest()
                session.put(key, forged, attachment=tag, congestion_control=zenoh.CongestionControl.BLOCK)
                sent[kind] = {"key": key, "tick": tick_of(forged), "at_tick": tick}
        time.sleep(0.001)
    # A query the sim answers, asked after the last put, is answered once the router has taken every
    # put before it (tests/test_fuzz.py): then the session may close without dropping any.
    flush_until_s = time.monotonic() + (30 if sent else 0)
    while time.monotonic() < flush_until_s:
        if any(reply.ok is not None for reply in session.get(f"swarm/{run}/config/0", timeout=5.0)):
            break
    for _, subscriber in sources.values():
        subscriber.undeclare()
    watch.undeclare()
    session.close()
    return {"sent": sent}


def alive_key(run: str, robot: int) -> str:
    return f"swarm/{run}/alive/agent/{robot}"


def config_key(run: str, robot: int) -> str:
    return f"swarm/{run}/config/{robot}"


def with_values(payload: bytes, value: float) -> bytes:
    """The same message with every entry of its vector set to ``value`` (same tick)."""
    body = msgpack.unpackb(payload, raw=False)
    size = len(body["m"]) // 8
    body["m"] = struct.pack(f"<{size}d", *([value] * size))
    return pack(body)


def all_with_attachment(subscriber) -> list[tuple[bytes, bytes | None]]:
    """Every queued sample's payload and attachment (a genuine sample's authentication tag: an attacker
    who sees it may copy it), oldest first."""
    samples = []
    while (sample := subscriber.try_recv()) is not None:
        attachment = sample.attachment
        samples.append((sample.payload.to_bytes(), None if attachment is None else attachment.to_bytes()))
    return samples


def flush(session, run: str, watch, report: dict) -> None:
    """Wait until the router has taken every put so far, and note then the run's tick.

    A query the sim answers, asked after the last put, is answered once the router has taken every put
    before it (tests/test_fuzz.py): then the session may close without dropping any. ``flushed_tick``:
    the first pose of robot ``--watch`` that comes after the answer (None: none came within 3 s, the
    run was over). A starved attacker whose puts reached the router only after the agents had left
    cannot expect them counted: the tests judge exact counts only when this tick left the agents time
    to read them."""
    flush_until_s, flushed = time.monotonic() + 30, False
    while not flushed and time.monotonic() < flush_until_s:
        flushed = any(reply.ok is not None for reply in session.get(config_key(run, 0), timeout=5.0))
    report["flushed_tick"] = None
    if flushed:
        while watch.try_recv() is not None:  # queued before the answer or just after: older
            pass
        pose_until_s = time.monotonic() + 3.0
        while report["flushed_tick"] is None and time.monotonic() < pose_until_s:
            payload = latest(watch)
            if payload is not None:
                report["flushed_tick"] = tick_of(payload)
            time.sleep(0.005)


def attack(args: argparse.Namespace) -> dict:
    """One attack of the issue's list (``--kind``), from tick ``--at-tick`` on robot ``--watch``'s poses:

    * ``future2``: two poses dated 10^6 and 10^6 + 1 ticks ahead, put on the wildcard pose key;
    * ``walk``: 40 poses of robot ``--robot`` dated k+1 ... k+40, in one burst;
    * ``near``: poses dated k+1 and k+2 on the wildcard pose key;
    * ``replay``: agent ``--robot``'s messages of ticks ``--at-tick`` ... ``--at-tick`` + ``--ticks`` - 1,
      each put again unchanged and again with other values the moment it is seen (before the next
      genuine one); a starved attacker skips the ones it saw too late (``copied_ticks`` names those
      it put);

    Every forged sample carries the attachment of the genuine sample it was made from (copying what
    a subscriber sees is all an outsider can do to look genuine).
    * ``flood-pose`` / ``flood-msg``: ``--rate`` samples per second (a genuine one of robot ``--robot``
      with its tick moved +1) until tick ``--at-tick`` + ``--ticks`` or ``--most`` samples;
    * ``zombie``: a liveliness token on agent ``--robot``'s key, held until the run ends;
    * ``config``: a queryable on every robot's config key answering the sim's own configuration with
      ``gain`` set to -1 (declared once the sim answers; the agents must come after it).
    """
    if args.server_log is not None:
        args.endpoint, args.run = server_address(args.server_log)
    run, kind, robot = args.run, args.kind, args.robot
    session = open_session(args.endpoint, args.credentials)
    ring = zenoh.handlers.RingChannel
    report: dict = {"kind": kind, "sent": 0}
    entities: list = []
    if kind == "zombie":
        entities.append(session.liveliness().declare_token(alive_key(run, robot)))
    if kind == "config":
        configs = {}
        for i in range(args.count):
            while i not in configs:
                for reply in session.get(config_key(run, i), timeout=5.0):
                    if reply.ok is not None:
                        body = msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
                        body["gain"] = -1.0
                        configs[i] = pack(body)

        def answer(query) -> None:
            i = int(str(query.key_expr).rsplit("/", 1)[-1])
            if i in configs:
                query.reply(config_key(run, i), configs[i])
                report["sent"] += 1

        entities.append(session.declare_queryable(f"swarm/{run}/config/*", answer))
        Path(args.ready).write_text("ready")
    watch = session.declare_subscriber(pose_key(run, args.watch), ring(64))
    own = session.declare_subscriber(pose_key(run, robot), ring(64))
    msgs = session.declare_subscriber(msg_key(run, robot), ring(64))
    entities += [watch, own, msgs]
    give_up_s, last_pose_s = time.monotonic() + args.timeout, time.monotonic()
    done = False
    # each sample seen is kept with its attachment (the run's tag), which a forgery must carry too
    newest_pose: tuple[bytes, bytes | None] | None = None
    newest_msg: tuple[bytes, bytes | None] | None = None
    replayed_tick = -1  # replay: the tick of the last message put again
    queued_msgs: list[tuple[bytes, bytes | None]] = []  # replay: the messages seen since the last poll
    period_s = 1.0 / args.rate if args.rate else 0.0

    block = zenoh.CongestionControl.BLOCK  # what it counts as sent is what the router took

    def put(key: str, payload: bytes, attachment: bytes | None) -> None:
        session.put(key, payload, attachment=attachment, congestion_control=block)

    next_s = time.monotonic()
    while time.monotonic() < give_up_s:
        if done and report["sent"] and kind != "config" and "flushed_tick" not in report:
            flush(session, run, watch, report)  # at once: when the router took the puts is the point
        payload = latest(watch)
        tick = tick_of(payload) if payload is not None else None
        for got in all_with_attachment(own):
            newest_pose = got
        for got in all_with_attachment(msgs):  # every one queued: a starved replay still sees each
            newest_msg = got
            queued_msgs.append(got)
        del queued_msgs[:-64]  # the ring's size: older ones the next poll no longer needs
        if tick is not None:
            last_pose_s = time.monotonic()
        elif time.monotonic() - last_pose_s > args.quiet_s:
            break  # the run is over
        now_tick = tick_of(newest_pose[0]) if newest_pose is not None else None
        if done or now_tick is None or now_tick < args.at_tick:
            time.sleep(0.001)
            continue
        assert newest_pose is not None  # now_tick came from it
        if kind in ("future2", "near"):
            offsets = (10**6, 10**6 + 1) if kind == "future2" else (1, 2)
            for offset in offsets:
                put(f"swarm/{run}/robot/*/pose", moved(newest_pose[0], offset), newest_pose[1])
                report["sent"] += 1
            report["at_tick"], done = now_tick, True
        elif kind == "walk":
            for offset in range(1, 41):
                put(pose_key(run, robot), moved(newest_pose[0], offset), newest_pose[1])
                report["sent"] += 1
            report["at_tick"], done = now_tick, True
        elif kind == "replay" and newest_msg is not None:
            last_tick = args.at_tick + args.ticks - 1  # only messages of ticks at_tick ... last_tick:
            # a starved attacker must not replay what its ring still holds once the run is over
            for message, tag in queued_msgs:  # in order: each seen message of the window, put again at once
                msg_tick = tick_of(message)
                if msg_tick is not None and max(replayed_tick + 1, args.at_tick) <= msg_tick <= last_tick:
                    put(msg_key(run, robot), message, tag)  # before the next genuine one
                    put(msg_key(run, robot), with_values(message, 1000.0), tag)
                    replayed_tick = msg_tick
                    report["copies"] = report.get("copies", 0) + 1
                    report.setdefault("copied_ticks", []).append(msg_tick)
                    report["sent"] += 2
                    report.setdefault("at_tick", msg_tick)
            queued_msgs.clear()
            msg_tick = tick_of(newest_msg[0])
            done = msg_tick is not None and (msg_tick >= last_tick or report.get("copies", 0) >= args.ticks)
        elif kind in ("flood-pose", "flood-msg"):
            source = newest_pose if kind == "flood-pose" else newest_msg
            key = pose_key(run, robot) if kind == "flood-pose" else msg_key(run, robot)
            if now_tick >= args.at_tick + args.ticks or report["sent"] >= args.most:
                done = True
                continue
            if source is None:
                continue
            forged, tag = moved(source[0], 1), source[1]
            while time.monotonic() >= next_s and report["sent"] < args.most:  # paced: catches up
                put(key, forged, tag)
                report["sent"] += 1
                next_s += period_s
            time.sleep(0.0002)
        else:
            time.sleep(0.001)
    if report["sent"] and kind != "config" and "flushed_tick" not in report:
        flush(session, run, watch, report)
    for entity in reversed(entities):
        entity.undeclare()
    session.close()
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    f = sub.add_parser("forge", help="put genuine samples with their tick moved ahead")
    f.add_argument("--endpoint")
    f.add_argument("--run")
    f.add_argument("--server-log", type=Path, help="read --endpoint and --run from this sim_server.log")
    f.add_argument("--watch", type=int, default=0, help="robot whose pose gives the current tick")
    f.add_argument("--at-tick", type=int, default=20)
    f.add_argument("--ahead", type=int, default=10**6)
    f.add_argument("--pose", type=int)
    f.add_argument("--msg", type=int)
    f.add_argument("--cmd", type=int)
    f.add_argument("--dim", type=int, default=2, help="message length when none was seen (--blind)")
    f.add_argument("--blind", action="store_true", help="forge a key even if no genuine sample was seen")
    f.add_argument("--credentials")
    f.add_argument("--run-key", help="sign the forged samples with this run key (hex): an insider")
    f.add_argument("--timeout", type=float, default=120.0)
    f.add_argument("--quiet-s", type=float, default=10.0, help="give up after this long without a pose")
    f.add_argument("--out", type=Path, required=True)
    a = sub.add_parser("attack", help="one attack (see attack())")
    a.add_argument("--kind", required=True)
    a.add_argument("--endpoint")
    a.add_argument("--run")
    a.add_argument("--server-log", type=Path)
    a.add_argument("--watch", type=int, default=0)
    a.add_argument("--robot", type=int, default=0)
    a.add_argument("--count", type=int, default=6, help="robots (config)")
    a.add_argument("--at-tick", type=int, default=20)
    a.add_argument("--ticks", type=int, default=100, help="flood length in ticks; replay: messages")
    a.add_argument("--rate", type=float, default=12_000.0, help="flood samples per second")
    a.add_argument("--most", type=int, default=10**9, help="flood: stop after this many samples")
    a.add_argument("--ready", default="/dev/null", help="file written once a config queryable is up")
    a.add_argument("--credentials")
    a.add_argument("--timeout", type=float, default=240.0)
    a.add_argument("--quiet-s", type=float, default=10.0)
    a.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.server_log is None and (args.endpoint is None or args.run is None):
        parser.error("give --endpoint and --run, or --server-log")
    report = forge(args) if args.command == "forge" else attack(args)
    args.out.write_text(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
