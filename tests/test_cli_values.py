"""Bad values over every option of every ``swarm`` command: one line on stderr, exit 2, nothing run.

The options are read from the real parser (``swarm.cli.build_parser``), so an option added later
without a case here fails :func:`test_every_option_has_bad_values`. Typed options (numbers, choices,
``--limit``) get every bad value of their type; options that name a file, a directory or a kind get
one bad value each, after arguments that are otherwise valid, so that the error line must come from
that option. Every case runs ``swarm.cli.main`` in-process under an alarm: a bad value that was
taken for a good one (and started the work) fails the case instead of running it.
"""

from __future__ import annotations

import argparse
import json
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.cli import build_parser, main
from swarm.runtime import usage

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SCENARIO = str(PROJECT_ROOT / "scenarios" / "thesis" / "cycle-local_consensus.yaml")
MODEL = str(PROJECT_ROOT / "models" / "gnn_default.npz")
MISSING = "/nonexistent/swarm-test/missing"
A_FILE = "{file}"  # a regular file where a directory is wanted (made by the fixture)
CASE_LIMIT_S = 60

BAD_BY_TYPE: dict[object, list[str]] = {
    usage.positive_int: ["six", "0", "-3", "2.5", "", "1e3"],
    usage.robot_count: ["six", "1", "0", "-2", ""],
    usage.non_negative_int: ["six", "-1", "0.5"],
    usage.positive_float: ["six", "0", "-1", "nan", "inf", "-inf", ""],
    usage.probability: ["six", "-0.1", "1", "1.5", "nan"],
    usage.limit_spec: [
        "six",
        "6",
        "6:",
        ":6:1",
        "a:b:c",
        "x:y:6:1",
        "6:0",
        "1:5",
        "cycle:six:1",
        "6:-1",
        "bogus:6:1",
        "7:10",
    ],
}
BAD_CHOICES = ["bogus", "", "-1"]

# (command, option) -> (arguments before it, bad value, what the error line must say)
BAD_NAMED: dict[tuple[str, str], tuple[list[str], str, str]] = {
    ("run", "scenario"): ([], MISSING, "no such scenario file"),
    ("run", "--out"): ([SCENARIO, "--engine", "kinematic"], A_FILE, "not a directory"),
    ("run", "--model"): ([SCENARIO, "--engine", "kinematic"], MISSING, "model file not found"),
    ("report", "run_dir"): ([], MISSING, "no such results directory"),
    ("sweep", "--config"): ([], MISSING, "no such sweep config file"),
    ("sweep", "--topologies"): ([], "bogus", "unknown topology 'bogus'"),
    ("sweep", "--controllers"): ([], "bogus", "unknown controller 'bogus'"),
    ("sweep", "--model"): (["--controllers", "gnn"], MISSING, "no such policy file"),
    ("sweep", "--task"): ([], "bogus", "task: 'bogus' is not swept; choose from formation, coverage"),
    ("sweep", "--out"): (
        ["--sizes", "6", "--seeds", "1", "--topologies", "cycle"],
        A_FILE,
        "not a directory",
    ),
    ("evaluate", "model"): ([], MISSING, "no such policy file"),
    ("evaluate", "--topologies"): ([MODEL], "bogus", "unknown topology 'bogus'"),
    ("evaluate", "--reuse"): ([MODEL], MISSING, "no such results directory"),
    ("evaluate", "--out"): ([MODEL, "--sizes", "6", "--seeds", "1"], A_FILE, "not a directory"),
    ("train", "--preset"): (["--algo", "bc"], "bogus", "unknown bc preset 'bogus'"),
    ("train", "--config"): (["--algo", "bc"], MISSING, "no such training config file"),
    ("train", "--out"): (["--algo", "bc"], A_FILE, "not a directory"),
    ("train", "--data"): (["--algo", "bc"], MISSING, "no such file"),
    ("collect", "--preset"): ([], "bogus", "unknown preset 'bogus'"),
    ("collect", "--graphs"): ([], "bogus", "unknown graph kind 'bogus'"),
    ("collect", "--robot-from"): ([], MISSING, "no such scenario file"),
    ("collect", "--out"): (["--samples", "10"], A_FILE + "/data.npz", "not a directory"),
}
REQUIRED: dict[str, list[str]] = {"evaluate": [MODEL], "report": [MISSING], "train": ["--algo", "bc"]}
"""What a command needs before the option under test (its positional arguments, ``--algo``)."""


def commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def value_options() -> Iterator[tuple[str, argparse.Action]]:
    """(command, action) for every option or positional argument that takes a value."""
    for name, parser in commands().items():
        for action in parser._actions:
            if action.nargs == 0 or isinstance(action, argparse._HelpAction):
                continue
            yield name, action


def option_name(action: argparse.Action) -> str:
    return action.option_strings[-1] if action.option_strings else action.dest


def typed_cases() -> Iterator[tuple[str, str, list[str], str]]:
    for command, action in value_options():
        if action.choices is not None:
            bad_values = BAD_CHOICES
        elif action.type in BAD_BY_TYPE:
            bad_values = BAD_BY_TYPE[action.type]
        else:
            continue
        name = option_name(action)
        before = [] if name == "--algo" else REQUIRED.get(command, [])
        if action.option_strings == [] and before:  # a positional comes first
            before = []
        for value in bad_values:
            yield command, name, before, value


def test_every_option_has_bad_values():
    uncovered = [
        f"{command} {option_name(action)}"
        for command, action in value_options()
        if action.choices is None
        and action.type not in BAD_BY_TYPE
        and (command, option_name(action)) not in BAD_NAMED
    ]
    assert uncovered == [], f"options without bad values in {__name__}: {uncovered}"


class Overran(Exception):
    pass


def run_bad(argv: list[str], capsys) -> tuple[int, list[str]]:
    """``main(argv)`` under an alarm: its exit status and stderr lines."""

    def overran(signum, frame):
        raise Overran(f"{argv} still running after {CASE_LIMIT_S} s: the bad value was taken")

    previous = signal.signal(signal.SIGALRM, overran)
    signal.alarm(CASE_LIMIT_S)
    try:
        try:
            status = main(argv)
        except SystemExit as stop:
            status = stop.code if isinstance(stop.code, int) else 1
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    return status, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize(
    ("command", "option", "before", "value"),
    list(typed_cases()),
    ids=[f"{c}-{o}={v!r}" for c, o, _, v in typed_cases()],
)
def test_bad_typed_value_is_one_line_exit_2(command, option, before, value, capsys):
    # '=': a value that starts with '-' too
    argv = [command, *before, f"{option}={value}" if option.startswith("-") else value]
    status, lines = run_bad(argv, capsys)
    assert status == 2, (argv, lines)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"swarm {command}: error: "), lines[0]
    assert option in lines[0] or repr(value) in lines[0], lines[0]


@pytest.mark.parametrize(
    ("command", "option"), sorted(BAD_NAMED), ids=[f"{c}-{o}" for c, o in sorted(BAD_NAMED)]
)
def test_bad_named_value_is_one_line_exit_2(command, option, tmp_path, capsys):
    before, value, expected = BAD_NAMED[(command, option)]
    a_file = tmp_path / "a-file"
    a_file.write_text("not a directory\n")
    value = value.replace(A_FILE, str(a_file))
    argv = [command, *before, *([option, value] if option.startswith("-") else [value])]
    status, lines = run_bad(argv, capsys)
    assert status == 2, (argv, lines)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"swarm {command}: error: "), lines[0]
    assert expected in lines[0], (expected, lines[0])


def test_limit_spec_reads_good_values():
    assert usage.limit_spec("12:100") == (None, 12, 100)
    assert usage.limit_spec("cycle:100:10") == ("cycle", 100, 10)


@pytest.mark.slow
@pytest.mark.parametrize("keep", ["head", "tail"])
def test_a_truncated_dataset_is_one_line_exit_2_and_leaves_no_output(tmp_path, capsys, keep):
    data = tmp_path / "bc.npz"
    assert main(["collect", "--samples", "300", "--out", str(data), "--quiet"]) == 0
    whole = data.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(whole[: len(whole) // 2] if keep == "head" else whole[: len(whole) - 100])
    capsys.readouterr()
    for algo in ("bc", "dagger"):
        out = tmp_path / f"out-{algo}"
        status, lines = run_bad(["train", "--algo", algo, "--data", str(cut), "--out", str(out)], capsys)
        assert status == 2, lines
        assert len(lines) == 1 and str(cut) in lines[0] and "truncated or damaged" in lines[0], lines
        assert not out.exists()  # no empty checkpoints/ left behind


@pytest.mark.slow
def test_sweep_of_gnn_without_model_runs_the_shipped_one(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", "--controllers", "gnn", "--sizes", "6", "--seeds", "2", "--topologies", "cycle"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    config = json.loads((out / "sweep_config.json").read_text())
    assert Path(config["model"]).resolve() == Path(MODEL).resolve()
    assert [p.name[:12] for p in (out / "cells").iterdir()] == ["cycle_6_gnn-"]
