"""The ``swarm`` command line.

Exit status, one meaning each: 0 success met; 1 ran but did not meet it, or could not complete
(a killed sim server, agents that never came up); 2 bad input only (nothing started); 130
interrupted (Ctrl-C, SIGTERM; the partial results of the run are written first).
"""

from __future__ import annotations

import sys

from swarm.core.exit_codes import ExitCode  # the standard library's enum only: first, and quick

COMMANDS = ("run", "report", "sweep", "evaluate", "train", "collect")

# Nothing heavy at module level (numpy, pydantic, the runtime): ``main`` must be running, and catching
# Ctrl-C, within milliseconds of the command's start. On a loaded machine even these few imports take
# long enough for a Ctrl-C to land in them: it is one line and exit 130 there too.
try:
    import argparse
    import contextlib
    import json
    import shutil
    import signal
    import time
    import uuid
    from pathlib import Path
except KeyboardInterrupt:  # the command is named as main names it
    _first = next((word for word in sys.argv[1:] if not word.startswith("-")), "")
    _command = f"swarm {_first}" if _first in COMMANDS else "swarm"
    print(f"{_command}: interrupted", file=sys.stderr)
    raise SystemExit(ExitCode.INTERRUPTED) from None

SWEEP_CONTROLLER_NAMES = [
    "local_consensus",
    "centralized",
    "gnn",
    "mec_flood",
    "mec_flood_forward",
    "centralized_mec",
]  # swarm.scenarios.sweep.SWEEP_CONTROLLERS (not imported here: it pulls in numba)

PROJECT_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SCENARIO = "scenarios/thesis/cycle-gnn.yaml"
EXIT_SUCCESS, EXIT_NOT_MET, EXIT_BAD_INPUT, EXIT_INTERRUPTED = (
    ExitCode.SUCCESS,
    ExitCode.NOT_MET,
    ExitCode.BAD_INPUT,
    ExitCode.INTERRUPTED,
)
RECORDING_FORMATS = ("mcap", "rerun")


class UsageError(Exception):
    """Bad input from the command line; printed as one line, exit 2."""


def _find_default_scenario() -> Path:
    for base in (Path.cwd(), PROJECT_ROOT):
        if (base / DEFAULT_SCENARIO).is_file():
            return base / DEFAULT_SCENARIO
    raise UsageError(f"no scenario given and the default {DEFAULT_SCENARIO} was not found")


def _load_with_overrides(path: Path, args: argparse.Namespace):
    """Load a scenario, applying command-line overrides before validation so that errors name keys."""
    import yaml

    from swarm.scenarios.scenario import (
        ENGINE_DEFAULTS,
        ScenarioError,
        load_scenario,
        parse_scenario,
        resolve_model_path,
    )

    scenario = load_scenario(path)
    if not (args.engine or args.controller or args.model or args.duration):
        return scenario
    data = scenario.model_dump(mode="json")
    if args.engine:
        data["sim"]["engine"] = args.engine
        written = yaml.safe_load(path.read_text()) or {}
        for section, key in ENGINE_DEFAULTS:  # chosen again for the new engine unless the file gives them
            if isinstance(data.get(section), dict) and key not in (written.get(section) or {}):
                data[section].pop(key, None)
    if args.duration:
        data["sim"]["duration_s"] = args.duration
    if args.controller:  # the new kind's defaults for the options only the old kind took
        from swarm.sim.controller_kinds import controller_kind

        takes = controller_kind(args.controller).options
        data["controller"] = {
            key: value
            for key, value in data["controller"].items()
            if key in ("model", "gain") or key in takes
        }
        data["controller"]["kind"] = args.controller
    if args.model:
        try:
            data["controller"]["model"] = str(resolve_model_path(args.model))
        except ScenarioError:
            raise UsageError(f"--model: model file not found: {args.model}") from None
    return parse_scenario(data, f"{path} (with command-line overrides)")


