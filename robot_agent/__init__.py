"""robot_agent: the per-robot process of the distributed runtime (one OS process per robot).

An agent does tiny numpy work per tick: one BLAS thread (set here, before numpy is first imported,
so that an agent started by hand on another host gets it too; the runner also sets it).
"""

import os as _os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")
