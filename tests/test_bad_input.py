"""Bad input to every command of the project: one clear line on stderr, a non-zero exit, no traceback.

Each case of ``swarm`` runs its ``main`` in-process; the others run the real command in a
subprocess (``python -m robot_agent`` and the ``robot-agent`` script, ``python -m sim_server``,
``python -m robot_agent.central``, ``python -m swarm.runtime.acl``). Each checks the exit status, that
stderr is exactly one line naming the problem, and for the agents that an unreachable endpoint is
given up after a bounded time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest
import yaml

from swarm.cli import main
from swarm.runtime.procs import free_tcp_port

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SCENARIO = PROJECT_ROOT / "scenarios" / "thesis" / "cycle-local_consensus.yaml"
ACL_SCENARIO = PROJECT_ROOT / "scenarios" / "security" / "acl.yaml"
PYTHON = sys.executable


def one_line_error(command: list[str], expected: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    """Run ``command``; it must exit non-zero with one stderr line containing ``expected``."""
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=timeout_s, cwd=PROJECT_ROOT, stdin=subprocess.DEVNULL
    )
    lines = result.stderr.strip().splitlines()
    assert result.returncode != 0, (command, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr, result.stderr
    assert len(lines) == 1, result.stderr
    assert expected in lines[0], (expected, lines[0])
    return result


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Bad files of every kind."""
    root = tmp_path_factory.mktemp("bad")
    contents = {
        "bad_yaml": "name: x\nrobots: {count: 3\n",
        "bad_key_scenario": "name: x\nrobots: {count: 3}\ntopology: {kind: cycle}\nbogus: 1\n",
        "bad_yaml_config": "epochs: [1\n",
        "bad_key_config": "bogus_key: 1\n",
        "bad_value_config": "direction_weight: speed\n",
        "not_a_policy": "this is not an npz file\n",
        "credentials": "robot-0:secret\n",
        "open_scenario": SCENARIO.read_text().replace("sim: {", "sim: {acl: false, ", 1),
        "disk_scenario": "name: x\nrobots: {count: 3}\ntopology: {kind: disk, radius_m: 2}\n"
        "success: {threshold: 1.0}\n",
    }
    paths = {name: root / name for name in contents}
    for name, text in contents.items():
        paths[name].write_text(text)
    paths["missing"] = root / "missing.yaml"
    return paths


# ----------------------------------------------------------------------------- swarm


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "{missing}"], "no such scenario file"),
        (["run", "{bad_yaml}"], "invalid YAML at line"),
        (["run", "{bad_key_scenario}"], "bogus: unknown key"),
        (["run", str(SCENARIO), "--duration", "-1"], "--duration: must be greater than 0"),
        (["run", str(SCENARIO), "--engine", "warp"], "argument --engine: invalid choice"),
        (["run", str(SCENARIO), "--out", "/proc/no/such/dir", "--engine", "kinematic"], "/proc/no"),
        (["sweep", "--config", "{missing}"], "no such sweep config file"),
        (["sweep", "--config", "{bad_yaml_config}"], "invalid YAML"),
        (["sweep", "--config", "{bad_key_config}"], "bogus_key: unknown key"),
        (["sweep", "--sizes", "1"], "every N must be at least 2"),
        (["evaluate", "{missing}"], "no such policy file"),
        (["evaluate", "{not_a_policy}", "--sizes", "4", "--seeds", "1", "--out", "{out}"], "policy file"),
        (["collect", "--preset", "nope"], "unknown preset 'nope'"),
        (["collect", "--samples", "0", "--out", "{out}/c.npz"], "samples"),
        (["train", "--algo", "bc", "--config", "{missing}"], "no such training config file"),
        (["train", "--algo", "bc", "--config", "{bad_yaml_config}"], "invalid YAML"),
        (
            ["train", "--algo", "bc", "--config", "{bad_key_config}"],
            "bad_key_config: unknown bc option 'bogus_key'",
        ),
        (
            ["train", "--algo", "coverage", "--config", "{bad_value_config}"],
            "bad_value_config: coverage option",
        ),
        (["train", "--algo", "nope"], "argument --algo: invalid choice"),
        (["fly"], "invalid choice: 'fly'"),
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else None,
)
def test_swarm_commands(files, tmp_path, monkeypatch, capsys, args, expected):
    """In-process (``swarm.cli.main``, what the console script calls; tests/test_cli.py runs the
    installed script once): exit 2, no traceback, one stderr line."""
    names = {**{name: str(path) for name, path in files.items()}, "out": str(tmp_path / "out")}
    argv = [*(arg.format(**names) for arg in args), "--quiet"]
    if args[0] in ("train", "fly"):
        argv.remove("--quiet")  # train has no --quiet
    monkeypatch.chdir(PROJECT_ROOT)  # as the subprocess ran: relative paths from the project root
    try:
        code = main(argv)
    except SystemExit as exit_info:  # argparse's usage errors
        code = exit_info.code
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2, lines
    assert len(lines) == 1 and expected in lines[0], (expected, lines)


