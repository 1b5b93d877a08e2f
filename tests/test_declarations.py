"""Each agent subscribes only to its own pose and its graph neighbours' messages: checked from outside
the agents, in the router's own view.

The sim server runs with its router's admin space open (``--admin-space``, read-only); the agents are
started by hand as on other hosts. Mid-run an outside client (``tests/outside.py``, no project code)
asks the router ``@/*/router/subscriber/**`` (every subscription it routes for, with the Zenoh ids of
the clients that declared it) and ``@/*/router/token/**`` (who holds which liveliness token: agent i is
the client holding ``alive/agent/i``). Each agent's subscriptions must be exactly its pose and the
messages of its neighbours on the cycle, computed here from i +- 1 mod N, not from the agent's record;
an agent that declared more (a wildcard, a non-neighbour) fails whatever it records.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

PROJECT_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(PROJECT_ROOT / "tests"))

import outside  # noqa: E402

pytestmark = pytest.mark.runtime  # real processes: the fast tier leaves it out

COUNT = 6


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _router_view(
    endpoint: str, run: str, deadline_s: float = 60.0
) -> tuple[dict[str, set[str]], dict[str, str]]:
    """``client zid -> subscribed keys`` and ``token key -> client zid``, as the router reports them,
    once every agent's token is there (retried up to ``deadline_s``)."""
    session = outside.open_session(endpoint)
    try:
        give_up_s = time.monotonic() + deadline_s
        while True:
            subscriptions: dict[str, set[str]] = {}
            tokens: dict[str, str] = {}
            for what in ("subscriber", "token"):
                for reply in session.get(f"@/*/router/{what}/**", timeout=5.0):
                    if reply.ok is None:
                        continue
                    key = str(reply.ok.key_expr).split(f"/router/{what}/", 1)[1]
                    clients = json.loads(reply.ok.payload.to_bytes())["clients"]
                    for zid in clients:
                        if what == "subscriber":
                            subscriptions.setdefault(zid, set()).add(key)
                        else:
                            tokens[key] = zid
            agents = [f"swarm/{run}/alive/agent/{i}" for i in range(COUNT)]
            if all(token in tokens for token in agents) or time.monotonic() > give_up_s:
                return subscriptions, tokens
            time.sleep(0.2)
    finally:
        session.close()


def test_the_router_sees_each_agent_subscribe_to_its_pose_and_neighbours_only(tmp_path):
    data = yaml.safe_load((PROJECT_ROOT / "scenarios/thesis/cycle-local_consensus.yaml").read_text())
    data["robots"]["count"] = COUNT
    data["sim"]["duration"] = 600.0  # stopped once the router has been asked
    scenario = tmp_path / "cycle.yaml"
    scenario.write_text(yaml.safe_dump(data))
    endpoint, run, out = f"tcp/127.0.0.1:{_free_port()}", "declarations", tmp_path / "out"
    python = sys.executable
    command = [python, "-m", "sim_server", "--scenario", str(scenario), "--out", str(out), "--run", run]
    server = subprocess.Popen(
        [*command, "--listen", endpoint, "--admin-space", "--quiet"],
        cwd=PROJECT_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    agents = subprocess.Popen(
        [python, "-m", "robot_agent", "--robots", f"0-{COUNT - 1}", "--connect", endpoint, "--run", run],
        cwd=PROJECT_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        subscriptions, tokens = _router_view(endpoint, run)
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=60)
        agents.communicate(timeout=60)
    prefix = f"swarm/{run}"
    for i in range(COUNT):
        zid = tokens.get(f"{prefix}/alive/agent/{i}")
        assert zid is not None, (i, sorted(tokens))
        neighbours = [(i - 1) % COUNT, (i + 1) % COUNT]
        expected = {f"{prefix}/robot/{i}/pose", *(f"{prefix}/agent/{j}/msg" for j in neighbours)}
        assert subscriptions.get(zid, set()) == expected, (i, sorted(subscriptions.get(zid, set())))
        assert [key for key, holder in tokens.items() if holder == zid] == [f"{prefix}/alive/agent/{i}"]
    assert agents.returncode == 0 and server.returncode in (0, 130)
