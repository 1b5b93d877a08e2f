"""Which BLAS kernel numpy's matrix products run on: a learned kind's numbers depend on it.

OpenBLAS (numpy's BLAS in its wheels) picks its kernels by CPU when numpy loads it: the AVX2 ones
(``Haswell``; AMD's ``Zen`` run the same code) on most x86-64 machines, the AVX-512 ones (``SkylakeX``,
``Cooperlake``, ``SapphireRapids``) on newer Xeons. They round some small products differently (a
``(B N, 32) x (32, 3)`` layer of a learned readout, for one), so a learned kind's run on one kernel
leaves the other's by rounding, which a closed loop then carries (``docs/design.md``, "Determinism";
``bench/investigations/blas_kernels.py``). A sweep records the kernel in each cell file
(``swarm.scenarios.task_sweep``), and ``OPENBLAS_CORETYPE=<kernel>``, set before numpy is imported,
runs on a kernel the CPU has.
"""

from __future__ import annotations

import functools


@functools.cache
def blas_kernel() -> str:
    """``"openblas SkylakeX"``: numpy's BLAS and the kernel it runs on; ``"unknown"`` where
    threadpoolctl (the ``sim`` extra) is missing or finds no BLAS."""
    import numpy  # noqa: F401  (loads numpy's BLAS, which threadpoolctl then finds)

    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return "unknown"
    found = [info for info in threadpool_info() if info.get("user_api") == "blas"]
    numpy_own = [info for info in found if "numpy" in str(info.get("filepath", ""))] or found
    if not numpy_own:
        return "unknown"
    parts = (numpy_own[0].get("internal_api"), numpy_own[0].get("architecture"))
    return " ".join(str(part) for part in parts if part)


def coretype_setting(kernel: str) -> str:
    """``"OPENBLAS_CORETYPE=SkylakeX"`` for the kernel ``"openblas SkylakeX"`` (:func:`blas_kernel`'s form):
    what makes OpenBLAS run on that kernel, set before numpy loads it, where the CPU has it."""
    return f"OPENBLAS_CORETYPE={kernel.split(' ')[-1]}"
