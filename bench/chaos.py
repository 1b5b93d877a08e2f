"""Seeded chaos soak of the distributed runtime: many short real runs under random faults.

Each run is a small swarm (3-5 robots, local consensus, a complete, cycle or line graph, lockstep or
realtime, a few seconds of sim time) started with ``python -m swarm.cli run`` as a user would, with a
random schedule drawn from the run's seed:

- process faults done by the runner: ``kill_agent``, ``hang_agent``, ``restart_agent``, ``kill_server``;
- link faults: ``drop_link`` (with or without ``restore_link``), ``packet_loss``, ``delay``;
- forged samples from an outside process (``tests/outside.py``, which imports none of the project's
  code): a genuine pose, message and command of the run, each put once with its tick moved 10^6 ahead;
- or, instead, one outside attack of issue 19 (``tests/outside.py attack``: two poses 10^6 ahead on
  the wildcard key, the 40-pose walk, +1/+2 poses, a replayed message, a pose or message flood of
  3000/s for 20 ticks, a zombie liveliness token on an agent's key);
- a death that no fault scheduled (runs without a process fault, 1 in 5): a SIGKILL from outside of
  one agent or of the agents' launcher once the trajectory has a drawn number of ticks.

The runs are open (``sim.acl: false``: the outsiders have no credentials); the run key still
authenticates every sample.

After each run it checks the invariants (a failed one is a *violation*):

1. ``exit``: ``swarm run`` exits 0 (converged) or 1 (not converged, incomplete), never 2 or a signal;
   no ``Traceback`` in its output or in any log of the run;
2. ``processes``: no process of the run (one whose command line names its results directory) is left
   once ``swarm run`` has returned (looked for during 5 s);
3. ``results``: ``metrics.json`` and ``server_stats.json`` parse, ``swarm report`` on the directory exits
   0 or 1 and agrees with the run on ``converged``;
4. ``converge``: a run not ended by ``kill_server`` whose live graph is connected at the end converged
   (the thresholds are loose: a chain of touching robots; the durations leave room for the faults;
   not judged after an outside kill);
5. ``counts``: ``events.jsonl`` holds one line per process fault done (a hang two: hang and resume) and
   nothing else; every receiver that no process fault touched counted each forged sample meant for it
   as ``future`` exactly once (its pose, each live neighbour of the forged message's sender, the
   server's command); a scheduled drop, loss or delay shows in the agents' counters;
6. ``replay``: a lockstep run with link faults only (and forged samples, or an attack other than the
   zombie token) is run a second time without the outsider: the trajectories (poses and applied wheels,
   every tick) are identical;
7. ``named``: the summary names every fault that happened: each process fault done (``fault:`` line),
   each agent the server saw go that no fault touched (``died``/``away``, ``NOT scheduled``), samples
   rejected when forged or attacking samples were sent, whether access control was on; an outside
   SIGKILL fails the run (exit 1) naming each killed robot as an unscheduled death (or freeze, when a
   zombie token outlived it) no earlier than the last tick on disk when it was killed (one earlier in
   realtime, where the server's tick is the last published while it waits for the next boundary), on
   stderr; the exit status is 1 whenever ``health.failures`` is not empty (swarm.runtime.health).

Run: ``python bench/chaos.py --runs 200 --seed 1`` (under ``nice`` on a shared machine). Writes
``bench/results/chaos.json`` (every run: its schedule, exit status, wall time and violations) and
``chaos.md`` after every run, so a soak cut short still leaves its figures. Exit status: 0 no violation,
1 some violation, 2 bad arguments.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import json
import os
import platform
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

PROJECT_ROOT = Path(__file__).resolve().parent.parent
OUTSIDE = PROJECT_ROOT / "tests" / "outside.py"
RESULTS = PROJECT_ROOT / "bench" / "results"
PERIOD_S = 0.05
AHEAD_TICKS = 10**6
RUN_TIMEOUT_S = 240.0
PROCESS_FAULTS = ("kill_agent", "hang_agent", "restart_agent", "kill_server")
LINK_FAULTS = ("drop_link", "packet_loss", "delay")
ATTACKS = ("future2", "walk", "near", "replay", "flood-pose", "flood-msg", "zombie")
"""``tests/outside.py attack --kind``: the outside attacks of issue 19 a run can meet after its start (the
config queryable must come before the agents: tests/test_outside_attacks.py)."""
FLOOD_RATE, FLOOD_TICKS = 3000, 20
"""A flood's samples per second and length in ticks (lower than the tests' 12,000/s: 3 runs share 2 cores)."""
REPORT_LOCK = threading.Lock()


# ----------------------------------------------------------------------------- schedules


def _edges(kind: str, count: int) -> list[tuple[int, int]]:
    if kind == "complete":
        return [(i, j) for i in range(count) for j in range(i + 1, count)]
    edges = [(i, i + 1) for i in range(count - 1)]
    return [*edges, (0, count - 1)] if kind == "cycle" else edges


def draw_plan(seed: int) -> dict:
    """One run's scenario and schedule, from its seed alone."""
    rng = random.Random(seed)
    count = rng.randint(3, 5)
    topology = rng.choice(["complete", "cycle", "line"])
    mode = "realtime" if rng.random() < 0.15 else "lockstep"
    duration_s = 6.0 if mode == "realtime" else 8.0
    steps = round(duration_s / PERIOD_S)
    faults: list[dict] = []
    kinds: list[str] = []
    process = rng.random() < 0.5
    if process:
        kind = rng.choice(PROCESS_FAULTS)
        at_s = round(rng.uniform(0.5, 3.0), 2)
        fault: dict = {"at": at_s, "kind": kind}
        if kind != "kill_server":
            fault["robot"] = rng.randrange(count)
        if kind == "hang_agent":
            fault["duration"] = round(rng.uniform(0.3, 1.5), 2)
        faults.append(fault)
        kinds.append(kind)
    for kind in LINK_FAULTS:
        if rng.random() >= 0.4:
            continue
        kinds.append(kind)
        if kind == "drop_link":
            i, j = rng.choice(_edges(topology, count))
            at_s = round(rng.uniform(0.0, 2.0), 2)
            faults.append({"at": at_s, "kind": "drop_link", "link": [i, j]})
            if topology == "line" or rng.random() < 0.5:  # a line must get its link back to gather
                faults.append(
                    {"at": round(at_s + rng.uniform(0.2, 1.5), 2), "kind": "restore_link", "link": [i, j]}
                )
        elif kind == "packet_loss":
            faults.append({"kind": "packet_loss", "p": round(rng.uniform(0.05, 0.4), 2)})
        else:
            start_s = round(rng.uniform(0.0, 2.0), 2)
            until_s = round(start_s + rng.uniform(0.5, 2.0), 2)
            faults.append({"at": start_s, "until": until_s, "kind": "delay", "ticks": rng.randint(1, 4)})
    forge, attack, outside_kill = None, None, None
    if rng.random() < 0.3:  # an outside attack (tests/outside.py attack) instead of the forger
        attack = {
            "kind": rng.choice(ATTACKS),
            "at_tick": rng.randint(10, steps // 3),
            "robot": rng.randrange(count),
            "watch": rng.randrange(count),
        }
        kinds.append(f"attack-{attack['kind']}")
    elif rng.random() < 0.6:
        forge = {
            "at_tick": rng.randint(10, steps // 3),
            "pose": rng.randrange(count),
            "msg": rng.randrange(count),
            "cmd": rng.randrange(count),
        }
        kinds.append("forged")
    if not process and rng.random() < 0.2:  # a death no fault scheduled: SIGKILL from outside
        outside_kill = {
            "target": "launcher" if rng.random() < 0.3 else "agent",
            "robot": rng.randrange(count),
            "at_tick": rng.randint(10, steps // 2),
        }
        kinds.append(f"outside-kill-{outside_kill['target']}")
    scenario = {
        "name": f"chaos-{seed}",
        "robots": {
            "count": count,
            "init": {
                "random": {
                    "seed": rng.randrange(10**6),
                    "x": [-1.0, 1.0],
                    "y": [-1.0, 1.0],
                    "min_separation": 0.4,
                }
            },
        },
        "topology": {"kind": topology},
        "robot": {"v_max": 0.5},
        "controller": {"kind": "local_consensus", "gain": 1.0},
        # acl off: the forger is an outsider without credentials (the run key still authenticates)
        "sim": {
            "mode": mode,
            "control_period": PERIOD_S,
            "duration": duration_s,
            "server_lost_s": 1.0,
            "acl": False,
        },
        "faults_seed": rng.randrange(1000),
        # a chain of touching robots (0.24 m each) plus 0.3 m: met by every connected graph that gathers
        "success": {
            "metric": "max_pairwise",
            "threshold": {"kinematic": 0.2, "pybullet": round(0.24 * count + 0.3, 2)},
        },
    }
    if faults:
        scenario["faults"] = faults
    return {
        "seed": seed,
        "scenario": scenario,
        "forge": forge,
        "attack": attack,
        "outside_kill": outside_kill,
        "kinds": kinds,
        "steps": steps,
    }


# ----------------------------------------------------------------------------- one run


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(PROJECT_ROOT), *filter(None, [env.get("PYTHONPATH")])])
    return env


def _lines(out: Path) -> int:
    with contextlib.suppress(OSError):
        return (out / "trajectory.jsonl").read_bytes().count(b"\n")
    return 0


def _kill_from_outside(out: Path, kill: dict, run: subprocess.Popen, done: dict) -> None:
    """SIGKILL robot ``kill["robot"]``'s agent, or the agents' launcher, once the trajectory has
    ``kill["at_tick"]`` lines; ``done``: the tick (lines) it was killed after and the pid."""
    while run.poll() is None and _lines(out) < kill["at_tick"]:
        time.sleep(0.01)
    if run.poll() is not None:
        return
    pid = None
    if kill["target"] == "agent":
        with contextlib.suppress(OSError, ValueError):
            pid = json.loads((out / "logs" / f"agent_{kill['robot']}.json").read_text())["pid"]
    else:  # the launcher: its forked agents share its command line, but their parent is the launcher
        matching: dict[int, int] = {}  # pid -> parent pid
        for entry in Path("/proc").iterdir():
            with contextlib.suppress(OSError, ValueError, IndexError):
                words = (entry / "cmdline").read_bytes().split(b"\0")
                if b"robot_agent" in words and b"--robots" in words and str(out / "logs").encode() in words:
                    matching[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        pid = next((p for p, parent in matching.items() if parent not in matching), None)
    if pid is None:
        return
    done["after_tick"] = _lines(out)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, 9)
        done["pid"] = pid


def _swarm_run(
    scenario_path: Path,
    out: Path,
    forge: dict | None,
    attack: dict | None = None,
    outside_kill: dict | None = None,
    robots: int = 0,
) -> dict:
    """``swarm run`` (and the forger or attacker beside it, and a SIGKILL from outside); exit status,
    output, what the forger or attacker sent, when the outside kill was done."""
    command = [sys.executable, "-m", "swarm.cli", "run", str(scenario_path), "--out", str(out), "--quiet"]
    started_s = time.perf_counter()
    run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    sent, forger_error, attacked, killed = None, None, None, {}
    killer = None
    if outside_kill is not None:
        killer = threading.Thread(
            target=_kill_from_outside, args=(out, outside_kill, run, killed), daemon=True
        )
        killer.start()
    try:
        if attack is not None:
            sent_path = out.parent / f"{out.name}-attack.json"
            log = out / "logs" / "sim_server.log"
            attacker = [
                sys.executable,
                str(OUTSIDE),
                "attack",
                "--kind",
                attack["kind"],
                "--server-log",
                str(log),
            ]
            attacker += ["--at-tick", str(attack["at_tick"]), "--robot", str(attack["robot"])]
            attacker += ["--watch", str(attack["watch"]), "--count", str(robots)]
            attacker += ["--rate", str(FLOOD_RATE), "--ticks", str(FLOOD_TICKS), "--timeout", "90"]
            attacker += ["--quiet-s", "3", "--out", str(sent_path)]
            done = subprocess.run(attacker, capture_output=True, text=True, timeout=180)
            if done.returncode == 0:
                attacked = json.loads(sent_path.read_text())
            else:
                forger_error = done.stderr.strip().splitlines()[-1:] or [f"status {done.returncode}"]
        if forge is not None:  # started at once: it connects as soon as the server listens
            sent_path = out.parent / f"{out.name}-sent.json"
            log = out / "logs" / "sim_server.log"
            forger = [sys.executable, str(OUTSIDE), "forge", "--server-log", str(log)]
            forger += ["--at-tick", str(forge["at_tick"]), "--ahead", str(AHEAD_TICKS)]
            forger += ["--pose", str(forge["pose"]), "--msg", str(forge["msg"]), "--cmd", str(forge["cmd"])]
            # --blind: a sender that is dead (killed, hung) has no genuine sample to move: forge one
            forger += ["--timeout", "60", "--blind", "--out", str(sent_path)]
            done = subprocess.run(forger, capture_output=True, text=True, timeout=180)
            if done.returncode == 0:
                sent = json.loads(sent_path.read_text())["sent"]
            else:  # e.g. it could not connect before the run ended: reported, not a violation
                forger_error = done.stderr.strip().splitlines()[-1:] or [f"status {done.returncode}"]
        stdout, stderr = run.communicate(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        run.kill()
        stdout, stderr = run.communicate()
        stderr += "\nchaos: swarm run timed out"
    if killer is not None:
        killer.join(timeout=5)
    return {
        "status": run.returncode,
        "stdout": stdout,
        "stderr": stderr,
        "sent": sent,
        "attacked": attacked,
        "killed": killed,
        "forger_error": forger_error,
        "wall_s": round(time.perf_counter() - started_s, 2),
    }


def _left_behind(out: Path) -> list[str]:
    """Processes whose command line names ``out`` (the run's server, launcher, agents)."""
    marker = str(out).encode()
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        with contextlib.suppress(OSError):
            cmdline = (entry / "cmdline").read_bytes()
            if marker in cmdline:
                text = cmdline.replace(b"\0", b" ").decode(errors="replace")
                found.append(f"{entry.name}: {text[:120]}")
    return found


def _trajectory(out: Path) -> list[tuple]:
    lines = []
    for line in (out / "trajectory.jsonl").read_text().splitlines():
        with contextlib.suppress(json.JSONDecodeError):
            item = json.loads(line)
            lines.append((item["tick"], item["poses"], item.get("wheels")))
    return lines


def _unplanned_disconnects(out: Path, faults: list[dict]) -> list[int]:
    """Robots whose agent the server saw go and come back although no process fault touched it: the
    router dropped its session (its lease expired: the process was starved for a second on a loaded
    machine) and it reconnected. Not a violation in itself (the run goes on), but the run then has a
    fault that no schedule has, so its lockstep replay is not expected to match."""
    touched = {f.get("robot") for f in faults if f["kind"] in PROCESS_FAULTS}
    try:
        events = json.loads((out / "server_stats.json").read_text()).get("agent_events", [])
    except (OSError, ValueError):
        return []
    return sorted(
        {e["robot"] for e in events if e["event"] in ("gone", "back") and e["robot"] not in touched}
    )


def _report(out: Path) -> tuple[int, str]:
    """``swarm report OUT`` in this process (the CLI's ``main``: no start-up cost per run)."""
    import io

    from swarm.cli import main as swarm

    errors = io.StringIO()
    try:  # one at a time: matplotlib (the plots) and the redirections are not thread-safe
        with REPORT_LOCK, contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
            status = swarm(["report", str(out)])
    except Exception as error:  # a crash of the report is a violation, not the soak's end
        return -1, f"{type(error).__name__}: {error}"
    return status, errors.getvalue().strip()[-200:]


def _all_froze_over(metrics: dict, faults: list[dict], kind: str) -> bool:
    """Every robot froze (no command: an incident the health block named) over the whole window of each
    ``kind`` fault, so no message could be sent in it, let alone delayed (seed 200080: a starved
    realtime run, every agent silent from tick 16 to 52, over a delay from tick 16 to 50)."""
    period_s = float(metrics.get("control_period_s") or 0.05)
    robots = (metrics.get("faults") or {}).get("live_robots") or []
    froze = [i for i in (metrics.get("health") or {}).get("incidents", []) if i.get("kind") == "froze"]
    windows = [f for f in faults if f["kind"] == kind]
    if not froze or not windows or not robots:
        return False
    for fault in windows:
        first = int(fault.get("at_s", fault.get("at", 0.0)) / period_s)
        last = int(fault.get("until_s", fault.get("until", 0.0)) / period_s)
        for robot in robots:
            spans = [(i["tick"], i["tick"] + i["ticks"]) for i in froze if i["robot"] == robot]
            if not any(start <= first + 1 and end >= last for start, end in spans):
                return False
    return True


def _records(out: Path) -> dict[int, dict]:
    records = {}
    for path in sorted((out / "logs").glob("agent_*.json")):
        with contextlib.suppress(ValueError, OSError):
            records[int(path.stem.split("_")[1])] = json.loads(path.read_text())
    return records


def check_run(plan: dict, out: Path, result: dict) -> list[str]:
    """The invariants of one run (module docstring); each violation one line."""
    violations: list[str] = []
    scenario, forge = plan["scenario"], plan["forge"]
    faults = scenario.get("faults", [])
    process = [f for f in faults if f["kind"] in PROCESS_FAULTS]
    server_killed = any(f["kind"] == "kill_server" for f in process)
    touched = {f["robot"] for f in process if "robot" in f} | set(_unplanned_disconnects(out, faults))

    # 1. exit status and tracebacks
    if result["status"] not in (0, 1):
        violations.append(f"exit: swarm run exited {result['status']}: {result['stderr'].strip()[-300:]}")
    texts = [result["stdout"], result["stderr"]]
    texts += [path.read_text(errors="replace") for path in (out / "logs").glob("**/*.log")]
    if any("Traceback" in text for text in texts):
        violations.append("exit: a Traceback in the output or the logs")

    # 2. processes left behind
    left = _left_behind(out)
    give_up_s = time.monotonic() + 5.0
    while left and time.monotonic() < give_up_s:
        time.sleep(0.2)
        left = _left_behind(out)
    if left:
        violations.append(f"processes: {len(left)} left behind: {left[:3]}")

    # 3. results readable, swarm report works
    try:
        metrics = json.loads((out / "metrics.json").read_text())
        stats = json.loads((out / "server_stats.json").read_text())
    except (OSError, ValueError) as error:
        violations.append(f"results: unreadable: {error}")
        return violations
    report_status, report_error = _report(out)
    if report_status not in (0, 1):
        violations.append(f"results: swarm report exited {report_status}: {report_error}")
    else:
        reported = json.loads((out / "metrics.json").read_text())
        if bool(reported.get("converged")) != bool(metrics.get("converged")):
            violations.append("results: swarm report disagrees on converged")
    failures = (metrics.get("health") or {}).get("failures") or []
    expected_status = 0 if metrics.get("converged") and not metrics.get("incomplete") and not failures else 1
    if result["status"] in (0, 1) and result["status"] != expected_status:
        violations.append(f"exit: status {result['status']} for converged={metrics.get('converged')}")

    # 7. named: the summary names every fault that happened, and a death no fault scheduled fails
    violations += _unnamed(plan, out, result, metrics, stats)

    # 4. live connected robots converge (a restarted agent that never came back before the run's end,
    # as the server saw it, leaves its robot standing while metrics counts it live: not judged then)
    restarted = {f["robot"] for f in process if f["kind"] == "restart_agent"}
    back = {e["robot"] for e in stats.get("agent_events", []) if e.get("event") == "back"}
    result["not_back"] = sorted(restarted - back)
    if (
        not result["not_back"]
        and not result.get("killed")
        and not server_killed
        and metrics.get("graph_connected")
        and not metrics.get("converged")
    ):
        violations.append(
            f"converge: live graph connected but not converged (final {metrics.get('final_metric')})"
        )

    # 5. counts consistent with what was injected
    events = []
    with contextlib.suppress(FileNotFoundError):
        events = [
            json.loads(line) for line in (out / "events.jsonl").read_text().splitlines() if line.strip()
        ]
    expected_events = []
    killed_at_s = min((f["at"] for f in process if f["kind"] == "kill_server"), default=None)
    for fault in process:
        if killed_at_s is not None and fault["at"] > killed_at_s:
            continue
        expected_events.append(fault["kind"])
        if fault["kind"] == "hang_agent":
            expected_events.append("resume_agent")
    if sorted(e["kind"] for e in events) != sorted(expected_events):
        violations.append(f"counts: events {[e['kind'] for e in events]}, expected {expected_events}")
    records = _records(out)
    if not server_killed and not result.get("killed"):  # agents killed from outside: counts are gone
        totals = {
            name: sum(r.get("messages", {}).get(name, 0) for r in records.values())
            for name in ("dropped_by_fault", "lost_by_fault", "delayed_by_fault")
        }
        kinds = [f["kind"] for f in faults]
        if "drop_link" in kinds and totals["dropped_by_fault"] == 0:
            violations.append("counts: a link was dropped but no agent counted a dropped message")
        if "packet_loss" in kinds and totals["lost_by_fault"] == 0:
            violations.append("counts: packet loss scheduled but no message counted lost by it")
        silent = _all_froze_over(metrics, faults, "delay")
        if "delay" in kinds and totals["delayed_by_fault"] == 0 and not silent:
            violations.append("counts: a delay scheduled but no message counted delayed")
    sent = result["sent"]
    if forge is not None and sent is not None and not process and not result.get("killed"):
        neighbours = {
            i: [j for j in range(scenario["robots"]["count"]) if j != i and _adjacent(scenario, i, j)]
            for i in range(scenario["robots"]["count"])
        }
        if "pose" in sent and forge["pose"] not in touched:
            poses = records.get(forge["pose"], {}).get("poses", {})
            got = poses.get("future", 0) + poses.get("unauthenticated", 0)  # the run key: unauthenticated
            if got != 1:
                violations.append(f"counts: robot {forge['pose']} counted {got} future poses, 1 forged")
        if "msg" in sent:
            for i in [j for j in neighbours[forge["msg"]] if j not in touched]:
                messages = records.get(i, {}).get("messages", {})
                got = messages.get("future", 0) + messages.get("unauthenticated", 0)
                if got != 1:
                    violations.append(
                        f"counts: robot {i} counted {got} future messages, 1 forged by {forge['msg']}"
                    )
        commands = stats.get("future_commands", 0) + stats.get("unauthenticated_commands", 0)
        if "cmd" in sent and commands != 1:
            violations.append(
                f"counts: the server counted {commands} future or unauthenticated commands, 1 forged"
            )
    return violations


def _unnamed(plan: dict, out: Path, result: dict, metrics: dict, stats: dict) -> list[str]:
    """Invariant 7: every process fault done is a ``fault:`` line of the printed summary; every agent the
    server saw go without a fault is named (``died`` or ``away``, ``NOT scheduled``); a SIGKILL from
    outside fails the run (exit 1) with the robots and the tick on stderr; forged or attacking samples
    that reached a receiver show as ``samples rejected``; the summary says whether access control was on."""
    out_violations = []
    stdout, stderr = result["stdout"], result["stderr"]
    if "access control: " not in stdout:
        out_violations.append("named: the summary does not say whether access control was on")
    events = []
    with contextlib.suppress(OSError):
        events = [
            json.loads(line) for line in (out / "events.jsonl").read_text().splitlines() if line.strip()
        ]
    for event in events:
        if event["kind"] == "resume_agent":
            continue
        who = "" if event.get("robot") is None else f" robot {event['robot']}"
        if f"fault: {event['kind']}{who} at" not in stdout:
            out_violations.append(f"named: the summary does not name {event['kind']}{who}")
    touched = {e.get("robot") for e in events}
    for event in stats.get("agent_events", []):
        robot = event.get("robot")
        if event.get("event") != "gone" or robot in touched:
            continue
        if not any(
            f"{kind}: robot {robot}'s agent went at tick {event['tick']}" in stdout
            for kind in ("died", "away")
        ):
            out_violations.append(
                f"named: robot {robot}'s agent went at tick {event['tick']}, not in the summary"
            )
    killed = result.get("killed") or {}
    kill = plan.get("outside_kill")
    if killed.get("pid") is not None and kill is not None and not metrics.get("incomplete"):
        robots = (
            range(plan["scenario"]["robots"]["count"]) if kill["target"] == "launcher" else [kill["robot"]]
        )
        if result["status"] != 1 or "the run failed" not in stderr:
            out_violations.append(f"named: an outside SIGKILL of the {kill['target']} did not fail the run")
        # died; or froze, when a token outlives the process (the zombie attack holds one on its key)
        died = {
            i["robot"]: i
            for i in (metrics.get("health") or {}).get("incidents", [])
            if i["kind"] in ("died", "froze") and not i["scheduled"]
        }
        for robot in robots:
            incident = died.get(robot)
            if incident is None:
                out_violations.append(
                    f"named: robot {robot} killed from outside, not named as an unscheduled death"
                )
            elif (  # realtime: between two boundaries the server's tick is the last one on disk (-1)
                incident["tick"] < killed["after_tick"] - 1
                or f"robot {robot}'s agent {incident['kind']}" not in stderr
            ):
                out_violations.append(
                    f"named: robot {robot}'s death at tick {incident['tick']} misdated or not on stderr"
                )
    attacked = result.get("attacked") or {}
    forged = bool(result.get("sent")) or (attacked.get("sent", 0) > 0 and attacked.get("kind") != "zombie")
    rejected = (metrics.get("health") or {}).get("samples", {}).get("rejected", {})
    any_rejected = any(
        count for streams in rejected.values() if isinstance(streams, dict) for count in streams.values()
    )
    if forged and any_rejected and "samples rejected: " not in stdout:
        out_violations.append("named: samples were rejected but the summary does not say so")
    return out_violations


def _adjacent(scenario: dict, i: int, j: int) -> bool:
    kind, count = scenario["topology"]["kind"], scenario["robots"]["count"]
    return (min(i, j), max(i, j)) in set(_edges(kind, count))


def soak_one(plan: dict, work: Path) -> dict:
    out = work / f"run-{plan['seed']}"
    scenario_path = work / f"chaos-{plan['seed']}.yaml"
    scenario_path.write_text(yaml.safe_dump(plan["scenario"], sort_keys=False))
    robots = plan["scenario"]["robots"]["count"]
    result = _swarm_run(
        scenario_path, out, plan["forge"], plan.get("attack"), plan.get("outside_kill"), robots
    )
    violations = check_run(plan, out, result)
    faults = plan["scenario"].get("faults", [])
    replayed = None
    only_links = all(f["kind"] not in PROCESS_FAULTS for f in faults)
    unplanned = _unplanned_disconnects(out, faults)
    outsiders = plan.get("outside_kill") is not None or (plan.get("attack") or {}).get("kind") == "zombie"
    lockstep = plan["scenario"]["sim"]["mode"] == "lockstep"
    if lockstep and only_links and not outsiders and not violations and not unplanned:
        replay_out = work / f"replay-{plan['seed']}"
        replay = _swarm_run(scenario_path, replay_out, None)
        unplanned = _unplanned_disconnects(replay_out, faults)
        if not unplanned:  # a session the router dropped is a fault no schedule has: no comparison
            replayed = replay["status"] in (0, 1) and _trajectory(out) == _trajectory(replay_out)
            if not replayed:
                violations.append(
                    f"replay: the trajectory differs from its replay (status {replay['status']})"
                )
        shutil.rmtree(replay_out, ignore_errors=True)
    metrics = {}
    with contextlib.suppress(OSError, ValueError):
        metrics = json.loads((out / "metrics.json").read_text())
    entry = {
        "seed": plan["seed"],
        "robots": plan["scenario"]["robots"]["count"],
        "topology": plan["scenario"]["topology"]["kind"],
        "mode": plan["scenario"]["sim"]["mode"],
        "faults": faults,
        "forge": plan["forge"],
        "attack": plan.get("attack"),
        "attack_sent": (result.get("attacked") or {}).get("sent"),
        "outside_kill": plan.get("outside_kill"),
        "killed_after_tick": (result.get("killed") or {}).get("after_tick"),
        "forged_sent": sorted(result["sent"] or []),
        "forger_error": result["forger_error"],
        "restarted_not_back": result.get("not_back", []),
        "unplanned_disconnects": unplanned,
        "kinds": plan["kinds"],
        "status": result["status"],
        "converged": metrics.get("converged"),
        "incomplete": bool(metrics.get("incomplete")),
        "replay_identical": replayed,
        "wall_s": result["wall_s"],
        "violations": violations,
    }
    if not violations:
        shutil.rmtree(out, ignore_errors=True)
    return entry


# ----------------------------------------------------------------------------- report


def summary(entries: list[dict]) -> dict:
    kinds: dict[str, int] = {}
    for entry in entries:
        for kind in entry["kinds"]:
            kinds[kind] = kinds.get(kind, 0) + 1
    return {
        "runs": len(entries),
        "violations": sum(len(e["violations"]) for e in entries),
        "runs_with_violations": sum(bool(e["violations"]) for e in entries),
        "faults_by_kind": dict(sorted(kinds.items())),
        "runs_without_fault": sum(not e["kinds"] for e in entries),
        "forged_samples_sent": sum(len(e["forged_sent"]) for e in entries),
        "attack_samples_sent": sum(e.get("attack_sent") or 0 for e in entries),
        "outside_kills_done": sum(e.get("killed_after_tick") is not None for e in entries),
        "forger_failed": sum(bool(e.get("forger_error")) for e in entries),
        "restarted_not_back": sum(bool(e.get("restarted_not_back")) for e in entries),
        "unplanned_disconnects": sum(bool(e.get("unplanned_disconnects")) for e in entries),
        "replays_identical": sum(e["replay_identical"] is True for e in entries),
        "replays": sum(e["replay_identical"] is not None for e in entries),
        "exit_status": {
            str(s): sum(e["status"] == s for e in entries)
            for s in sorted({e["status"] for e in entries}, key=str)
        },
        "converged": sum(bool(e["converged"]) for e in entries),
        "modes": {m: sum(e["mode"] == m for e in entries) for m in ("lockstep", "realtime")},
        "wall_s_total": round(sum(e["wall_s"] for e in entries), 1),
    }


def write_report(entries: list[dict], args: argparse.Namespace, started: str) -> None:
    figures = summary(entries)
    document = {
        "command": f"python bench/chaos.py --runs {args.runs} --seed {args.seed} --workers {args.workers}",
        "started_utc": started,
        "machine": f"{platform.node()} ({os.cpu_count()} cores), load {os.getloadavg()[0]:.1f} at the end",
        "summary": figures,
        "runs": entries,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(document, indent=1) + "\n")
    lines = [
        "# Chaos soak",
        "",
        f"`{document['command']}` (started {started} UTC; {document['machine']}). "
        "What each run does and the invariants checked: the docstring of `bench/chaos.py`.",
        "",
        "| figure | value |",
        "|---|---|",
        f"| runs | {figures['runs']} ({figures['modes']['lockstep']} lockstep,"
        f" {figures['modes']['realtime']} realtime) |",
        f"| invariant violations | **{figures['violations']}** (in {figures['runs_with_violations']} runs) |",
        f"| runs without any fault | {figures['runs_without_fault']} |",
        *(f"| runs with `{kind}` | {count} |" for kind, count in figures["faults_by_kind"].items()),
        f"| forged samples sent (pose, message, command) | {figures['forged_samples_sent']} |",
        f"| attack samples sent (tests/outside.py attack) | {figures['attack_samples_sent']} |",
        f"| SIGKILLs from outside done (agent or launcher) | {figures['outside_kills_done']} |",
        f"| runs whose forger could not connect (its counts not checked) | {figures['forger_failed']} |",
        "| runs where the router dropped an agent's session that no fault touched (no replay compared) |"
        f" {figures['unplanned_disconnects']} |",
        "| runs whose restarted agent was not back before the end (convergence not judged) |"
        f" {figures['restarted_not_back']} |",
        "| lockstep link-fault runs identical to their replay |"
        f" {figures['replays_identical']} of {figures['replays']} |",
        f"| exit status | {', '.join(f'{s}: {n}' for s, n in figures['exit_status'].items())} |",
        f"| converged | {figures['converged']} |",
        f"| wall time of the runs | {figures['wall_s_total']:.0f} s |",
        "",
    ]
    bad = [e for e in entries if e["violations"]]
    if bad:
        lines += ["## Violations", ""]
        lines += [f"- seed {e['seed']}: {'; '.join(e['violations'])}" for e in bad]
        lines.append("")
    out.with_suffix(".md").write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200, help="how many runs (default 200)")
    parser.add_argument(
        "--seed", type=int, default=1, help="seed of the schedules (run i: seed * 100000 + i)"
    )
    parser.add_argument(
        "--out", default=str(RESULTS / "chaos"), help="results, without suffix (default bench/results/chaos)"
    )
    parser.add_argument("--keep", type=Path, help="keep the results directories of violating runs here")
    parser.add_argument("--workers", type=int, default=3, help="runs at a time (default 3)")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    started = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    entries: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="chaos-") as scratch:
        work = args.keep or Path(scratch)
        work.mkdir(parents=True, exist_ok=True)
        try:
            from tqdm import tqdm

            progress = tqdm(total=args.runs, desc="chaos", unit="run")
        except ImportError:
            progress = None
        plans = [draw_plan(args.seed * 100_000 + i) for i in range(args.runs)]
        pool = concurrent.futures.ThreadPoolExecutor(max(1, args.workers))
        for entry in pool.map(lambda plan: soak_one(plan, work), plans):  # in seed order
            entries.append(entry)
            write_report(entries, args, started)
            if progress is not None:
                progress.update(1)
                progress.set_postfix(violations=sum(len(e["violations"]) for e in entries))
            if entry["violations"]:
                print(f"seed {entry['seed']}: " + "; ".join(entry["violations"]), file=sys.stderr, flush=True)
        pool.shutdown()
        if progress is not None:
            progress.close()
    figures = summary(entries)
    print(f"{figures['runs']} runs, {figures['violations']} violations; {args.out}.md")
    return 0 if figures["violations"] == 0 else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
