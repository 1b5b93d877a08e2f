"""Mutation check of the suite: each mutation breaks the code on purpose, in a temporary copy of the
project, and the tests that guard that behaviour must then fail.

For every mutation below the script copies the working tree (without ``.git`` and run outputs) to a
temporary directory, replaces one piece of code (an exact string, or with ``regex=True`` a Python
regular expression whose replacement may use its groups, so that a mutation survives a renamed
variable or a reworded comment; the script stops if the piece is not found exactly once: the code moved
and the mutation must follow it), runs the named tests there with ``python -m pytest -x -q`` and
expects them to fail (pytest's exit 1; exit 2, an error while collecting, also counts). A named test
file that does not exist stops the script too: "no tests ran" is not a catch. ``--baseline`` also runs
the same tests on the unmutated copy first and expects them to pass (a test that fails anyway catches
nothing).

Run: ``python bench/mutations.py [--baseline] [--only NAME ...]`` (under ``nice``; tens of minutes);
``--list`` shows each mutation, its tests and whether its code is found, and runs nothing. A full run
writes ``bench/results/mutations.md`` and ``.json``; a run with ``--only`` writes
``runs/mutations-only.md`` and ``.json`` unless ``--out`` says otherwise (a partial run is no result to
commit). Exit status 0 when every mutation was caught, 1 otherwise, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent
RESULTS = PROJECT_ROOT / "bench" / "results"


@dataclass(frozen=True)
class Mutation:
    name: str
    what: str
    path: str
    before: str
    after: str
    tests: tuple[str, ...]
    regex: bool = False  # before: a regular expression (re.MULTILINE); after: its replacement template

    def found(self, text: str) -> int:
        """How many times the code to mutate occurs in ``text``."""
        return len(re.findall(self.before, text, re.MULTILINE)) if self.regex else text.count(self.before)

    def mutated(self, text: str) -> str:
        if self.regex:
            return re.sub(self.before, self.after, text, count=1, flags=re.MULTILINE)
        return text.replace(self.before, self.after)


MUTATIONS = [
    Mutation(
        "wire-checks-removed",
        "swarm/runtime/wire.py without its NaN, magnitude and message-length checks",
        "swarm/runtime/wire.py",
        """    value = float(value)
    if not math.isfinite(value) or abs(value) > bound:
        return None
    return value""",
        """    value = float(value)
    return value""",
        ("tests/test_wire.py",),
    ),
    Mutation(
        "message-length-check-removed",
        "a message of another length than the controller's is accepted",
        "swarm/runtime/wire.py",
        """    if dim is not None and size != dim:
        return None