def _results_dir(args: argparse.Namespace, name: str) -> Path:
    """``--out`` (refused when it is not empty, unless ``--force``: then cleared), or a fresh
    ``runs/<name>-<date>-<time>-<random>`` that no other run has."""
    if not args.out:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        return Path("runs") / f"{name}-{stamp}-{uuid.uuid4().hex[:6]}"
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"--out {out_dir}: exists and is not a directory")
    if out_dir.is_dir() and any(out_dir.iterdir()):
        if not args.force:
            raise UsageError(f"--out {out_dir}: directory is not empty (--force clears it first)")
        resolved = out_dir.resolve()
        if resolved in (Path.cwd().resolve(), *Path.cwd().resolve().parents) or (resolved / ".git").exists():
            raise UsageError(f"--out {out_dir}: will not clear the working directory or a repository")
        for entry in out_dir.iterdir():
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    return out_dir


def _check_out_dir(option: str, path: str | None) -> None:
    """Refuse, before any work, an output directory that cannot be one (a file is in the way)."""
    if path is None:
        return
    for where in (Path(path), *Path(path).parents):
        if where.exists():
            if not where.is_dir():
                raise UsageError(f"{option} {path}: {where} exists and is not a directory")
            return


def _write_recordings(out_dir: Path, formats: list[str] | None) -> None:
    """The recordings asked for with ``--record`` (``swarm.scenarios.recording``), from the results
    on disk."""
    if formats:
        from swarm.scenarios.recording import write_recordings

        for path in write_recordings(out_dir, formats):
            print(f"  recording: {path}")


def _print_partial(out_dir: Path, formats: list[str] | None) -> None:
    """After a run that ended early: its partial results, if any were written, to stdout."""
    from swarm.scenarios.results import summary_lines

    metrics_path = out_dir / "metrics.json"
    try:
        outcome = json.loads(metrics_path.read_text())
    except (OSError, ValueError):
        return
    if outcome.get("partial"):
        print("\n".join(summary_lines(outcome, out_dir)), flush=True)
        with contextlib.suppress(Exception):  # the recording of a partial run is a bonus
            _write_recordings(out_dir, formats)


def cmd_run(args: argparse.Namespace) -> int:
    from swarm.scenarios.results import summary_lines, write_startup_results

    path = Path(args.scenario) if args.scenario else _find_default_scenario()
    scenario = _load_with_overrides(path, args)
    if args.record:
        from swarm.scenarios.recording import check_formats

        check_formats(args.record)
    out_dir = _results_dir(args, scenario.name)
    try:
        from swarm.runtime.runner import run_scenario

        outcome = run_scenario(scenario, out_dir, path, progress=not args.quiet, agent_nice=args.agent_nice)
    except KeyboardInterrupt:
        if not (out_dir / "metrics.json").is_file():  # before the first tick: the scenario and what it says
            with contextlib.suppress(Exception):
                write_startup_results(
                    out_dir, scenario, "interrupted (Ctrl-C) during start-up, before the first tick"
                )
        _print_partial(out_dir, args.record)
        raise
    except RuntimeError as error:
        if _raised(error, "swarm.runtime.distributed", "RunFailed"):
            _print_partial(out_dir, args.record)
        raise
    print("\n".join(summary_lines(outcome, out_dir)))
    _write_recordings(out_dir, args.record)
    if outcome.get("incomplete"):  # e.g. a kill_server fault ended the run early
        print(f"swarm run: run incomplete: {outcome['incomplete']}", file=sys.stderr)
        return EXIT_NOT_MET
    return _health_or(outcome, "swarm run")


def _health_or(outcome: dict, prog: str) -> int:
    """Exit 1 with the reasons when the run's health failed (swarm.runtime.health), else by convergence."""
    failures = (outcome.get("health") or {}).get("failures")
    if failures:
        print(f"{prog}: the run failed: {'; '.join(failures)}", file=sys.stderr)
        return EXIT_NOT_MET
    return EXIT_SUCCESS if outcome["converged"] else EXIT_NOT_MET


def cmd_report(args: argparse.Namespace) -> int:
    from swarm.scenarios.results import report, summary_lines

    out_dir = Path(args.run_dir)
    outcome = report(out_dir)
    print("\n".join(summary_lines(outcome, out_dir)))
    _write_recordings(out_dir, args.record)
    if outcome.get("incomplete"):
        print(f"swarm report: run incomplete: {outcome['incomplete']}", file=sys.stderr)
        return EXIT_NOT_MET
    return _health_or(outcome, "swarm report")


