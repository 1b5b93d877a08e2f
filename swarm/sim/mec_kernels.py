"""Compiled (numba) kernels of the minimum-enclosing-circle controllers, for the batched engine.

``swarm.core.mec`` holds the per-robot arithmetic in plain floats (what the robot agents run) and the
loops over B environments x N robots; this module compiles those very functions with numba, in a
serial and a multi-threaded variant (``swarm.sim.kernels.PARALLEL_MIN_ROBOTS``). No ``fastmath``: the
agents' Python floats and these kernels then round alike, so the engines agree to the last bits
(``tests/test_mec.py``).
"""

from __future__ import annotations

import types

import numba

from swarm.core import mec
from swarm.sim import kernels

welzl_circle = numba.njit(cache=True)(mec.welzl_circle)
merge_support = numba.njit(cache=True)(mec.merge_support)
drive_toward = numba.njit(cache=True)(mec.drive_toward)

_GLOBALS = {
    **vars(mec),
    "prange": numba.prange,
    "welzl_circle": welzl_circle,
    "merge_support": merge_support,
    "drive_toward": drive_toward,
}


def _compiled_globals(function):
    """``function`` of ``swarm.core.mec`` with its calls bound to the compiled functions above (same code
    object, so numba caches it under ``swarm/core/mec.py`` and an edit there recompiles it)."""
    rebound = types.FunctionType(function.__code__, _GLOBALS, function.__name__, function.__defaults__)
    rebound.__doc__, rebound.__qualname__ = function.__doc__, function.__qualname__
    return rebound


def _serial_and_parallel(function):
    function = _compiled_globals(function)
    serial, parallel = kernels.jit_serial_and_parallel(function)

    def dispatch(*args):
        rows = args[0].shape[0] * args[0].shape[1]
        return (parallel if rows >= kernels.PARALLEL_MIN_ROBOTS else serial)(*args)

    dispatch.__doc__ = function.__doc__
    dispatch.__name__ = function.__name__.lstrip("_")
    return dispatch


mec_flood = _serial_and_parallel(mec.flood_step)
centralized_mec = _serial_and_parallel(mec.centralized_mec_step)
