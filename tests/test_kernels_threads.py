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
