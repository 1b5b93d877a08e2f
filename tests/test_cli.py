"""Tests for the ``swarm`` command line (swarm.cli) and the results directory it writes.

The CLI runs in-process through ``swarm.cli.main`` for speed; one test runs the installed console
script in a subprocess. Exit status: 0 success met, 1 ran but not met, 2 bad input.
"""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from test_scenario import BAD_SCENARIOS, THESIS_SCENARIOS, VALID, write_case

from swarm.cli import main
from swarm.core import graphs
from swarm.scenarios.results import read_trajectory
from swarm.scenarios.scenario import load_scenario, parse_scenario

METRICS_KEYS = {
    "converged",
    "convergence_time_s",
    "final_metric",
    "metric",
    "threshold",
    "lower_bound_s",
    "components",
}

# Simulated seconds per thesis scenario: long enough to converge (measured convergence times in the
# comments, all from the seed-1 start with v_max 0.5 m/s), short enough to keep the runs cheap (writing
# the GIF, up to 150 frames, costs most of a run).
DURATIONS_S = {
    "complete-centralized": 5.0,  # 4.60 s
    "complete-local_consensus": 5.0,  # 4.65 s
    "cycle-centralized": 5.0,  # 4.60 s
    "cycle-local_consensus": 7.0,  # 6.35 s
    "line-centralized": 5.0,  # 4.60 s
    "line-local_consensus": 17.0,  # 15.90 s (a line is the slowest graph)
    "random-centralized": 5.0,  # 4.60 s
    "random-local_consensus": 8.0,  # 7.15 s
    "weak-centralized": 5.0,  # 4.60 s: the centralized expert uses everyone's position, not the graph
    "weak-local_consensus": 3.5,  # triangles 2.95 s and 2.70 s; never globally
    "complete-gnn": 5.0,  # 4.20 s (models/gnn_default.npz, the default of controller gnn)
    "cycle-gnn": 5.0,  # 4.25 s
    "line-gnn": 5.0,  # 4.25 s
    "random-gnn": 5.0,  # 4.20 s
    "weak-gnn": 3.5,  # two triangles 2.55 s and 2.45 s, never globally
}


def run_cli(*args: str) -> int:
    return main(["run", *args, "--quiet"])


@pytest.mark.parametrize("path", THESIS_SCENARIOS, ids=lambda path: path.stem)
def test_thesis_scenario_runs_and_writes_results(tmp_path, capsys, path):
    duration = DURATIONS_S[path.stem]
    out = tmp_path / "results"
    # the kinematic engine (in-process); the pybullet runtime is covered by tests/test_runtime.py
    code = run_cli(str(path), "--out", str(out), "--duration", str(duration), "--engine", "kinematic")
    captured = capsys.readouterr()
    assert captured.err == ""
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= METRICS_KEYS
    assert metrics["metric"] == "max_pairwise"
    assert metrics["threshold"] == load_scenario(path).success.threshold_for("kinematic")
    adjacency = load_scenario(path).adjacency()
    components = graphs.connected_components(adjacency)

    if path.stem in ("weak-local_consensus", "weak-gnn"):
        # two triangles: global consensus is impossible, each triangle meets on its own
        assert code == 1
        assert metrics["converged"] is False
        assert metrics["convergence_time_s"] is None
        assert metrics["final_metric"] > metrics["threshold"]
        assert "NOT converged" in captured.out
    else:
        assert code == 0
        assert metrics["converged"] is True
        assert metrics["final_metric"] <= metrics["threshold"]
        assert 0 < metrics["convergence_time_s"] <= duration
        assert "converged" in captured.out
    assert [component["robots"] for component in metrics["components"]] == components
    assert all(component["converged"] for component in metrics["components"])
    if path.stem.startswith("weak-"):
        assert len(metrics["components"]) == 2
        assert "2 components" in captured.out

    # no controller beats the physical limit (docs/design.md, "Metrics and the lower bound")
    assert metrics["lower_bound_s"] > 0
    for time_s in [metrics["convergence_time_s"], *(c["convergence_time_s"] for c in metrics["components"])]:
        assert time_s is None or time_s >= 0
    if metrics["converged"]:
        assert metrics["convergence_time_s"] >= metrics["lower_bound_s"]

    # the resolved scenario: every default filled in, the command-line duration applied
    resolved = parse_scenario(yaml.safe_load((out / "scenario.yaml").read_text()))
    assert resolved.sim.duration_s == duration
    assert resolved.model_copy(update={"sim": load_scenario(path).sim}) == load_scenario(path)

    # one trajectory line per tick, ticks 0..steps
    control_period = resolved.sim.control_period_s
    steps = round(duration / control_period)
    lines = (out / "trajectory.jsonl").read_text().splitlines()
    assert len(lines) == steps + 1
    records = [json.loads(line) for line in lines]
    assert [record["tick"] for record in records] == list(range(steps + 1))
    np.testing.assert_allclose([r["time_s"] for r in records], np.arange(steps + 1) * control_period)
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    assert poses.shape == (steps + 1, 6, 3)
    np.testing.assert_allclose(poses[0], resolved.initial_poses())

    for picture, kind in [("convergence.png", "PNG"), ("animation.gif", "GIF")]:
        with Image.open(out / picture) as image:
            assert image.format == kind
            assert image.size[0] > 100 and image.size[1] > 100
            image.load()
    with Image.open(out / "animation.gif") as gif:
        assert getattr(gif, "n_frames", 1) > 1
    assert (out / "logs").is_dir()