def cmd_sweep(args: argparse.Namespace) -> int:
    import yaml

    from swarm.scenarios.sweep import SweepConfig, run_sweep

    data: dict = {}
    if args.config:
        try:
            data = yaml.safe_load(Path(args.config).read_text()) or {}
        except FileNotFoundError:
            raise UsageError(f"{args.config}: no such sweep config file") from None
        except yaml.YAMLError as error:
            raise UsageError(f"{args.config}: invalid YAML: {str(error).splitlines()[0]}") from None
        if not isinstance(data, dict):
            raise UsageError(f"{args.config}: a sweep config is a mapping of settings")
    if args.task not in (None, "rendezvous") or data.get("task") not in (None, "rendezvous"):
        return _task_sweep(args, data)
    for flag, given in (("--resume", args.resume), ("--tables-only", args.tables_only)):
        if given:
            raise UsageError(f"{flag}: a task sweep setting (--task formation or coverage)")
    data.pop("task", None)
    config = SweepConfig()
    if args.config:
        config = SweepConfig.from_mapping(data, source=args.config)
    overrides = {
        "topologies": args.topologies,
        "sizes": args.sizes,
        "seeds": args.seeds,
        "controllers": args.controllers,
        "max_duration_s": args.max_duration,
        "gain": args.gain,
        "v_max_mps": args.v_max,
        "model": args.model,
        "workers": args.workers,
        "packet_loss": args.packet_loss,
    }
    config = config.with_overrides({key: value for key, value in overrides.items() if value is not None})
    _check_out_dir("--out", args.out)
    out_dir = Path(args.out)
    rows = run_sweep(config, out_dir, progress=not args.quiet)
    failed = [row for row in rows if row["success_rate"] < 1.0]
    print(f"sweep: {len(rows)} cells, table in {out_dir / 'sweep.md'}, plots in {out_dir}")
    for row in failed:
        print(
            f"  not always converged: {row['topology']} N={row['robots']} {row['controller']}: "
            f"{row['success_rate']:.1%}"
        )
    return EXIT_SUCCESS if not failed else EXIT_NOT_MET


def _task_sweep(args: argparse.Namespace, data: dict) -> int:
    """``swarm sweep --task formation`` (or a config with ``task:``): swarm.scenarios.task_sweep."""
    from swarm.scenarios.task_sweep import TaskSweepConfig, cell_names, run_task_sweep

    if args.gain is not None:
        raise UsageError("--gain: a rendezvous sweep setting; a task sweep has none")
    if args.task is not None:
        data = {**data, "task": args.task}
    source = args.config or "command line"
    config = TaskSweepConfig.from_mapping(data, source=source)
    overrides = {
        "topologies": args.topologies,
        "sizes": args.sizes,
        "seeds": args.seeds,
        "controllers": args.controllers,
        "duration_s": args.max_duration,
        "v_max_mps": args.v_max,
        "packet_losses": None if args.packet_loss is None else [args.packet_loss],
        "model": args.model,
    }
    config = config.with_overrides({key: value for key, value in overrides.items() if value is not None})
    _check_out_dir("--out", args.out)
    out_dir = Path(args.out)
    rows = run_task_sweep(
        config,
        out_dir,
        progress=not args.quiet,
        resume=args.resume,
        workers=args.workers or 1,
        tables_only=args.tables_only,
    )
    failed = [row for row in rows if row["success_rate"] < 1.0]
    print(
        f"sweep {config.task}: {len(rows)} cells, table in {out_dir / 'sweep.md'},"
        f" plot {out_dir / 'sweep.png'}"
    )
    for row in failed:
        loss = f" loss {row['packet_loss']:g}" if row["packet_loss"] else ""
        print(
            f"  not always met: {row['topology']} N={row['robots']}{loss} {row['controller']}: "
            f"{row['success_rate']:.1%}"
        )
    lacking = [name for name in cell_names(config) if not (out_dir / "cells" / name).is_file()]
    if lacking:  # --tables-only over cells not all run yet: incomplete
        shown = ", ".join(lacking[:3]) + (", ..." if len(lacking) > 3 else "")
        print(f"  incomplete: {len(lacking)} cells of these lists not run yet ({shown}); --resume runs them")
    return EXIT_SUCCESS if not failed and not lacking else EXIT_NOT_MET