# ----------------------------------------------------------------------------- robot agents


@pytest.mark.runtime
def test_agent_gives_up_on_an_unreachable_endpoint_after_its_startup_timeout():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"  # nothing listens there
    start_s = time.monotonic()
    result = one_line_error(
        [PYTHON, "-m", "robot_agent", "--robot", "3", "--connect", endpoint, "--startup-timeout", "1.5"],
        f"robot 3: could not connect to {endpoint} within 1.5 s",
    )
    assert result.returncode == 1
    assert time.monotonic() - start_s >= 1.4  # it waited its timeout (not hanging: one_line_error's 60 s)


@pytest.mark.runtime
def test_central_gives_up_on_an_unreachable_endpoint_after_its_startup_timeout():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    start_s = time.monotonic()
    one_line_error(
        [PYTHON, "-m", "robot_agent.central", "--connect", endpoint, "--startup-timeout", "1"],
        f"could not connect to {endpoint} within 1 s",
    )
    assert time.monotonic() - start_s >= 0.9  # it waited its timeout (not hanging: one_line_error's 60 s)


def _console_script(name: str) -> str:
    path = Path(sysconfig.get_path("scripts")) / name
    if not path.exists():
        pytest.skip(f"{name} is not installed")
    return str(path)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--robot", "-1"], "argument --robot: a robot id is a number >= 0"),
        (["--robots", "0-x"], "robot ids like 3, 0-5 or 0,2,7-9"),
        (["--robot", "1", "--run", "a/b"], "run id must match"),
        (["--robot", "1", "--connect", "nonsense"], "Endpoints must be of the form"),
        (["--robot", "1", "--startup-timeout", "0"], "argument --startup-timeout: seconds > 0"),
        (["--robot", "1", "--credentials", "{missing}"], "no such credentials file"),
        (["--robot", "1", "--credentials", "{not_a_policy}"], "expected lines of user:password"),
        (["--robot", "1", "--credentials", "{credentials}", "--password", "x"], "not both"),
        (["--robot", "1", "--user", "robot-1"], "--user needs --password"),
        (["--connect", "tcp/127.0.0.1:7447"], "one of the arguments --robot --robots is required"),
        (["--robot", "1", "--ros2", "--scenario", "{disk_scenario}"], "a disk graph needs the sim server"),
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else None,
)
def test_agent_command_line(files, args, expected):
    names = {name: str(path) for name, path in files.items()}
    command = [_console_script("robot-agent"), *(arg.format(**names) for arg in args)]
    assert one_line_error(command, expected).returncode == 2


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--run", "a*b"], "run id must match"),
        (["--connect", "nonsense"], "Endpoints must be of the form"),
        (["--startup-timeout", "-2"], "--startup-timeout must be > 0"),
        (["--lease-ms", "soon"], "argument --lease-ms: invalid int value"),
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else None,
)
def test_central_command_line(args, expected):
    assert one_line_error([PYTHON, "-m", "robot_agent.central", *args], expected).returncode == 2