@pytest.mark.parametrize(
    ("content", "key", "reason"),
    [case[1:] for case in BAD_SCENARIOS],
    ids=[case[0] for case in BAD_SCENARIOS],
)
def test_bad_scenario_one_line_exit_2_and_nothing_starts(tmp_path, monkeypatch, capsys, content, key, reason):
    monkeypatch.chdir(tmp_path)
    path = write_case(tmp_path, content)
    assert run_cli(str(path)) == 2  # no --out: a run would create runs/<name>-<time> here
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert str(path) in lines[0] and key in lines[0] and reason in lines[0]
    assert lines[0].startswith("swarm run: error: ")
    assert "Traceback" not in captured.err
    assert captured.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.yaml"]


def test_missing_scenario_file_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    assert run_cli("no-such-scenario.yaml", "--out", str(out)) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    assert "no-such-scenario.yaml" in lines[0] and "no such scenario file" in lines[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("options", "key", "reason"),
    [
        (["--duration", "-1"], "--duration", "greater than 0"),
        (["--model", "no-such-model.npz"], "--model", "model file not found"),
    ],
)
def test_bad_command_line_override_exit_2(tmp_path, monkeypatch, capsys, options, key, reason):
    monkeypatch.chdir(tmp_path)
    path = write_case(tmp_path, VALID)
    try:
        status = run_cli(str(path), *options)
    except SystemExit as stop:  # a value the option's type refuses: argparse exits at once
        status = stop.code
    assert status == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    assert key in lines[0] and reason in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.yaml"]


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["sweep", "--help"]])
def test_help_exits_0(capsys, argv):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "usage: swarm" in out
    if argv[0] == "run":
        assert "--duration" in out and "Exit 0" in out


@pytest.mark.parametrize("argv", [[], ["run", "--no-such-option"], ["fly"]])
def test_usage_errors_exit_2(capsys, argv):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.splitlines()  # one line, not the whole usage
    assert len(lines) == 1 and lines[0].startswith("swarm") and "error:" in lines[0] and "--help" in lines[0]


def installed_console_script() -> str:
    candidate = Path(sysconfig.get_path("scripts")) / "swarm"
    found = str(candidate) if candidate.is_file() else shutil.which("swarm")
    assert found, "the swarm console script is not installed (pip install -e .)"
    return found


def test_installed_console_script(tmp_path):
    # the real process: exit status and stderr as a shell sees them (bad input: exit 2, one line, no
    # traceback, nothing written; --help: exit 0). Full runs are covered in-process above.
    swarm = installed_console_script()
    bad = write_case(tmp_path, {**VALID, "colour": "red"})
    done = subprocess.run([swarm, "run", str(bad)], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"swarm run: error: {bad}: colour: unknown key"]
    assert done.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenario.yaml"]
    done = subprocess.run([swarm, "run", "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0
    assert "usage: swarm run" in done.stdout


def test_verbosity_decides_what_the_library_shows(tmp_path, capsys):
    """The summary lines are the CLI's own and the same at every verbosity; -v adds the library's
    debug records (here the runner's), --quiet keeps its information records off stdout."""
    scenario = str(THESIS_SCENARIOS[0])
    common = ["run", scenario, "--engine", "kinematic", "--duration", "1"]
    outputs = {}
    for name, flags in {"default": [], "verbose": ["-v"], "quiet": ["--quiet"]}.items():
        main([*common, "--out", str(tmp_path / name), *flags])
        outputs[name] = capsys.readouterr().out.replace(str(tmp_path / name), "OUT")
    debug = [line for line in outputs["verbose"].splitlines() if "kinematic engine" in line]
    assert len(debug) == 1 and debug[0].endswith("-> OUT")
    assert (
        outputs["default"]
        == outputs["quiet"]
        == "\n".join(line for line in outputs["verbose"].splitlines() if line not in debug) + "\n"
    )
    assert "kinematic engine" not in outputs["default"]
    logging.getLogger("swarm").info("an information record")
    assert capsys.readouterr().out == ""  # --quiet was the last setting: warnings and errors only
    main([*common, "--out", str(tmp_path / "again")])
    logging.getLogger("swarm.anything").info("an information record")
    assert capsys.readouterr().out.splitlines()[-1] == "an information record"
