"""``swarm.scenarios.blas``: the kernel numpy's matrix products run on, read from the process itself.

The oracle is OpenBLAS's own switch: a child process started with ``OPENBLAS_CORETYPE`` set runs on
that kernel, and the name must say so."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swarm.scenarios.blas import blas_kernel

ROOT = Path(__file__).resolve().parent.parent


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((line for line in text.splitlines() if line.startswith("flags")), "")
    return set(line.split(":", 1)[-1].split())


def _kernel_in_child(coretype: str) -> str:
    code = "from swarm.scenarios.blas import blas_kernel; print(blas_kernel())"
    environment = os.environ | {"OPENBLAS_CORETYPE": coretype}
    done = subprocess.run(
        [sys.executable, "-c", code], env=environment, cwd=ROOT, capture_output=True, text=True, check=True
    )
    return done.stdout.strip()


def test_the_kernel_is_numpys_blas_and_the_one_openblas_was_told_to_use():
    name = blas_kernel()
    if not name.startswith("openblas"):
        pytest.skip(f"numpy's BLAS here is {name!r}, not OpenBLAS")
    assert len(name.split()) == 2  # "openblas <kernel>"
    if not {"avx2", "fma"} <= _cpu_flags():
        pytest.skip("the CPU lacks AVX2 and FMA: OpenBLAS's Haswell kernel cannot run here")
    assert _kernel_in_child("Haswell") == "openblas Haswell"
    if "avx512f" in _cpu_flags():
        assert _kernel_in_child("SkylakeX") == "openblas SkylakeX"