def _policy_task(path: str) -> str:
    """The task a policy file is for: formation or coverage by its ``format`` (any version of it: the
    loader names an outdated one), else rendezvous."""
    import numpy as np

    from swarm.sim.coverage_gnn import CoverageGnnWeights
    from swarm.sim.formation_gnn import FormationGnnWeights
    from swarm.sim.steering_mlp import PolicyFileError

    try:
        with np.load(path, allow_pickle=False) as data:
            found = str(data["format"]) if "format" in data.files else ""
    except (OSError, ValueError) as error:
        raise UsageError(f"{path}: not a policy file ({error})") from None
    for weights_class, task in ((FormationGnnWeights, "formation"), (CoverageGnnWeights, "coverage")):
        if found.split("/")[0] == weights_class.FORMAT.split("/")[0]:
            try:
                weights_class.load(path)  # refused before any cell runs
            except PolicyFileError as error:
                raise UsageError(f"{path}: {error}") from None
            return task
    return "rendezvous"


def _task_evaluate(args: argparse.Namespace, task: str) -> int:
    """``swarm evaluate MODEL`` of a task's learned kind: a task sweep of its experts, its baselines and
    the learned kind with MODEL, on the same starts (swarm.scenarios.task_sweep)."""
    from swarm.core.tasks import registry
    from swarm.scenarios.task_sweep import TaskSweepConfig, run_task_sweep

    rendezvous_only = {
        "--limit": args.limit,
        "--reuse": args.reuse,
        "--curve-sizes": args.curve_sizes,
        "--curve-starts": args.curve_starts,
    }
    for option, value in rendezvous_only.items():
        if value is not None:
            raise UsageError(f"{option}: a rendezvous evaluation setting; a {task} evaluation has none")
    entry = registry.get(task)
    overrides = {
        "topologies": args.topologies,
        "sizes": args.sizes,
        "seeds": args.seeds,
        "duration_s": args.max_duration,
        "packet_losses": args.packet_loss,
        "controllers": [*entry.experts, *entry.baselines, *entry.learned],
        "model": args.model,
    }
    config = TaskSweepConfig(task=task).with_overrides(
        {key: value for key, value in overrides.items() if value is not None}
    )
    _check_out_dir("--out", args.out)
    out_dir = Path(args.out)
    rows = run_task_sweep(config, out_dir, progress=not args.quiet, workers=args.workers or 1)
    failed = [row for row in rows if row["controller"] in entry.learned and row["success_rate"] < 1.0]
    table, plot = out_dir / "sweep.md", out_dir / "sweep.png"
    print(f"evaluate {task}: {len(rows)} cells, table in {table}, plot {plot}")
    for row in failed:
        loss = f" loss {row['packet_loss']:g}" if row["packet_loss"] else ""
        print(f"  model not always met: {row['topology']} N={row['robots']}{loss}: {row['success_rate']:.1%}")
    return EXIT_SUCCESS if not failed else EXIT_NOT_MET


def cmd_evaluate(args: argparse.Namespace) -> int:
    from swarm.scenarios.evaluate import EvaluateConfig, evaluate
    from swarm.scenarios.sweep import SweepConfig

    if not Path(args.model).is_file():
        raise UsageError(f"{args.model}: no such policy file")
    task = _policy_task(args.model)
    if args.task is not None and args.task != task:
        raise UsageError(f"--task {args.task}: {args.model} is a {task} policy")
    if task != "rendezvous":
        return _task_evaluate(args, task)

    limits: dict[str | int, int] = {}
    for topology, count, starts in args.limit or []:  # swarm.runtime.usage.limit_spec
        limits[f"{topology}:{count}" if topology else count] = starts
    for reuse_dir in args.reuse or []:
        if not Path(reuse_dir).is_dir():
            raise UsageError(f"--reuse {reuse_dir}: no such results directory")
    _check_out_dir("--out", args.out)
    defaults = EvaluateConfig(model=args.model)
    config = EvaluateConfig(
        model=args.model,
        out=args.out,
        topologies=args.topologies or defaults.topologies,
        sizes=args.sizes or defaults.sizes,
        seeds=args.seeds or defaults.seeds,
        limits=limits,
        max_duration_s=args.max_duration or defaults.max_duration_s,
        reuse=args.reuse or [],
        curve_sizes=args.curve_sizes or defaults.curve_sizes,
        curve_starts=args.curve_starts or defaults.curve_starts,
        workers=args.workers or 1,
        packet_losses=args.packet_loss or defaults.packet_losses,
    )
    SweepConfig(
        topologies=config.topologies, sizes=config.sizes, seeds=config.seeds, workers=config.workers
    ).check("command line")
    for topology, count, _ in args.limit or []:
        if (topology is not None and topology not in config.topologies) or count not in config.sizes:
            where = f"{topology}:{count}" if topology else f"N = {count}"
            raise UsageError(f"--limit: {where} is not a cell of this evaluation (--topologies, --sizes)")
    rows = evaluate(config, progress=not args.quiet)
    failed = [row for row in rows if row["controller"] == "gnn" and row["success_rate"] < 1.0]
    print(f"evaluate: {len(rows)} cells, table in {Path(args.out) / 'evaluation.md'}, plots in {args.out}")
    for row in failed:
        print(f"  model not always converged: {row['topology']} N={row['robots']}: {row['success_rate']:.1%}")
    return EXIT_SUCCESS if not failed else EXIT_NOT_MET


