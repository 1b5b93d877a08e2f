"""Exit statuses that mean one thing each (swarm/cli.py): 0 success, 1 ran but not successful or
could not complete, 2 bad input only (nothing started), 130 interrupted (tests/test_runtime.py,
Ctrl-C). Real processes: a sim server killed from outside, model files damaged on purpose."""

from __future__ import annotations

import json
import os
import signal
import sys
import zipfile
from pathlib import Path

import psutil
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))

from test_runtime import Run, max_pairwise_of, scenario_file

from swarm.cli import main
from swarm.scenarios.results import read_trajectory

PROJECT_ROOT = Path(__file__).resolve().parent.parent
MODEL = PROJECT_ROOT / "models" / "gnn_default.npz"


@pytest.mark.runtime
def test_a_sim_server_killed_from_outside_is_exit_1_not_bad_input(tmp_path):
    out = tmp_path / "out"
    run = Run(scenario_file(tmp_path, "cycle-local_consensus", sim__duration=120.0), out)
    run.wait_for(lambda: run.ticks() >= 10)
    servers = [
        child
        for child in psutil.Process(run.process.pid).children(recursive=True)
        if child.cmdline()[1:3] == ["-m", "sim_server"]
    ]
    assert len(servers) == 1
    os.kill(servers[0].pid, signal.SIGKILL)
    code, _, stderr = run.finish()
    lines = stderr.strip().splitlines()
    assert code == 1, stderr
    assert len(lines) == 1 and lines[0].startswith("swarm run: run failed: sim server exited with status -9")
    assert "Traceback" not in stderr
    assert run.survivors() == []
    assert json.loads((out / "metrics.json").read_text())["incomplete"]  # what was run is kept


def _bad_models(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """Model files that are not usable policies, each with the reason the error must give."""
    good = MODEL.read_bytes()
    text = tmp_path / "notes.txt"
    text.write_text("this is not a model\n")
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good[: len(good) // 2])
    damaged = tmp_path / "damaged.npz"
    middle = len(good) // 2
    damaged.write_bytes(
        good[:middle] + bytes(b ^ 0xFF for b in good[middle : middle + 64]) + good[middle + 64 :]
    )
    foreign = tmp_path / "foreign.npz"
    with zipfile.ZipFile(foreign, "w") as archive:
        archive.writestr("weights.npy", b"not numpy")
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    return {
        "text": (text, "not a policy file (not an .npz archive)"),
        "truncated": (truncated, "damaged or truncated policy file"),
        "damaged": (damaged, "damaged or truncated policy file"),
        "foreign": (foreign, ""),
        "empty": (empty, "not a policy file (not an .npz archive)"),
    }


@pytest.mark.parametrize("engine", ["kinematic", "pybullet"])
def test_a_bad_model_file_is_one_line_exit_2_before_anything_starts(tmp_path, engine, capsys):
    """In-process (``swarm.cli.main``): the file is read before any process would start."""
    for name, (model, reason) in _bad_models(tmp_path).items():
        data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-gnn.yaml").read_text())
        data["controller"]["model"] = str(model)
        data["sim"]["duration"] = 2.0
        scenario = tmp_path / f"{name}.yaml"
        scenario.write_text(yaml.safe_dump(data))
        out = tmp_path / f"out-{engine}-{name}"
        code = main(["run", str(scenario), "--engine", engine, "--out", str(out)])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2, (name, lines)
        assert len(lines) == 1 and str(model) in lines[0] and reason in lines[0], (name, lines)
        assert not (out / "trajectory.jsonl").exists() and not (out / "logs").exists(), name  # nothing ran


@pytest.mark.runtime
def test_a_run_killed_after_it_converged_is_exit_1_incomplete(tmp_path):
    """README: exit 1 also for a run that could not complete, even one whose swarm had already met
    its threshold: a kill_server fault at 6 s of a 20 s run, the 4 robots within 0.8 m long before."""
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/faults/kill-server.yaml").read_text())
    data["robots"]["count"] = 4
    data["robots"]["init"]["random"].update(x=[-1, 1], y=[-1, 1])
    data["sim"]["duration"] = 20.0
    data["success"]["threshold"]["pybullet"] = 0.8
    data["faults"] = [{"at": 6.0, "kind": "kill_server"}]
    scenario = tmp_path / "killed-after-convergence.yaml"
    scenario.write_text(yaml.safe_dump(data))
    out = tmp_path / "out"
    run = Run(scenario, out)
    code, stdout, stderr = run.finish()
    _, poses, _ = read_trajectory(out / "trajectory.jsonl")
    spread_m = max_pairwise_of(poses)  # computed here, not by the code under test
    assert spread_m[0] > 0.8 and spread_m[-1] <= 0.8, spread_m  # it converged during the run
    assert len(poses) < 0.5 * round(20.0 / 0.05)  # and ended early
    outcome = json.loads((out / "metrics.json").read_text())
    assert outcome["converged"] is True and outcome["incomplete"], outcome
    assert code == 1, (stdout, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm run: run incomplete: "), stderr
    assert "kill_server" in lines[0]
    assert "  PARTIAL: " in stdout and "  converged: max_pairwise <= 0.8 m" in stdout, stdout
    assert run.survivors() == []
