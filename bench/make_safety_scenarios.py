"""Writes ``scenarios/safety/``: 6, 20 and 50 robots from uniform, two-cluster, strip and ring starts,
mec_flood with the barrier filter (docs/safety.md), on the kinematic engine.

    .venv/bin/python bench/make_safety_scenarios.py

Starts (seeded, explicit poses in the files): uniform in a square growing with N; two clusters 8 m apart;
a strip 0.8 N m long and 1 m wide; a ring of radius 0.25 N m. Every start keeps axle centres 0.5 m
apart (controlled points at least 0.4 m apart, over the barrier's 0.37 m). Graphs: uniform on the
complete graph, two-cluster on the cycle, strip on the line, ring on a disk graph. The success threshold
is 1.5x an estimate of the packing limit of N discs of the barrier's radius (module `packing_estimate_m`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from swarm.core.robot import RobotParams
from swarm.core.safety import SafetyParams, body_distance_m

OUT = Path(__file__).resolve().parents[1] / "scenarios" / "safety"
SIZES = (6, 20, 50)
GRAPHS = {"uniform": {"kind": "complete"}, "two-cluster": {"kind": "cycle"}, "strip": {"kind": "line"}}


def packing_estimate_m(count: int, diameter_m: float) -> float:
    """Max pairwise distance of ``count`` discs of ``diameter_m`` packed hexagonally in a circle: the
    circle's diameter, from the packing density pi / (2 sqrt 3) (an estimate, not the tabulated optimum)."""
    if count == 1:
        return 0.0
    density = math.pi / (2.0 * math.sqrt(3.0))
    return max(diameter_m, diameter_m * math.sqrt(count / density) - diameter_m)


def _separated(rng, count, sample, separation=0.5):
    points: list[np.ndarray] = []
    for _ in range(200_000):
        p = sample(rng)
        if all(np.hypot(*(p - q)) >= separation for q in points):
            points.append(p)
            if len(points) == count:
                return np.array(points)
    raise RuntimeError("cannot place the robots")


def starts(kind: str, count: int, rng: np.random.Generator) -> np.ndarray:
    if kind == "uniform":
        half = 0.5 * math.sqrt(2.0 * count)
        xy = _separated(rng, count, lambda r: r.uniform(-half, half, 2))
    elif kind == "two-cluster":
        half = 0.5 * math.sqrt(count)
        first = _separated(rng, count // 2, lambda r: r.uniform(-half, half, 2))
        second = _separated(rng, count - count // 2, lambda r: r.uniform(-half, half, 2))
        shift = np.array([4.0 + half, 0.0])
        xy = np.concatenate([first - shift, second + shift])
    elif kind == "strip":
        length = 0.8 * count
        xy = _separated(rng, count, lambda r: r.uniform([-length / 2, -0.5], [length / 2, 0.5]))
    else:  # ring
        angles = np.linspace(0.0, 2.0 * math.pi, count, endpoint=False)
        xy = 0.25 * count * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    theta = rng.uniform(-math.pi, math.pi, (count, 1))
    return np.round(np.concatenate([xy, theta], axis=1), 4)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    diameter = body_distance_m(RobotParams(), SafetyParams())
    for count in SIZES:
        for index, kind in enumerate(("uniform", "two-cluster", "strip", "ring")):
            rng = np.random.default_rng(1000 * count + index)
            poses = starts(kind, count, rng)
            ring_radius = 0.5 * count * math.sin(math.pi / count) + 1.0  # half a ring edge, plus 1 m
            topology = GRAPHS.get(kind, {"kind": "disk", "radius": ring_radius})
            threshold = round(1.5 * packing_estimate_m(count, diameter), 2)
            scenario = {
                "name": f"safety-{kind}-{count}",
                "description": (
                    f"{count} robots from a {kind} start, mec_flood with the barrier filter; success at 1.5x"
                    f" an estimate of the packing limit of {count} discs {diameter:.2f} m across"
                    " (bench/make_safety_scenarios.py wrote this file)"
                ),
                "robots": {"count": count, "init": {"poses": poses.tolist()}},
                "topology": topology,
                "controller": {"kind": "mec_flood"},
                "sim": {"engine": "kinematic", "control_period_s": 0.05, "duration_s": 20 + 1.2 * count},
                "safety": {"kind": "barrier"},
                "success": {"metric": "max_pairwise", "threshold": threshold},
            }
            path = OUT / f"{kind}-{count}.yaml"
            path.write_text(yaml.safe_dump(scenario, sort_keys=False, default_flow_style=None, width=110))
            print(path)


if __name__ == "__main__":
    main()