def cmd_train(args: argparse.Namespace) -> int:
    import importlib

    import yaml

    from swarm.learn.train import ALGORITHMS

    overrides: dict = {}
    if args.config:
        try:
            overrides = yaml.safe_load(Path(args.config).read_text()) or {}
        except FileNotFoundError:
            raise UsageError(f"{args.config}: no such training config file") from None
        except yaml.YAMLError as error:
            raise UsageError(f"{args.config}: invalid YAML: {str(error).splitlines()[0]}") from None
    if args.out:
        _check_out_dir("--out", args.out)
        overrides["out"] = args.out
    if args.data:
        overrides["data"] = args.data
    if args.quiet:
        overrides["progress"] = False
    module = importlib.import_module(ALGORITHMS[args.algo])
    try:
        config = module.make_config(args.preset, overrides)
    except (TypeError, ValueError) as error:
        raise UsageError(f"{args.config}: {error}" if args.config else str(error)) from None
    print(f"swarm train: {args.algo} -> {module.train(config)}")
    return EXIT_SUCCESS


def cmd_collect(args: argparse.Namespace) -> int:
    from swarm.learn.data import collect, collect_config

    overrides = {
        "samples": args.samples,
        "graphs": tuple(args.graphs) if args.graphs else None,
        "sizes": tuple(args.sizes) if args.sizes else None,
        "hops": args.hops,
        "phi_source": args.phi_source,
        "normaliser": args.normaliser,
        "labels": args.labels,
        "seed": args.seed,
    }
    if args.robot_from:  # the robot of a scenario: its speed limit and geometry
        from swarm.scenarios.scenario import load_scenario

        robot = load_scenario(args.robot_from).robot
        overrides.update(robot.model_dump())
    try:
        config = collect_config(args.preset, **overrides)
    except ValueError as error:
        raise UsageError(str(error)) from None
    _check_out_dir("--out", str(Path(args.out).parent))
    started = time.perf_counter()
    dataset = collect(config, progress=not args.quiet)
    path = dataset.save(args.out)
    print(f"swarm collect: {len(dataset)} samples in {time.perf_counter() - started:.1f} s -> {path}")
    return EXIT_SUCCESS


