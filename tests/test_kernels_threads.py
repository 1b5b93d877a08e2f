"""The multi-threaded variant of a compiled kernel runs on several threads, also when loaded from numba's
disk cache after the serial variant of the same function was compiled and cached
(``swarm.sim.kernels.jit_serial_and_parallel``: every serial/parallel kernel pair of ``swarm.sim`` is
made by it).

The oracle is outside the code under test: a prange loop writes the id of the thread that ran each
iteration, in fresh processes sharing one fresh cache directory. Before the fix, both variants of a
function shared one cache entry and the parallel variant loaded the serial code: every id 0.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from swarm.core import graphs, tasks
from swarm.core.robot import RobotParams
from swarm.sim import coverage_controllers, kernels
from swarm.sim.controller_kinds import CONTROLLER_KINDS, ControllerArgs, batched_controller
from swarm.sim.kinematic import KinematicSim

pytestmark = pytest.mark.slow  # compiles every kernel's serial and parallel variants

SCRIPT = """
import json, numba, numpy as np
from swarm.sim.kernels import jit_serial_and_parallel

def who(out):
    for i in numba.prange(out.shape[0]):
        out[i] = numba.get_thread_id()

serial, parallel = jit_serial_and_parallel(who)
numba.set_num_threads(2)
ids = {}
for name, kernel in (("serial", serial), ("parallel", parallel)):
    out = np.full(1000, -1)
    kernel(out)
    ids[name] = sorted(set(out.tolist()))
print(json.dumps(ids))
"""


def test_parallel_variant_uses_threads_after_serial_was_cached(tmp_path: Path) -> None:
    (tmp_path / "who.py").write_text(SCRIPT)  # a file: numba caches only functions defined in one
    environment = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
        "NUMBA_NUM_THREADS": "2",
        "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
    }
    runs = []
    for _ in range(2):  # the first compiles and caches both variants, the second loads both
        done = subprocess.run(
            [sys.executable, str(tmp_path / "who.py")],
            env=environment,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    for ids in runs:
        assert ids["serial"] == [0]
        assert ids["parallel"] == [0, 1]  # each of the two threads ran its share of the iterations
    assert len(list((tmp_path / "cache").rglob("*.nbi"))) == 2  # one cache entry per variant


@pytest.mark.parametrize("kind", ["local_consensus", "mec_flood", "centralized_mec", "gnn"])
@pytest.mark.parametrize("graph", ["fixed", "disk"])
def test_threaded_engine_is_bit_for_bit_the_serial_one(kind: str, graph: str, monkeypatch) -> None:
    """Whether an evaluation runs on threads (``PARALLEL_MIN_ROBOTS``: batches of 50 000 robots and more)
    must not change a bit of any start's result: every controller kind's trajectory on a fixed and on a
    disk graph, threaded against serial, in one process (numba compiles or loads each variant)."""
    robot = RobotParams()
    model = Path(__file__).resolve().parents[1] / "models" / "gnn_flood.npz"
    args = ControllerArgs(robot=robot, robot_count=12, policy=str(model))
    rng = np.random.default_rng(3)
    poses = np.concatenate([rng.uniform(-2, 2, (9, 12, 2)), rng.uniform(-np.pi, np.pi, (9, 12, 1))], axis=-1)
    links = {"adjacency": graphs.cycle(12)} if graph == "fixed" else {"disk_radius_m": 1.5}
    numba.set_num_threads(2)
    runs = []
    for threshold in (1 << 62, 0):  # serial, then every kernel threaded
        monkeypatch.setattr(kernels, "PARALLEL_MIN_ROBOTS", threshold)
        sim = KinematicSim(robot, batched_controller(kind, args), 0.05, poses, **links)
        runs.append(sim.rollout(40))
    assert np.abs(runs[0][-1] - runs[0][0]).max() > 0.05  # the robots moved
    np.testing.assert_array_equal(runs[1], runs[0])


COVERAGE_KINDS = [name for name, kind in CONTROLLER_KINDS.items() if kind.task == "coverage"]


@pytest.mark.parametrize("kind", COVERAGE_KINDS)
def test_threaded_coverage_cells_are_bit_for_bit_the_serial_ones(kind: str, monkeypatch) -> None:
    """The coverage kinds' cells (``swarm.sim.coverage_controllers.cell_sums``) threaded from
    ``PARALLEL_MIN_CELL_POINTS``: a swarm's whole trajectory on a line graph, threaded against serial."""
    robot = RobotParams()
    section = tasks.parse_section({"kind": "coverage", "region": [[-1, -1], [1, -1], [1, 1], [-1, 1]]})
    args = ControllerArgs(robot=robot, control_period_s=0.05, robot_count=10, task=section)
    rng = np.random.default_rng(4)
    poses = np.concatenate([rng.uniform(-1, 1, (5, 10, 2)), rng.uniform(-np.pi, np.pi, (5, 10, 1))], axis=-1)
    numba.set_num_threads(2)
    runs = []
    for threshold in (1 << 62, 0):  # serial, then threaded
        monkeypatch.setattr(coverage_controllers, "PARALLEL_MIN_CELL_POINTS", threshold)
        line = graphs.line(10)[None]
        sim = KinematicSim(robot, batched_controller(kind, args), 0.05, poses, adjacency=line)
        runs.append(sim.rollout(30))
    assert np.abs(runs[0][-1] - runs[0][0]).max() > 0.05  # the robots moved
    np.testing.assert_array_equal(runs[1], runs[0])
