"""``robot-agent --robot I --connect ENDPOINT [--run RUN]``: the process of one robot.

Without ``--run`` the agent asks ``swarm/*/config/<I>`` and joins the one run whose sim serves
robot I (several runs behind one endpoint: give ``--run``).

``--robots 0-5`` (or ``0,2,4``) starts one process per robot from one launcher: the launcher
imports everything once and forks the agents before any Zenoh session exists (forking after a
session is open hangs the child), which starts tens of agents in a fraction of a second.

Exit status: 0 the run ended (the sim went away or SIGTERM), 1 the agent could not start.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import time
from pathlib import Path

from robot_agent.agent import EXIT_FAILED, AgentOptions, RobotAgent
from swarm import wire
from swarm.procs import die_with_parent


def parse_robots(text: str) -> list[int]:
    """``"3"``, ``"0-5"``, ``"0,2,7-9"`` -> sorted robot ids."""
    robots: set[int] = set()
    for part in text.split(","):
        low, _, high = part.strip().partition("-")
        if not low.isdigit() or (high and not high.isdigit()):
            raise argparse.ArgumentTypeError(f"robot ids like 3, 0-5 or 0,2,7-9, got {text!r}")
        robots.update(range(int(low), int(high or low) + 1))
    return sorted(robots)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="robot-agent",
        description="Run the controller of one robot (or one process per robot with --robots): fetch its "
        "configuration from the sim server over Zenoh, listen only to its own pose and its graph "
        "neighbours, and send wheel commands.",
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--robot", type=int, help="robot id")
    which.add_argument("--robots", type=parse_robots, help="several robot ids (0-5, 0,2,4): one process each")
    parser.add_argument(
        "--connect",
        action="append",
        help="Zenoh endpoint of the sim server, repeatable (default: tcp/127.0.0.1:7447)",
    )
    parser.add_argument(
        "--run",
        help="run id: the key prefix swarm/<run>/ (default: the one run whose sim serves this robot)",
    )
    parser.add_argument(
        "--zenoh-mode", choices=["client", "peer"], default="client", help="session mode (default: client)"
    )
    parser.add_argument("--lease-ms", type=int, default=1000, help="Zenoh lease (default 1000 ms)")
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="seconds to reach the sim")
    parser.add_argument("--log-dir", help="write agent_<i>.json (and agent_<i>.log with --robots) here")
    parser.add_argument("--die-with-parent", action="store_true", help="exit when the parent process dies")
    return parser


def run_one(robot: int, args: argparse.Namespace) -> int:
    options = AgentOptions(
        robot=robot,
        run=args.run,
        connect=args.connect or ["tcp/127.0.0.1:7447"],
        zenoh_mode=args.zenoh_mode,
        lease_ms=args.lease_ms,
        startup_timeout_s=args.startup_timeout,
        log_dir=Path(args.log_dir) if args.log_dir else None,
    )
    agent = RobotAgent(options)
    signal.signal(signal.SIGTERM, agent.request_stop)
    signal.signal(signal.SIGINT, agent.request_stop)
    return agent.run()


def _child(robot: int, args: argparse.Namespace) -> int:
    """In a forked child: own log file, die with the launcher, run the agent."""
    if args.log_dir:
        log = os.open(Path(args.log_dir) / f"agent_{robot}.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
    die_with_parent()
    return run_one(robot, args)


def _exit_reason(log_dir: str | None, robot: int | None) -> str:
    try:
        record = json.loads((Path(log_dir) / f"agent_{robot}.json").read_text())
    except (TypeError, OSError, ValueError):
        return ""
    return f": {record.get('exit_reason')}" if record.get("exit_reason") else ""


def launch(robots: list[int], args: argparse.Namespace) -> int:
    """Fork one agent process per robot and wait for them; SIGTERM/SIGINT are passed on."""
    children: dict[int, int] = {}
    stopping = False

    def forward(signum: int, _frame: object) -> None:
        nonlocal stopping
        stopping = True
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    sys.stdout.flush()
    sys.stderr.flush()
    for robot in robots:
        if stopping:
            break
        pid = os.fork()
        if pid == 0:
            code = EXIT_FAILED
            try:
                code = _child(robot, args)
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(code)
        children[pid] = robot
    worst = 0
    while children:
        try:
            pid, status = os.wait()
        except ChildProcessError:
            break
        except InterruptedError:
            continue
        robot = children.pop(pid, None)
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            why = _exit_reason(args.log_dir, robot)
            print(
                f"robot-agent: robot {robot} (pid {pid}) exited with {code}{why}", file=sys.stderr, flush=True
            )
            worst = max(worst, 1)
    return worst


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.die_with_parent:
        die_with_parent()
    try:
        if args.run is not None:
            wire.check_run_id(args.run)
    except ValueError as error:
        print(f"robot-agent: error: {error}", file=sys.stderr)
        return 2
    if args.log_dir:
        Path(args.log_dir).mkdir(parents=True, exist_ok=True)
    if args.robot is not None:
        return run_one(args.robot, args)
    start_s = time.perf_counter()
    code = launch(args.robots, args)
    elapsed_s = time.perf_counter() - start_s
    print(f"robot-agent: {len(args.robots)} agents ended after {elapsed_s:.1f} s", flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