def build_parser() -> argparse.ArgumentParser:
    from swarm.core.topologies import kinds
    from swarm.runtime.usage import (
        OneLineArgumentParser,
        limit_spec,
        non_negative_int,
        positive_float,
        positive_int,
        probability,
        robot_count,
    )
    from swarm.sim.controller_kinds import CONTROLLER_KINDS

    grid_kinds = kinds(grid=True)

    parser = OneLineArgumentParser(
        prog="swarm",
        description="Decentralized GNN controllers for differential-drive robot swarms: "
        "run scenarios, sweep experiments.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    shown = OneLineArgumentParser(add_help=False)  # what every command shows besides its results
    shown.add_argument("--quiet", action="store_true", help="no progress bar; only warnings and errors")
    shown.add_argument("-v", "--verbose", action="count", default=0, help="also debug messages")

    run = commands.add_parser(
        "run",
        parents=[shown],
        help="run one scenario and write its results directory",
        description="Run a scenario file and write scenario.yaml, trajectory.jsonl, metrics.json, "
        "convergence.png and animation.gif to the results directory. Exit 0 when the scenario's "
        "success criterion is met, 1 when the run completed without meeting it, 2 on bad input.",
    )
    run.add_argument("scenario", nargs="?", help=f"scenario YAML file (default: {DEFAULT_SCENARIO})")
    run.add_argument(
        "--out", help="results directory; refused when not empty (default: runs/<name>-<date>-<time>-<id>)"
    )
    run.add_argument("--force", action="store_true", help="clear a non-empty --out directory first")
    run.add_argument(
        "--record",
        nargs="+",
        choices=RECORDING_FORMATS,
        help="also write a recording of the run: mcap (ROS 2 messages, for Foxglove), rerun (.rrd)",
    )
    run.add_argument("--engine", choices=["kinematic", "pybullet"], help="override sim.engine")
    run.add_argument("--controller", choices=list(CONTROLLER_KINDS), help="override controller.kind")
    run.add_argument("--model", help="override controller.model (exported model file)")
    run.add_argument("--duration", type=positive_float, help="override sim.duration_s (simulated seconds)")
    run.add_argument(
        "--agent-nice",
        type=int,
        choices=range(20),
        metavar="0-19",
        help="pybullet: niceness the agents get on top of this process's (default 5: the sim server,"
        " on the critical path of every tick, wins a contended core)",
    )
    run.set_defaults(handler=cmd_run)

    report = commands.add_parser(
        "report",
        parents=[shown],
        help="re-create metrics.json and the plots of a results directory from what is on disk",
        description="Read a results directory back (scenario.yaml, trajectory.jsonl up to its last complete "
        "line, events.jsonl) and rewrite metrics.json, convergence.png and animation.gif: for a run "
        "that was killed or ended early. Exit 0 success met, 1 not met or the run incomplete, 2 unreadable.",
    )
    report.add_argument("run_dir", help="results directory of a run")
    report.add_argument("--record", nargs="+", choices=RECORDING_FORMATS, help="also write recordings")
    report.set_defaults(handler=cmd_report)

    sweep = commands.add_parser(
        "sweep",
        parents=[shown],
        help="run a grid of topologies x sizes x seeds x controllers in the batched simulator",
        description="Run every (topology, N, controller) cell with SEEDS random starts in the batched "
        "kinematic simulator; write sweep.csv, sweep.md and plots of the convergence-time "
        "distributions (absolute and as a ratio to the lower bound of docs/design.md).",
    )
    sweep.add_argument(
        "--config", help="YAML file with any SweepConfig (or, with task:, TaskSweepConfig) fields"
    )
    sweep.add_argument(
        "--task",
        help="formation or coverage: that task's experts and baselines on complete, cycle, line, random "
        "and disk graphs, judged by the task's own rule (swarm.scenarios.task_sweep); default rendezvous",
    )
    sweep.add_argument("--topologies", nargs="+", help=" ".join([*grid_kinds, "line_sorted"]))
    sweep.add_argument("--sizes", nargs="+", type=robot_count, help="robot counts N")
    sweep.add_argument("--seeds", type=positive_int, help="random starts per cell")
    sweep.add_argument("--controllers", nargs="+", help=" ".join(SWEEP_CONTROLLER_NAMES))
    sweep.add_argument(
        "--packet-loss", type=probability, help="probability that a message is lost (default 0)"
    )
    sweep.add_argument(
        "--model",
        help="policy file of controller gnn (default: models/gnn_default.npz), or with --task of the"
        " task's learned kind (capt_gnn, lloyd_gnn; default: the shipped one under models/)",
    )
    sweep.add_argument(
        "--max-duration", type=positive_float, help="simulated seconds before a start counts as failed"
    )
    sweep.add_argument("--gain", type=positive_float, help="consensus gain K (1/s)")
    sweep.add_argument("--v-max", type=positive_float, help="wheel-speed limit (m/s)")
    sweep.add_argument("--out", default="runs/sweep", help="output directory (default: runs/sweep)")
    sweep.add_argument(
        "--workers",
        type=positive_int,
        help="processes the starts are split over (default 1; the results do not depend on it): a"
        " rendezvous sweep splits each cell's starts, a task sweep every cell's chunks of starts",
    )
    sweep.add_argument(
        "--resume",
        action="store_true",
        help="task sweeps: read the cells --out already holds from a sweep of the same settings (its"
        " topologies, sizes, controllers and packet losses may differ) instead of running them again:"
        " a long sweep can be run in parts, e.g. one graph at a time",
    )
    sweep.add_argument(
        "--tables-only",
        action="store_true",
        help="task sweeps: run no cell; rebuild sweep.md, sweep.csv and sweep.png from the cells --out"
        " holds (as --resume reads them); where some cells of the lists are not there yet, the tables of"
        " the others, a line naming the missing ones, and exit 1 (exit 2, writing nothing, if none is)",
    )
    sweep.set_defaults(handler=cmd_sweep)

    evaluate = commands.add_parser(
        "evaluate",
        parents=[shown],
        help="compare a policy file with local consensus and the centralized expert on a grid",
        description="Run the model, local consensus and the centralized expert from the same random starts "
        "on every (topology, N) cell of the batched simulator (swarm sweep's starts, stopping rule and "
        "cell cache); write evaluation.csv, evaluation.md and plots (max_pairwise over time, ratio to the "
        "lower bound). Exit 1 when the model did not converge from every start.",
    )
    evaluate.add_argument(
        "model",
        help="policy file (.npz): a rendezvous GNN, or a task's learned kind (capt_gnn: formation,"
        " lloyd_gnn: coverage; that task's experts and baselines on the task sweep's cells)",
    )
    evaluate.add_argument(
        "--task",
        choices=["rendezvous", "formation", "coverage"],
        help="the task the model is for (default: read from the file); a task's default cells are"
        " swarm sweep --task's: 20 starts, complete, cycle, line, random and disk graphs, N 6 12 24",
    )
    evaluate.add_argument("--topologies", nargs="+", help=" ".join(grid_kinds))
    evaluate.add_argument("--sizes", nargs="+", type=robot_count, help="robot counts N (default 6 12 24)")
    evaluate.add_argument("--seeds", type=positive_int, help="random starts per cell (default 1000)")
    evaluate.add_argument(
        "--limit",
        action="append",
        type=limit_spec,
        metavar="[TOPOLOGY:]N:STARTS",
        help="run only the first STARTS starts at N (of one topology only, if given)",
    )
    evaluate.add_argument(
        "--max-duration", type=positive_float, help="simulated seconds before a start counts as failed"
    )
    evaluate.add_argument(
        "--reuse", nargs="+", help="results directories whose cached cells to read (swarm sweep)"
    )
    evaluate.add_argument(
        "--curve-sizes", nargs="+", type=robot_count, help="N of the max_pairwise-over-time plots"
    )
    evaluate.add_argument(
        "--packet-loss",
        nargs="+",
        type=probability,
        help="message-loss probabilities, each a set of cells (default 0)",
    )
    evaluate.add_argument(
        "--curve-starts", type=positive_int, help="starts per max_pairwise curve (default 100)"
    )
    evaluate.add_argument("--out", default="runs/evaluate", help="output directory (default: runs/evaluate)")
    evaluate.add_argument(
        "--workers",
        type=positive_int,
        help="processes each cell's starts are split over (default 1)",
    )
    evaluate.set_defaults(handler=cmd_evaluate)

    from swarm.learn.train import ALGORITHMS

    train = commands.add_parser(
        "train",
        parents=[shown],
        help="train a controller (behavioural cloning, reinforcement learning)",
        description="Train with the chosen algorithm; --config is a YAML file of the algorithm's config "
        "fields. Writes logs, checkpoints, plots and the trained model to the output directory.",
    )
    train.add_argument("--algo", required=True, choices=sorted(ALGORITHMS), help="training algorithm")
    train.add_argument("--preset", default="default", help="named base config of the algorithm")
    train.add_argument("--config", help="YAML file with config fields (override the preset)")
    train.add_argument("--out", help="output directory (overrides the config's out)")
    train.add_argument("--data", help="training data file, for algorithms that read one (bc: swarm collect)")
    train.set_defaults(handler=cmd_train)

    collect = commands.add_parser(
        "collect",
        parents=[shown],
        help="collect expert data for behavioural cloning in the batched simulator",
        description="Roll out the centralized expert (or local consensus) on a mix of graphs and sizes with "
        "every robot's start random, and record each robot's features (with the policy's message timing) "
        "and the expert's saturated robot-frame velocity to one .npz file (swarm.learn.data).",
    )
    collect.add_argument("--preset", default="default", help="default | thesis (complete graph, N=6, M, Phi)")
    collect.add_argument("--samples", type=positive_int, help="robot-ticks to record (default 1,000,000)")
    collect.add_argument("--graphs", nargs="+", help=" ".join(grid_kinds))
    collect.add_argument("--sizes", nargs="+", type=robot_count, help="robot counts N")
    collect.add_argument("--hops", type=positive_int, help="K: features Phi1..PhiK")
    collect.add_argument("--phi-source", choices=["m", "output"], help="Phi from neighbours' M or outputs")
    collect.add_argument("--normaliser", choices=["degree", "n_minus_1"], help="c_i of M and Phi")
    collect.add_argument("--labels", choices=["centralized", "local_consensus"], help="the expert")
    collect.add_argument("--seed", type=non_negative_int, help="random seed")
    collect.add_argument(
        "--robot-from", metavar="SCENARIO", help="use the robot of this scenario (v_max, axle, offset, body)"
    )
    collect.add_argument("--out", default="data/bc.npz", help="output file (default: data/bc.npz)")
    collect.set_defaults(handler=cmd_collect)
    return parser


def _raised(error: BaseException, module: str, name: str) -> bool:
    """Whether ``error`` is ``module.name``, looked up among the modules already imported (the one
    that raised it was; importing the runtime for the check would cost seconds)."""
    loaded = sys.modules.get(module)
    return loaded is not None and isinstance(error, getattr(loaded, name))


def _handle(args: argparse.Namespace) -> int:
    """Run the command; its errors as one line and an exit status."""
    from swarm.runtime.usage import one_line

    command = f"swarm {args.command}"
    try:
        return args.handler(args)
    except UsageError as error:
        print(f"{command}: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:  # a file or directory that cannot be read or written
        where = f"{error.filename}: " if error.filename else ""
        print(f"{command}: error: {where}{error.strerror or one_line(error)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (ValueError, RuntimeError) as error:
        if _raised(error, "swarm.runtime.distributed", "RunFailed"):  # ran, could not complete
            print(f"{command}: run failed: {one_line(error)}", file=sys.stderr)
            return EXIT_NOT_MET
        if _raised(error, "swarm.scenarios.scenario", "ScenarioError"):
            print(f"{command}: error: {error}", file=sys.stderr)
            return EXIT_BAD_INPUT
        if isinstance(error, ValueError):  # bad content found late, e.g. a policy file that is not one
            print(f"{command}: error: {one_line(error)}", file=sys.stderr)
            return EXIT_BAD_INPUT
        raise


class _CtrlC:
    """While ``main`` runs (main thread, SIGINT not ignored): Ctrl-C raises KeyboardInterrupt as usual
    and is also remembered, because a library may turn it into another error mid-import (numpy raises
    ImportError when Ctrl-C lands in its C imports): that error then counts as the interrupt it was."""

    def __init__(self) -> None:
        self.seen = False
        self.previous: object = None

    def _handle(self, signum: int, frame: object) -> None:
        self.seen = True
        raise KeyboardInterrupt

    def __enter__(self) -> _CtrlC:
        with contextlib.suppress(ValueError):  # not the main thread: leave the handler alone
            if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
                self.previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)  # type: ignore[arg-type]


def main(argv: list[str] | None = None) -> int:
    given = sys.argv[1:] if argv is None else argv
    first = next((word for word in given if not word.startswith("-")), None)
    command = f"swarm {first}" if first in COMMANDS else "swarm"  # before argparse has read it
    with _CtrlC() as ctrl_c:
        try:  # everything, imports included: Ctrl-C at any moment is one line and 130, never a traceback
            from swarm.runtime.usage import configure_logging

            args = build_parser().parse_args(argv)
            command = f"swarm {args.command}"
            configure_logging(-1 if args.quiet else args.verbose)
            return _handle(args)
        except KeyboardInterrupt:
            print(f"{command}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Exception:
            if ctrl_c.seen:  # a Ctrl-C that a library turned into another error
                print(f"{command}: interrupted", file=sys.stderr)
                return EXIT_INTERRUPTED
            raise


if __name__ == "__main__":
    sys.exit(main())
