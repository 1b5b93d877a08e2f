"""``python -m sim_server --scenario FILE --out DIR --run RUN --listen ENDPOINT``: the PyBullet sim server.

Exit status: 0 the run completed, 1 it failed (agents did not come up), 2 bad input, 3 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sim_server.server import EXIT_BAD_INPUT, ServerOptions, SimServer, install_signal_handlers
from swarm import wire
from swarm.procs import die_with_parent
from swarm.scenario import ScenarioError, load_scenario, resolve_model_path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="seconds to wait for all agents")
    parser.add_argument("--die-with-parent", action="store_true", help="exit when the parent process dies")
    parser.add_argument("--quiet", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.die_with_parent:
        die_with_parent()
    try:
        scenario = load_scenario(args.scenario)
        wire.check_run_id(args.run)
        policy = None
        model = args.model or scenario.controller.model
        if scenario.controller.kind == "gnn":
            policy = resolve_model_path(model, Path(args.scenario)).read_bytes()
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
        )
        server = SimServer(scenario, options)
    except (ScenarioError, ValueError) as error:
        print(f"sim_server: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    install_signal_handlers(server)
    return server.serve()


if __name__ == "__main__":
    sys.exit(main())
