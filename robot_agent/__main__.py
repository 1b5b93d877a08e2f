"""``robot-agent --robot I --connect ENDPOINT [--run RUN]``: the process of one robot.

Without ``--run`` the agent asks ``swarm/*/config/<I>`` and joins the one run whose sim serves
robot I (several runs behind one endpoint: give ``--run``).

``--robots 0-5`` (or ``0,2,4``) starts one process per robot from one launcher: the launcher
imports everything once and forks the agents before any Zenoh session exists (forking after a
session is open hangs the child), which starts tens of agents in a fraction of a second.

With ``sim.acl`` (``swarm.runtime.acl``) the sim server admits only authenticated agents: give
``--credentials FILE`` (lines ``user:password``; ``{robot}`` in FILE stands for the robot id, one file
per robot) or ``--user`` and ``--password``.

Exit status: 0 the run ended (the sim went away or SIGTERM), 1 the agent could not start (one line on
stderr says why: no sim at the endpoint within ``--startup-timeout``, refused credentials, a robot id
the run does not have), 2 bad command-line input.
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

import zenoh

from robot_agent.agent import EXIT_FAILED, AgentOptions, RobotAgent
from swarm.core.exit_codes import ExitCode
from swarm.runtime import acl, tls, wire
from swarm.runtime.procs import die_with_parent
from swarm.runtime.usage import OneLineArgumentParser, configure_logging, one_line


def parse_robots(text: str) -> list[int]:
    """``"3"``, ``"0-5"``, ``"0,2,7-9"`` -> sorted robot ids."""
    robots: set[int] = set()
    for part in text.split(","):
        low, _, high = part.strip().partition("-")
        if not low.isdigit() or (high and not high.isdigit()):
            raise argparse.ArgumentTypeError(f"robot ids like 3, 0-5 or 0,2,7-9, got {text!r}")
        robots.update(range(int(low), int(high or low) + 1))
    return sorted(robots)


def robot_id(text: str) -> int:
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"a robot id is a number >= 0, got {text!r}")
    return int(text)


def positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"seconds > 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineArgumentParser(
        prog="robot-agent",
        description="Run the controller of one robot (or one process per robot with --robots): fetch its "
        "configuration from the sim server over Zenoh, listen only to its own pose and its graph "
        "neighbours, and send wheel commands.",
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--robot", type=robot_id, help="robot id")
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
    parser.add_argument(
        "--startup-timeout",
        type=positive_seconds,
        default=60.0,
        help="seconds to reach the sim and get the configuration, then give up (default 60)",
    )
    parser.add_argument(
        "--credentials",
        help="file of user:password lines for a sim with sim.acl ({robot} in the path: the robot id); "
        "the line of user robot-<i>, or the only line",
    )
    parser.add_argument("--user", help="Zenoh user name (sim.acl; default with --password: robot-<i>)")
    parser.add_argument("--password", help="Zenoh password (sim.acl; prefer --credentials: not in ps)")
    parser.add_argument(
        "--tls", help="directory with the run's ca.pem and this robot's robot-<i>.{pem,key} (tls/ endpoints)"
    )
    parser.add_argument("--log-dir", help="write agent_<i>.json (and agent_<i>.log with --robots) here")
    parser.add_argument("--die-with-parent", action="store_true", help="exit when the parent process dies")
    parser.add_argument(
        "--nice",
        type=int,
        default=0,
        help="add this to the agents' niceness before they start (0-19; the runner gives 5: the sim server,"
        " on the critical path of every tick, then wins a contended core)",
    )
    ros = parser.add_argument_group("ROS 2 robots (docs/ros2.md; needs the ros2 extra: rosbags)")
    ros.add_argument(
        "--ros2",
        action="store_true",
        help="the robot is a ROS 2 robot: read its pose from <ns>/odom (nav_msgs/Odometry) and publish "
        "geometry_msgs/Twist on <ns>/cmd_vel, as rmw_zenoh maps them (scenario key ros2)",
    )
    ros.add_argument(
        "--scenario",
        help="with --ros2: take the configuration from this scenario file (no sim server; the agent ends "
        "after sim.duration_s)",
    )
    ros.add_argument("--model", help="with --scenario: the gnn policy file (default: the scenario's)")
    ros.add_argument("--domain-id", type=int, help="with --ros2: ROS_DOMAIN_ID (default: the scenario's, 0)")
    ros.add_argument("--namespace", help="with --ros2: namespace, {i} the robot id (default: robot_{i})")
    return parser


def ros2_overrides(args: argparse.Namespace) -> dict:
    """The ``ros2`` settings given on the command line (ValueError: bad input)."""
    if not args.ros2:
        if args.scenario or args.model or args.domain_id is not None or args.namespace:
            raise ValueError("--scenario, --model, --domain-id and --namespace go with --ros2")
        return {}
    overrides: dict = {}
    if args.domain_id is not None:
        overrides["domain_id"] = args.domain_id
    if args.namespace is not None:
        overrides["namespace"] = args.namespace
    from swarm.runtime import ros2

    settings = ros2.Ros2Settings(**overrides)
    ros2.check_domain_id(settings.domain_id)
    settings.cmd_vel(0)  # a namespace template that formats
    return overrides


def zenoh_settings(robot: int, args: argparse.Namespace) -> dict:
    """More session settings: a link may take no longer to open than the start-up timeout, and the
    robot's credentials (``CredentialsError`` when they cannot be read)."""
    open_timeout_ms = max(1, min(10_000, round(1e3 * args.startup_timeout)))
    settings: dict = {"transport/unicast/open_timeout": open_timeout_ms}
    if args.credentials:
        settings.update(acl.client_settings(*acl.read_credentials(args.credentials, robot)))
    elif args.password is not None:
        settings.update(acl.client_settings(args.user or acl.user_of(robot), args.password))
    if args.tls:  # swarm.runtime.tls.TlsError (a ValueError) when a file is missing
        settings.update(tls.client_settings(args.tls, robot))
    return settings


