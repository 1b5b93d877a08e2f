"""Every numba kernel of the kinematic engine, run once with numba's bounds checks on.

Compiled without them (the default), an index past an array reads whatever lies there: the flood
kernel once read a skip flag past its ``(B, N)`` array under a delay fault, and the last environments
of each batch skipped messages on garbage (issue 18). In a fresh process with ``NUMBA_BOUNDSCHECK=1``
and a fresh ``NUMBA_CACHE_DIR`` (cached code compiled without the checks must not be reused), the
script below runs the engine for every controller kind (``gnn`` once per shipped model kind) on a
fixed and on a disk graph, without faults and under every link fault kind (a delay long enough for
an inbox of several ticks), with a mid-run restart of one environment and a ``keep`` of some, the
sweep's convergence loop, serial and then with every kernel threaded. An index out of bounds raises
IndexError and the script fails. It then requires that every compiled kernel of ``swarm.sim.kernels``,
``swarm.sim.mec_kernels``, ``swarm.sim.flood_kernel``, ``swarm.sim.coverage_controllers`` (the coverage
kinds, on a coverage section) and ``swarm.sim.safety_kernel`` (the safety filter, run
with one, two and five robots and an obstacle) has run (a new kernel is checked for free,
or this test names it). Process faults need the pybullet engine (``tests/test_contract.py`` checks
that the kinematic engine refuses them).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import json, sys, types
import numba
import numpy as np
from numba.core.dispatcher import Dispatcher


@numba.njit
def past(values, index):
    return values[index]


try:  # the checks are on, or this run proves nothing
    past(np.zeros(2), 5)
    sys.exit("NUMBA_BOUNDSCHECK is not in effect")
except IndexError:
    pass

from pathlib import Path
from swarm.core.faults import LINK_FAULTS, LinkFaults
from swarm.core.robot import RobotParams
from swarm.scenarios.sweep import converge_batch
from swarm.sim import coverage_controllers, flood_kernel, kernels, mec_kernels, safety_kernel
from swarm.core import tasks
from swarm.core.obstacles import Capsules, ObstacleSpec
from swarm.core.safety import SafetyParams
from swarm.sim.safety_filter import SafetyFilter
from swarm.sim.controller_kinds import CONTROLLER_KINDS, ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim
from swarm.sim.policy import load_policy
from swarm.core import graphs

robot = RobotParams()
models = {}
for path in sorted(Path(sys.argv[1]).glob("*.npz")):
    models.setdefault(load_policy(path).kind, str(path))
variants = []
SECTIONS = {"rendezvous": None, "coverage": tasks.parse_section({"kind": "coverage", "grid_per_axis": 12})}
for name, kind in CONTROLLER_KINDS.items():
    if kind.task == "formation":  # numpy (no kernel)
        continue
    rendezvous_model = "model" in kind.options and kind.task == "rendezvous"  # others: their shipped one
    variants += [(name, model) for model in models.values()] if rendezvous_model else [(name, None)]


def link_faults(kind):
    fault = {"kind": kind, "at_s": 0.1, "until_s": 0.6, "link": (0, 1), "p": 0.4, "ticks": 3}
    if kind == "restore_link":
        return [{"kind": "drop_link", "at_s": 0.05, "link": (0, 1)}, {**fault, "at_s": 0.3}]
    return [fault]


batch, count = 3, 5
rng = np.random.default_rng(0)


def start():
    xy = rng.uniform(-1.5, 1.5, (batch, count, 2))
    return np.concatenate([xy, rng.uniform(-3, 3, (batch, count, 1))], -1)


runs = 0
obstacles = Capsules([ObstacleSpec(kind="disc", centre=(0.0, 0.0), radius_m=0.2)])
for threshold in (1 << 62, 0):  # serial, then every kernel threaded
    kernels.PARALLEL_MIN_ROBOTS = threshold
    coverage_controllers.PARALLEL_MIN_CELL_POINTS = threshold
    for safety_count in (1, 2, count):  # the safety filter: alone, a pair, a crowd, with an obstacle
        safe = SafetyFilter(robot, SafetyParams(noise_m=0.01, dropout=0.2), obstacles)
        args = ControllerArgs(robot=robot, robot_count=safety_count)
        sim = KinematicSim(
            robot, batched_controller("local_consensus", args), 0.05, start()[:, :safety_count],
            adjacency=graphs.complete(safety_count), safety=safe,
        )
        for _ in range(6):
            sim.step()
    for name, model in variants:
        task = SECTIONS[CONTROLLER_KINDS[name].task]
        args = ControllerArgs(robot=robot, robot_count=count, policy=model, task=task)
        for graph in ({"adjacency": graphs.line(count)}, {"disk_radius_m": 1.2}):
            for kind in (None, *LINK_FAULTS):
                faults = None if kind is None else LinkFaults(link_faults(kind), 0.05, 1)
                sim = KinematicSim(
                    robot, batched_controller(name, args), 0.05, start(), link_faults=faults,
                    message_max_age_ticks=2, **graph,
                )
                for tick in range(16):
                    if tick == 8:
                        sim.restart(np.array([2]), start()[:1])
                    sim.step()
                sim.keep(np.array([0, 2]))
                for _ in range(3):
                    sim.step()
                runs += 1
        if task is not None:  # the sweep's convergence loop is rendezvous's
            continue
        sim = KinematicSim(robot, batched_controller(name, args), 0.05, start(), disk_radius_m=1.2)
        converge_batch(sim, 0.5, 1.0, 0.2, disconnected=np.zeros(batch, dtype=bool))
known = np.zeros(2 * 4 + 1)
mec_kernels.merge_support(known, np.ones(2 * 4 + 1), np.ones(4), np.zeros(4), 4)  # not on the engine's path


def dispatchers(module):
    for value in vars(module).values():
        if isinstance(value, Dispatcher):
            yield value
        elif isinstance(value, types.FunctionType) and value.__closure__:
            cells = [cell.cell_contents for cell in value.__closure__]
            yield from (cell for cell in cells if isinstance(cell, Dispatcher))


found = {id(d): d for module in (kernels, mec_kernels, flood_kernel, safety_kernel, coverage_controllers)
         for d in dispatchers(module)}
never = sorted(
    d.py_func.__qualname__
    for d in found.values()
    if not d.signatures and d.targetoptions.get("inline") != "always"
)
print(json.dumps({"runs": runs, "kernels": len(found), "never_run": never}))
"""


@pytest.mark.slow
def test_every_engine_kernel_runs_within_bounds(tmp_path):
    script = tmp_path / "bounds.py"
    script.write_text(SCRIPT)
    environment = {
        **os.environ,
        "NUMBA_BOUNDSCHECK": "1",
        "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
        "NUMBA_NUM_THREADS": "2",
        "PYTHONPATH": str(ROOT),
    }
    done = subprocess.run(
        [sys.executable, str(script), str(ROOT / "models")],
        env=environment,
        capture_output=True,
        text=True,
        timeout=3000,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["never_run"] == [], report
    assert report["kernels"] >= 20 and report["runs"] > 100, report