@pytest.fixture(scope="module")
def sim_of_three(tmp_path_factory):
    """A sim server of a 3-robot run waiting for its agents; yields (endpoint, run id, log path)."""
    root = tmp_path_factory.mktemp("sim")
    data = yaml.safe_load(SCENARIO.read_text())
    data["robots"]["count"] = 3
    scenario = root / "three.yaml"
    scenario.write_text(yaml.safe_dump(data))
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    log = root / "sim.log"
    with open(log, "w") as output:
        server = subprocess.Popen(
            [
                *(PYTHON, "-m", "sim_server", "--scenario", str(scenario), "--out", str(root / "out")),
                *("--run", "three", "--listen", endpoint, "--startup-timeout", "60"),
            ],
            stdout=output,
            stderr=subprocess.STDOUT,
            cwd=PROJECT_ROOT,
        )
    try:
        deadline = time.monotonic() + 30
        while "listening on" not in log.read_text():
            assert server.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        yield endpoint, log
    finally:
        server.terminate()
        server.wait(timeout=10)


@pytest.mark.runtime
@pytest.mark.parametrize("run", [["--run", "three"], []], ids=["with --run", "discovering the run"])
def test_agent_with_a_robot_id_the_run_does_not_have(sim_of_three, run):
    endpoint, _ = sim_of_three
    result = one_line_error(
        [PYTHON, "-m", "robot_agent", "--robot", "7", "--connect", endpoint, "--startup-timeout", "5", *run],
        "robot 7: ",
    )
    assert "no robot 7 in this run of 3 robots" in result.stderr and result.returncode == 1


@pytest.mark.runtime
def test_sim_server_on_a_port_in_use(sim_of_three, tmp_path, _run_key):
    endpoint, _ = sim_of_three  # its server listens there already
    result = one_line_error(
        [
            PYTHON,
            "-m",
            "sim_server",
            "--scenario",
            str(SCENARIO),
            "--out",
            str(tmp_path),
            "--listen",
            endpoint,
        ],
        "cannot open the Zenoh session",
    )
    assert "Address already in use" in result.stderr and result.returncode == 2


# ----------------------------------------------------------------------------- sim server


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--scenario", "{missing}"], "no such scenario file"),
        (["--scenario", "{bad_key_scenario}"], "bogus: unknown key"),
        (["--scenario", str(SCENARIO), "--run", "a/b"], "run id must match"),
        (["--scenario", str(SCENARIO), "--listen", "nonsense"], "Endpoints must be of the form"),
        (["--scenario", str(ACL_SCENARIO)], "sets sim.acl: give --users FILE"),
        (["--scenario", str(ACL_SCENARIO), "--users", "{missing}"], "no such users file"),
        (["--scenario", str(SCENARIO), "--tls", "{missing}"], "ca.pem: no such file"),
        (["--scenario", "{open_scenario}", "--users", "{credentials}"], "sets sim.acl: false"),
        (["--scenario", str(SCENARIO), "--out", "/proc/no/such/dir"], "/proc/no"),
        (["--scenario", str(SCENARIO)], "the following arguments are required: --out"),
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else None,
)
def test_sim_server_command_line(files, tmp_path, args, expected, _run_key):
    names = {name: str(path) for name, path in files.items()}
    command = [PYTHON, "-m", "sim_server", *(arg.format(**names) for arg in args)]
    if "--out" not in command and "required" not in expected:
        command += ["--out", str(tmp_path / "out")]
    command += ["--listen", f"tcp/127.0.0.1:{free_tcp_port()}"] if "--listen" not in command else []
    assert one_line_error(command, expected).returncode == 2


def test_acl_credentials_command(tmp_path):
    one_line_error(
        [PYTHON, "-m", "swarm.runtime.acl", "credentials", "--robots", "0", "--out", str(tmp_path)],
        "--robots",
    )
    result = subprocess.run(
        [PYTHON, "-m", "swarm.runtime.acl", "credentials", "--robots", "2", "--out", str(tmp_path / "c")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "--users" in result.stdout and sorted(os.listdir(tmp_path / "c")) == [
        "robot-0.cred",
        "robot-1.cred",
        "users.txt",
    ]
    assert json.dumps(result.stderr) == '""'


@pytest.fixture
def _run_key(monkeypatch):
    """A run key, as `swarm run` gives its processes: without one the sim server warns on stderr."""
    monkeypatch.setenv("SWARM_RUN_KEY", "ab" * 32)
