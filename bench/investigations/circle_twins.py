"""How often the enclosing circle of the MEC controllers (``swarm.core.mec.welzl_circle``) is too big, against
the exact oracle of ``tests/circle_oracle.py``, on random 10 um swarms (2..16 points in a 10 um square
within 10 m of the origin); ``--base REV`` measures that commit's ``swarm/core/mec.py`` instead.

    python bench/investigations/circle_twins.py --swarms 3000             # this tree
    python bench/investigations/circle_twins.py --swarms 3000 --base b22e47c   # before the shared tolerance

Prints the count of circles more than 1.1x the exact radius, and the worst ratio.
"""

from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parent.parent))  # bench/: its helpers and benchmarks

import argparse
import math
import subprocess
import sys
import types
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from circle_oracle import exact_min_radius_squared, random_tiny_swarm  # noqa: E402


def mec_module(base: str | None) -> types.ModuleType:
    if base is None:
        from swarm.core import mec

        return mec
    source = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{base}:swarm/core/mec.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    module = types.ModuleType("mec_at_base")
    exec(compile(source, f"{base}:swarm/core/mec.py", "exec"), module.__dict__)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--swarms", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--base", help="a commit whose swarm/core/mec.py to measure instead")
    args = parser.parse_args()
    mec = mec_module(args.base)
    rng = np.random.default_rng(args.seed)
    ratios = []
    for _ in range(args.swarms):
        points = random_tiny_swarm(rng)
        _, _, radius = mec.welzl_circle(points[:, 0].tolist(), points[:, 1].tolist(), len(points))
        ratios.append(radius / math.sqrt(exact_min_radius_squared(points)))
    ratios_array = np.array(ratios)
    print(
        f"{args.base or 'working tree'}: {int(np.sum(ratios_array > 1.1))} of {args.swarms} circles more than"
        f" 1.1x the exact radius, worst {ratios_array.max():.3g}x, smallest {ratios_array.min():.12g}x"
    )


if __name__ == "__main__":
    main()