""",
        "",
        ("tests/test_wire.py",),
    ),
    Mutation(
        "pose-tag-not-checked",
        "the agent takes a pose without checking its run-key tag",
        "robot_agent/agent.py",
        """                if run_key is not None and not run_key.check(pose_key, payload, tag):""",
        """                if False:""",
        ("tests/test_outside_attacks.py",),
    ),
    Mutation(
        "config-tag-not-checked",
        "the agent takes any config reply, the sim's or another answerer's",
        "robot_agent/agent.py",
        """        if key is None:
            return True
        if key.check(""",
        """        if True:
            return True
        if key.check(""",
        ("tests/test_outside_attacks.py",),
    ),
    Mutation(
        "server-never-finds-an-agent-hung",
        "the lockstep server waits for every live token's command, however long it stays silent",
        "sim_server/server.py",
        """                if self._missed_in_row[i] >= HUNG_AFTER_DEADLINES:""",
        """                if False:""",
        ("tests/test_outside_attacks.py",),
    ),
    Mutation(
        "agent-subscribes-to-every-message",
        "an agent also subscribes to every robot's messages (agent/*/msg) but records only its neighbours",
        "robot_agent/agent.py",
        """        for j in config.neighbours:
            self._alive_subs[j] = session.liveliness().declare_subscriber(""",
        """        spy = Inlet(session, f"{keys.prefix}/agent/*/msg", MESSAGE_RING)
        entities.append(spy)
        for j in config.neighbours:
            self._alive_subs[j] = session.liveliness().declare_subscriber(""",
        ("tests/test_declarations.py",),
    ),
    Mutation(
        "numpy-gain-1.5x",
        "the numpy policy's output 1.5x too large (the torch model unchanged)",
        "swarm/sim/policy.py",
        """        return self.output_scale_mps * self._network(features_local / self.feature_scale_m)""",
        "        return 1.5 * self.output_scale_mps * self._network(features_local / self.feature_scale_m)",
        ("tests/test_policy.py::test_numpy_forward_equals_torch",),
    ),
    Mutation(
        "numpy-gnn-gain-1.5x",
        "the numpy graph filter's gain 1.5x too large",
        "swarm/sim/policy.py",
        """        return gain[..., None] * (weights[..., None] * f).sum(-2)""",
        """        return 1.5 * gain[..., None] * (weights[..., None] * f).sum(-2)""",
        ("tests/test_policy.py::test_numpy_forward_equals_torch",),
    ),
    Mutation(
        "lower-bound-zero",
        "the lower bound is always zero",
        "swarm/core/metrics.py",
        """    return max(0.0, radius_m - threshold_m / math.sqrt(3.0)) / v_max_mps""",
        """    return 0.0 * max(0.0, radius_m - threshold_m / math.sqrt(3.0)) / v_max_mps""",
        ("tests/test_sweep.py::test_no_start_beats_the_lower_bound",),  # the sweep alone, not the unit test
    ),
    Mutation(
        "lower-bound-halved",
        "the lower bound is half what it should be",
        "swarm/core/metrics.py",
        """    return max(0.0, radius_m - threshold_m / math.sqrt(3.0)) / v_max_mps""",
        """    return 0.5 * max(0.0, radius_m - threshold_m / math.sqrt(3.0)) / v_max_mps""",
        ("tests/test_sweep.py::test_no_start_beats_the_lower_bound",),
    ),
    Mutation(
        "sweep-cache-ignored",
        "a sweep recomputes every cell instead of reading its cache",
        "swarm/scenarios/sweep.py",
        """    cell = find_cached_cell(out_dir, config, topology, count, controller, reuse)
    if cell is not None:
        return cell""",
        """    cell = None""",
        ("tests/test_sweep.py::test_sweep_command_writes_tables_and_plots",),
    ),
    Mutation(
        "no-tick-window",
        "agents believe any tick (the window of swarm/runtime/ticks.py removed)",
        "swarm/runtime/ticks.py",
        """        if self.tick < 0:
            return 0  # before the first pose: only tick 0 is believed without confirmation
        return tick_limit(self.tick, now_s - self.at_s, self.step_s)""",
        """        return 2**62""",
        ("tests/test_forged_ticks.py",),
    ),
    Mutation(
        "server-accepts-future-commands",
        "the server applies a command dated after its own tick",
        "sim_server/server.py",
        """            if cmd.tick > self._tick:
                self.stats["future_commands"] += 1
                return
""",
        "",
        ("tests/test_forged_ticks.py",),
    ),
    Mutation(
        "killed-server-is-bad-input",
        "a run whose server was killed from outside exits 2 (bad input)",
        "swarm/cli.py",
        r'(if _raised\(error, "swarm\.runtime\.distributed", "RunFailed"\):[^\n]*\n'
        r"[^\n]*run failed[^\n]*\n\s*return )EXIT_NOT_MET",
        r"\g<1>EXIT_BAD_INPUT",
        ("tests/test_exit_codes.py::test_a_sim_server_killed_from_outside_is_exit_1_not_bad_input",),
        regex=True,
    ),
    Mutation(
        "model-not-checked-before-start",
        "the pybullet engine starts its processes without reading the model file first",
        "swarm/runtime/distributed.py",
        r"(\n\s*)try:  # before any process starts: a bad file is bad input[^\n]*\n\s*load_policy\([^\n]*\)\n"
        r"\s*except PolicyFormatError as error:\n\s*raise ScenarioError\([^\n]*\) from None",
        r"\g<1>del load_policy, PolicyFormatError",
        ("tests/test_exit_codes.py::test_a_bad_model_file_is_one_line_exit_2_before_anything_starts",),
        regex=True,
    ),
    Mutation(
        "agent-message-ring-of-16",
        "an agent's message ring holds 16 samples, as it once did: a flood pushes genuine ones out",
        "robot_agent/agent.py",
        "MESSAGE_RING = 8192",
        "MESSAGE_RING = 16",
        ("tests/test_outside_attacks.py::test_a_flood_pushes_no_genuine_sample_out",),
    ),
    # ------------------------------------------------------------------------ issue 18's mutations
    Mutation(
        "pose-window-open-before-first-pose",
        "an agent believes any tick until its first genuine pose (PoseWindow.limit before the first pose)",
        "swarm/runtime/ticks.py",
        r"(if self\.tick < 0:[^\n]*\n\s*)return 0\b",
        r"\g<1>return 2**62",
        ("tests/test_ticks.py::test_before_its_first_pose_an_agent_believes_tick_zero_only",),
        regex=True,
    ),
    Mutation(
        "same-tick-message-replay-accepted",
        "a neighbour's message of a tick already received is taken again, overwriting the genuine payload",
        "robot_agent/agent.py",
        r"if tick <= newest\.get\(j, -1\):",
        "if tick < newest.get(j, -1):",
        (
            "tests/test_outside_attacks.py::test_a_same_tick_message_replay_does_not_overwrite_the_genuine_one",
        ),
        regex=True,
    ),
    Mutation(
        "incomplete-converged-run-exits-0",
        "swarm run exits 0 for an incomplete run whose swarm had already converged (README: 1)",
        "swarm/cli.py",
        r"(print\(f\"swarm run: run incomplete: [^\n]*\n\s*)return [^\n]+",
        r'\g<1>return 0 if outcome["converged"] else 1',
        ("tests/test_exit_codes.py::test_a_run_killed_after_it_converged_is_exit_1_incomplete",),
        regex=True,
    ),
    Mutation(
        "flood-skip-without-same-lists",
        "the flood kernel skips an unchanged neighbour's message without checking that the robot's "
        "neighbour lists are those of the last tick",
        "swarm/sim/flood_kernel.py",
        r"may_skip = own_valid and same_lists\[env, i\]",
        "may_skip = own_valid",
        ("tests/test_flood.py",),
        regex=True,
    ),
    Mutation(
        "batched-flood-merge-without-tie-break",
        "the batched mec_flood merge keeps the first of two support points with equal projections "
        "(no tie-break by x, then y; merge_support, the per-robot form, keeps it)",
        "swarm/core/mec.py",
        r"(pk = best\[m\]\n\s*)if pq > pk or \(pq == pk[^\n]*:",
        r"\g<1>if pq > pk:",
        ("tests/test_mec.py",),
        regex=True,
    ),
    Mutation(
        "welzl-circle-without-rounding-tolerance",
        "welzl_circle's inside test without the coordinate-rounding term (99bdc36's fix; a circle up to "
        "twice too big for tiny swarms far from the origin)",
        "swarm/core/mec.py",
        r"(\btol = [^\n]*?)\s*\+\s*1e-14 \* \w+",
        r"\g<1>",
        ("tests/test_circle.py",),
        regex=True,
    ),
    Mutation(
        "mec-flood-steers-its-controlled-point",
        "mec_flood drives the point 0.2 m ahead of the axle to the centre, not the axle that success "
        "judges (issue 18: axles left up to 2 l apart)",
        "swarm/core/mec.py",
        r"(if radius > 0\.0:\n\s*ux, uy = drive_toward\(\n\s*)poses\[env, i, 0\],\n(\s*)poses\[env, i, 1\],",
        r"\g<1>poses[env, i, 0] + 0.2 * math.cos(poses[env, i, 2]),\n\g<2>"
        r"poses[env, i, 1] + 0.2 * math.sin(poses[env, i, 2]),",
        ("tests/test_mec.py::test_the_baselines_gather_the_axles_whatever_the_offset",),
        regex=True,
    ),
    Mutation(
        "scaled-steering-ignores-the-run-period",
        "a flood GNN with scaled steering measures distances at its training period whatever the "
        "run's control period (issue 18: 0.05 m never met at T = 0.2 s)",
        "swarm/sim/policy.py",
        r"self\.control_period_s = float\(trained_period_s if control_period_s is None else "
        r"control_period_s\)",
        "self.control_period_s = float(trained_period_s)",
        ("tests/test_flood.py::test_the_shipped_gnn_meets_small_thresholds_and_fast_robots",),
        regex=True,
    ),
    Mutation(
        "agent-drives-the-unfiltered-command",
        "a robot agent with the safety filter on drives its controller's command, not the filtered one",
        "robot_agent/agent.py",
        "wheels = (0.0, 0.0) if brake else wheels_one(u_safe, pose.theta_rad, params)",
        "wheels = (0.0, 0.0) if brake else wheels_one(u_world, pose.theta_rad, params)",
        (
            "tests/test_safety_runtime.py::test_the_pybullet_runtime_filters_in_each_agent_and_counts_contacts",
        ),
    ),
    Mutation(
        "sense-key-not-in-the-acl",
        "the access-control rules leave out each robot's own sensor reading (robot/<i>/sense)",
        "swarm/runtime/acl.py",
        "heard = [keys.pose(robot), keys.sense(robot), *(keys.msg(j) for j in neighbours)",
        "heard = [keys.pose(robot), *(keys.msg(j) for j in neighbours)",
        ("tests/test_acl.py",),
    ),
    Mutation(
        "obstacles-not-built",
        "the PyBullet world leaves out the scenario's obstacles: robots drive through walls",
        "sim_server/physics.py",
        "            for index, capsule in enumerate(obstacles):",
        "            for index, capsule in enumerate(()):",
        ("tests/test_safety_runtime.py::test_pybullet_counts_the_contacts_of_a_scripted_head_on_collision",),
    ),
    Mutation(
        "pack-flood-restart-keeps-its-tick-count",
        "the batched pack_flood keeps a restarted robot's tick count (its per-robot form starts over)",
        "swarm/sim/pack_flood.py",
        "        self._ticks[fresh] = 0\n",
        "",
        ("tests/test_contract.py",),
    ),
    Mutation(
        "coverage-flood-ages-not-counted",
        "the batched lloyd_flood takes a heard position without aging it a hop (its per-robot form ages it)",
        "swarm/sim/coverage_controllers.py",
        "            age = np.where(theirs[..., 0] > 0.0, theirs[..., 0] + 1.0, 0.0)\n",
        "            age = theirs[..., 0]\n",
        ("tests/test_contract.py",),
    ),
    Mutation(
        "coverage-cell-ties-to-nobody",
        "a point as near another robot counts in no cell (the rule: in every cell it is nearest to)",
        "swarm/sim/coverage_controllers.py",
        "                    if ex * ex + ey * ey < mine:\n",
        "                    if ex * ex + ey * ey <= mine:\n",
        ("tests/test_coverage.py",),
    ),
    Mutation(
        "coverage-empty-cell-stays",
        "a batched robot with an empty cell gets no target (the rule: head for the density's centroid)",
        "swarm/sim/coverage_controllers.py",
        "    return np.where(mass > 0.0, sums[..., 1:] / np.where(mass > 0.0, mass, 1.0), fallback)\n",
        "    return np.where(mass > 0.0, sums[..., 1:] / np.where(mass > 0.0, mass, 1.0), np.nan)\n",
        ("tests/test_contract.py",),
    ),
]


def _commit() -> str:
    """The checkout's commit, with ``+changes`` when its tracked files differ from it."""

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=PROJECT_ROOT, capture_output=True, text=True).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+changes" if git("status", "--porcelain", "--untracked-files=no") else "")


def _copy(destination: Path) -> None:
    ignore = shutil.ignore_patterns(
        ".git", "runs", "__pycache__", ".pytest_cache", ".venv", "*.egg-info", "data"
    )
    shutil.copytree(PROJECT_ROOT, destination, ignore=ignore, symlinks=True)


def _pytest(root: Path, tests: tuple[str, ...]) -> tuple[int, str, float]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(root)
    started_s = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
    )
    lines = [line for line in (done.stdout + done.stderr).strip().splitlines() if line.strip()]
    failed = [line for line in lines if line.startswith(("FAILED", "ERROR"))]  # the test and why
    summary = [line for line in lines if " passed" in line or " failed" in line]
    last = failed[0] if failed else (summary[-1] if summary else (lines[-1] if lines else ""))
    return done.returncode, last[:300], round(time.perf_counter() - started_s, 1)


def apply(root: Path, mutation: Mutation) -> None:
    path = root / mutation.path
    text = path.read_text()
    found = mutation.found(text)
    if found != 1:
        raise SystemExit(f"{mutation.name}: the code to mutate was found {found} times in {mutation.path}")
    mutated = mutation.mutated(text)
    assert mutated != text, mutation.name
    path.write_text(mutated)


def missing_tests(root: Path, mutation: Mutation) -> list[str]:
    """The named tests whose file is not in ``root`` (pytest would exit 4: no tests ran)."""
    return [test for test in mutation.tests if not (root / test.split("::")[0]).exists()]


def is_caught(status: int) -> bool:
    """pytest's exit 1 (a test failed) or 2 (interrupted: a collection error); not 3-5 (internal
    error, usage error, no tests collected) nor 0."""
    return status in (1, 2)


def list_mutations() -> int:
    """Each mutation, where and how often its code is found now, and its tests (0 when every one is
    found exactly once and every test file exists)."""
    ready = True
    for mutation in MUTATIONS:
        path = PROJECT_ROOT / mutation.path
        found = mutation.found(path.read_text()) if path.exists() else 0
        missing = missing_tests(PROJECT_ROOT, mutation)
        ready = ready and found == 1 and not missing
        state = "ok" if found == 1 and not missing else f"code found {found} times"
        if missing:
            state += f", no such test file: {' '.join(missing)}"
        print(f"{mutation.name}: {mutation.what}\n  {mutation.path} [{state}]")
        print(f"  tests: {' '.join(mutation.tests)}")
    return 0 if ready else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--baseline", action="store_true", help="run each mutation's tests unmutated first")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="these mutations only (see --list)")
    parser.add_argument(
        "--out",
        help="results, without suffix (default: bench/results/mutations; with --only runs/mutations-only)",
    )
    parser.add_argument("--list", action="store_true", help="list them and whether their code is found")
    args = parser.parse_args(argv)
    if args.list:
        return list_mutations()
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    if args.only and len(chosen) != len(args.only):
        parser.error(f"unknown mutation; known: {', '.join(m.name for m in MUTATIONS)}")
    if args.out is None:
        args.out = str(PROJECT_ROOT / "runs" / "mutations-only" if args.only else RESULTS / "mutations")
    for mutation in chosen:  # before anything runs: a missing test file would read as caught
        if missing := missing_tests(PROJECT_ROOT, mutation):
            raise SystemExit(f"{mutation.name}: no such test file: {' '.join(missing)}")
    results = []
    for mutation in chosen:
        entry = {
            "name": mutation.name,
            "what": mutation.what,
            "file": mutation.path,
            "tests": list(mutation.tests),
        }
        if args.baseline:
            with tempfile.TemporaryDirectory(prefix="baseline-") as scratch:
                root = Path(scratch) / "project"
                _copy(root)
                status, last, wall_s = _pytest(root, mutation.tests)
                entry["baseline"] = {"status": status, "last_line": last, "wall_s": wall_s}
        with tempfile.TemporaryDirectory(prefix="mutant-") as scratch:
            root = Path(scratch) / "project"
            _copy(root)
            apply(root, mutation)
            status, last, wall_s = _pytest(root, mutation.tests)
        entry.update(status=status, last_line=last, wall_s=wall_s, caught=is_caught(status))
        if args.baseline:
            entry["caught"] = entry["caught"] and entry["baseline"]["status"] == 0
        results.append(entry)
        print(f"{mutation.name}: {'caught' if entry['caught'] else 'MISSED'} ({last})", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = "python bench/mutations.py" + (" --baseline" if args.baseline else "")
    command += f" --only {' '.join(args.only)}" if args.only else ""
    out.with_suffix(".json").write_text(
        json.dumps({"command": command, "commit": _commit(), "mutations": results}, indent=1) + "\n"
    )
    lines = [
        "# Mutation check",
        "",
        f"`{command}` ({time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC, on commit {_commit()}). Each"
        " mutation is applied to a"
        " temporary copy of the project; its tests must fail (`bench/mutations.py`).",
        "",
        "| mutation | what it breaks | tests | result | the failing test and why (pytest) |",
        "|---|---|---|---|---|",
    ]
    for entry in results:
        verdict = "caught" if entry["caught"] else "**missed**"
        if "baseline" in entry:
            verdict += f" (unmutated: exit {entry['baseline']['status']})"
        tests = "<br>".join(f"`{test}`" for test in entry["tests"])
        last = entry["last_line"].replace("|", "/")
        lines.append(f"| `{entry['name']}` | {entry['what']} | {tests} | {verdict} | {last} |")
    caught = sum(entry["caught"] for entry in results)
    lines += ["", f"{caught} of {len(results)} mutations caught.", ""]
    out.with_suffix(".md").write_text("\n".join(lines))
    return 0 if caught == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