def describe_failure(record: dict, args: argparse.Namespace) -> str:
    """Why an agent could not run, in one line, from its record."""
    reason = str(record.get("exit_reason") or "failed")
    if reason == "could not connect":
        endpoints = ", ".join(args.connect or ["tcp/127.0.0.1:7447"])
        reason = f"could not connect to {endpoints} within {args.startup_timeout:g} s"
        if args.credentials or args.password is not None:
            reason += " (no sim server there, or it refused the credentials)"
    elif record.get("config_error") and record["config_error"] not in reason:
        reason = f"{reason}: {record['config_error']}"
    elif reason in ("no config from the sim", "no sim serves this robot"):
        reason += f" within {args.startup_timeout:g} s"
    return reason


def run_one(robot: int, args: argparse.Namespace, settings: dict) -> int:
    options = AgentOptions(
        robot=robot,
        run=args.run,
        connect=args.connect or ["tcp/127.0.0.1:7447"],
        zenoh_mode=args.zenoh_mode,
        lease_ms=args.lease_ms,
        startup_timeout_s=args.startup_timeout,
        log_dir=Path(args.log_dir) if args.log_dir else None,
        zenoh_settings=settings,
    )
    agent: RobotAgent
    if args.ros2:
        from robot_agent.ros2 import Ros2RobotAgent

        agent = Ros2RobotAgent(options, args.ros2_overrides, args.local_configs.get(robot))
    else:
        agent = RobotAgent(options)
    signal.signal(signal.SIGTERM, agent.request_stop)
    signal.signal(signal.SIGINT, agent.request_stop)
    code = agent.run()
    if code != 0:  # one write: the launcher's agents share its stderr
        sys.stderr.write(f"robot-agent: error: robot {robot}: {describe_failure(agent.record, args)}\n")
    return code


