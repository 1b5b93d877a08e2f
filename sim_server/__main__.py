"""``python -m sim_server --scenario FILE --out DIR --run RUN --listen ENDPOINT``: the PyBullet sim server.

At the end it writes ``metrics.json``, ``convergence.png`` and ``animation.gif`` into ``--out`` from what
is on disk (marked partial when the run did not complete) and prints the summary and the results
directory, unless ``--no-report`` (``swarm run`` writes them itself).

Exit status: 0 the run completed, 1 it failed (agents did not come up), 2 bad input (one line on
stderr: a scenario that does not load, an endpoint that cannot be listened on, ...), 130 interrupted.

A scenario with ``sim.acl: true`` needs ``--users FILE``: the agents' ``user:password`` lines
(``python -m swarm.runtime.acl credentials``); the router then admits only those users, each to its own
neighbourhood of the graph (``swarm.runtime.acl``). ``sim.acl`` unset: access control is on with
``--users`` and off without (``server_stats.json`` says which); ``sim.acl: false``: off, and
``--users`` is bad input.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import zenoh

from swarm.runtime import acl, tls, wire
from swarm.runtime.procs import die_with_parent
from swarm.runtime.usage import (
    EXIT_BAD_INPUT,
    OneLineArgumentParser,
    configure_logging,
    one_line,
    silenced_stderr,
)
from swarm.scenarios.scenario import ScenarioError, load_scenario, parse_scenario, policy_path

ADMIN_SPACE = {"adminspace/enabled": True, "adminspace/permissions": {"read": True, "write": False}}


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineArgumentParser(
        prog="python -m sim_server",
        description="Simulate a scenario's robots in PyBullet and serve them to robot agents over Zenoh.",
    )
    parser.add_argument("--scenario", required=True, help="scenario YAML file")
    parser.add_argument("--out", required=True, help="results directory (trajectory, server_stats.json)")
    parser.add_argument("--run", default="run", help="run id: the key prefix swarm/<run>/ (default: run)")
    parser.add_argument(
        "--listen",
        action="append",
        help="Zenoh endpoint to listen on, repeatable (default: tcp/127.0.0.1:7447; "
        "tcp/0.0.0.0:7447 for agents on other hosts)",
    )
    parser.add_argument("--connect", action="append", default=[], help="Zenoh endpoint to connect to")
    parser.add_argument(
        "--zenoh-mode", choices=["router", "peer"], default="router", help="session mode (default: router)"
    )
    parser.add_argument("--model", help="policy file for controller gnn (default: the scenario's)")
    parser.add_argument("--lease-ms", type=int, default=1000, help="Zenoh lease (default 1000 ms)")
    parser.add_argument(
        "--tls",
        help="directory of the run's TLS certificates (python -m swarm.runtime.tls certificates): listen on"
        " tls/HOST:PORT with mutual TLS",
    )
    parser.add_argument(
        "--users",
        help="sim.acl: file of the agents' user:password lines (python -m swarm.runtime.acl credentials)",
    )
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="seconds to wait for all agents")
    parser.add_argument(
        "--admin-space",
        action="store_true",
        help="open the router's Zenoh admin space (@/<zid>/router/**) read-only: who declared what, "
        "seen by the router (tests/test_declarations.py)",
    )
    parser.add_argument("--die-with-parent", action="store_true", help="exit when the parent process dies")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument(
        "--ros2",
        action="store_true",
        help="also be ROS 2 robots: publish each robot's <ns>/odom and /clock, obey <ns>/cmd_vel, as "
        "rmw_zenoh maps them (scenario key ros2; docs/ros2.md; needs the ros2 extra: rosbags)",
    )
    parser.add_argument(
        "--no-report",
        action="store_true",
        help="do not write metrics.json and the plots at the end, nor print the summary (swarm run does it)",
    )
    return parser


def write_results(out_dir: Path, code: int) -> None:
    """At the end of a run served by hand (several hosts): ``metrics.json`` and the plots from what is on
    disk (marked partial unless the run completed), then the summary and where the results are."""
    from sim_server.server import EXIT_INTERRUPTED
    from swarm.scenarios.results import report, summary_lines

    why = None
    if code != 0:
        try:
            ticks = (out_dir / "trajectory.jsonl").read_bytes().count(b"\n")
        except OSError:
            ticks = 0
        stopped = "was interrupted" if code == EXIT_INTERRUPTED else f"ended with status {code}"
        why = f"the sim server {stopped} after {ticks} ticks"
    try:
        outcome = report(out_dir, partial=why)
    except (ScenarioError, OSError, ValueError) as error:
        print(f"sim_server: no results written: {one_line(error)}", file=sys.stderr)
        return
    print("\n".join(summary_lines(outcome, out_dir)), flush=True)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(-1 if args.quiet else 0)
    if args.die_with_parent:
        die_with_parent()
    with silenced_stderr():  # pybullet prints its build time on stderr when imported
        from sim_server.server import ServerOptions, SimServer, install_signal_handlers
    try:
        scenario = load_scenario(args.scenario)
        wire.check_run_id(args.run)
        if args.model:
            data = scenario.model_dump(mode="json")
            data["controller"]["model"] = args.model
            scenario = parse_scenario(data)
        path = policy_path(scenario, Path(args.scenario))
        policy = path.read_bytes() if path is not None else None
        settings = {}
        if scenario.sim.acl or (scenario.sim.acl is None and args.users):  # unset: on with --users
            settings = acl_settings(scenario, args)
        elif args.users:
            raise ValueError(
                f"--users is for scenarios with access control, and {args.scenario} sets sim.acl: false"
            )
        if args.tls:
            settings = {**settings, **tls.router_settings(args.tls)}  # TlsError is a ValueError
        if args.admin_space:
            settings = {**settings, **ADMIN_SPACE}
        run_key = wire.RunKey.from_env()  # ValueError (bad input) when SWARM_RUN_KEY is not a key
        if run_key is None:
            logging.getLogger("sim_server").warning(
                "sim_server: %s is not set: poses, configs and commands are not authenticated "
                "(anyone who can reach the router can forge them; docs/distributed-runtime.md)",
                wire.RUN_KEY_ENV,
            )
        options = ServerOptions(
            run=args.run,
            out_dir=Path(args.out),
            listen=args.listen or ["tcp/127.0.0.1:7447"],
            connect=args.connect,
            zenoh_mode=args.zenoh_mode,
            lease_ms=args.lease_ms,
            startup_timeout_s=args.startup_timeout,
            policy=policy,
            quiet=args.quiet,
            zenoh_settings=settings,
            run_key=run_key,
            ros2=args.ros2,
        )
        # endpoints and settings of the right form, before anything starts (serve() opens the session)
        wire.session_config(options.zenoh_mode, options.connect, options.listen, args.lease_ms, settings)
        server = SimServer(scenario, options)
    except (ScenarioError, ValueError, OSError, zenoh.ZError) as error:
        print(f"sim_server: error: {one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    install_signal_handlers(server)
    try:
        code = server.serve()
        if not args.no_report:
            write_results(Path(args.out), code)
        return code
    except zenoh.ZError as error:  # e.g. the --listen port is in use
        print(f"sim_server: error: cannot open the Zenoh session: {one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:  # the results directory cannot be written
        print(f"sim_server: error: {one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT


def acl_settings(scenario, args: argparse.Namespace) -> dict:
    """The router's authentication and access control for a scenario with ``sim.acl``."""
    if args.zenoh_mode != "router":
        raise ValueError("sim.acl needs --zenoh-mode router: the agents are clients of its access control")
    if not args.users:
        raise ValueError(
            f"{args.scenario} sets sim.acl: give --users FILE of the agents' user:password lines"
            " (python -m swarm.runtime.acl credentials --robots N --out DIR writes one)"
        )
    users = Path(args.users)
    if not users.is_file():
        raise ValueError(f"{users}: no such users file")
    ros2_keys = None
    if args.ros2:
        from swarm.runtime import ros2

        settings = ros2.Ros2Settings.from_scenario(scenario.model_dump(mode="json"))
        ros2_keys = [ros2.acl_key_exprs(settings, i) for i in range(scenario.robots.count)]
    adjacency = scenario.adjacency()  # None: a disk graph, no agent hears another but by the radio
    count = scenario.robots.count
    graph = [[0.0] * count for _ in range(count)] if adjacency is None else adjacency
    return acl.router_settings(wire.Keys(args.run), graph, users.resolve(), ros2_keys)


if __name__ == "__main__":
    sys.exit(main())