def _child(robot: int, args: argparse.Namespace, settings: dict) -> int:
    """In a forked child: own log file, die with the launcher, run the agent."""
    if args.log_dir:
        log = os.open(Path(args.log_dir) / f"agent_{robot}.log", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
    die_with_parent()
    return run_one(robot, args, settings)


def _exit_reason(args: argparse.Namespace, robot: int | None) -> str:
    try:
        record = json.loads((Path(args.log_dir) / f"agent_{robot}.json").read_text())
    except (TypeError, OSError, ValueError):
        return ""
    return f": {describe_failure(record, args)}" if record.get("exit_reason") else ""


EXITS_FILE = "launcher_exits.jsonl"
"""In ``--log-dir``: one line per forked agent that ended, ``{"robot", "pid", "exit_status"}`` (a negative
status: killed by that signal)."""


def launch(robots: list[int], args: argparse.Namespace, settings: dict[int, dict]) -> int:
    """Fork one agent process per robot and wait for them; SIGTERM/SIGINT are passed on."""
    children: dict[int, int] = {}
    stopping = False

    def forward(signum: int, _frame: object) -> None:
        nonlocal stopping
        stopping = True
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
                os.kill(pid, signal.SIGCONT)  # a stopped agent (hang_agent fault) must run to exit

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    sys.stdout.flush()
    sys.stderr.flush()
    for robot in robots:
        if stopping:
            break
        pid = os.fork()
        if pid == 0:
            code: int = EXIT_FAILED
            try:
                code = _child(robot, args, settings[robot])
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
        child: int | None = children.pop(pid, None)
        code = os.waitstatus_to_exitcode(status)
        if args.log_dir:  # every exit the launcher saw, for the run's health (swarm.runtime.health)
            with open(Path(args.log_dir) / EXITS_FILE, "a") as exits:
                exits.write(json.dumps({"robot": child, "pid": pid, "exit_status": code}) + "\n")
        if code != 0:
            why = _exit_reason(args, child)
            print(
                f"robot-agent: robot {child} (pid {pid}) exited with {code}{why}", file=sys.stderr, flush=True
            )
            worst = max(worst, 1)
    return worst


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging()
    if args.die_with_parent:
        die_with_parent()
    robots = [args.robot] if args.robot is not None else args.robots
    try:
        if args.run is not None:
            wire.check_run_id(args.run)
        if args.credentials and (args.user or args.password is not None):
            raise ValueError("give --credentials or --user/--password, not both")
        if args.user and args.password is None:
            raise ValueError("--user needs --password")
        settings = {robot: zenoh_settings(robot, args) for robot in robots}
        args.ros2_overrides = ros2_overrides(args)
        args.local_configs = {}
        if args.scenario:
            from robot_agent.ros2 import local_config

            args.run = args.run or "run"
            args.local_configs = {r: local_config(args.scenario, r, args.run, args.model) for r in robots}
        # endpoints of the right form, before any agent starts (each opens its own session)
        wire.session_config(args.zenoh_mode, args.connect or [], (), args.lease_ms, settings[robots[0]])
        if not 0 <= args.nice <= 19:
            raise ValueError(f"--nice: {args.nice} is not within 0-19")
        if args.log_dir:
            Path(args.log_dir).mkdir(parents=True, exist_ok=True)
    except (ValueError, KeyError, OSError, zenoh.ZError) as error:  # CredentialsError, ScenarioError too
        print(f"robot-agent: error: {one_line(error)}", file=sys.stderr)
        return ExitCode.BAD_INPUT
    if args.nice:
        os.nice(args.nice)  # before forking: every agent inherits it
    if args.robot is not None:
        return run_one(args.robot, args, settings[args.robot])
    start_s = time.perf_counter()
    code = launch(args.robots, args, settings)
    elapsed_s = time.perf_counter() - start_s
    print(f"robot-agent: {len(args.robots)} agents ended after {elapsed_s:.1f} s", flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
