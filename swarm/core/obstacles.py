"""Static obstacles: discs and walls (scenario key ``obstacles``), as capsules.

Every obstacle is the set of points within ``radius`` of a segment ``[start, end]``: a disc is a
segment of length zero (``radius = radius_m``), a wall a segment with half its thickness as radius.
Capsules are convex, so the distance from a point to one is a convex function of the point, which the
barrier of ``swarm.core.safety`` (O) relies on.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class ObstacleSpec(BaseModel):
    """``{kind: disc, centre: [x, y], radius_m: R}`` or ``{kind: wall, start: [x, y], end: [x, y],
    thickness_m: T}`` (metres)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["disc", "wall"]
    centre: tuple[float, float] | None = None
    radius_m: float | None = Field(None, gt=0)
    start: tuple[float, float] | None = None
    end: tuple[float, float] | None = None
    thickness_m: float = Field(0.1, gt=0)

    @model_validator(mode="after")
    def _keys_of_kind(self) -> ObstacleSpec:
        if self.kind == "disc":
            if self.centre is None or self.radius_m is None:
                raise ValueError("a disc needs centre and radius_m")
            if self.start is not None or self.end is not None:
                raise ValueError("a disc takes centre and radius_m, not start and end")
        else:
            if self.start is None or self.end is None:
                raise ValueError("a wall needs start and end")
            if self.centre is not None or self.radius_m is not None:
                raise ValueError("a wall takes start, end and thickness_m, not centre and radius_m")
        return self

    def capsule(self) -> tuple[tuple[float, float], tuple[float, float], float]:
        """``(start, end, radius)`` of the capsule this obstacle is."""
        if self.kind == "disc":
            assert self.centre is not None and self.radius_m is not None  # _keys_of_kind
            return self.centre, self.centre, self.radius_m
        assert self.start is not None and self.end is not None  # _keys_of_kind
        return self.start, self.end, 0.5 * self.thickness_m


class Capsules:
    """K obstacles as arrays: ``start (K, 2)``, ``end (K, 2)``, ``radius (K,)``."""

    def __init__(self, specs: list[ObstacleSpec] | tuple[ObstacleSpec, ...] = ()):
        parts = [spec.capsule() for spec in specs]
        self.start = np.array([p[0] for p in parts], dtype=np.float64).reshape(-1, 2)
        self.end = np.array([p[1] for p in parts], dtype=np.float64).reshape(-1, 2)
        self.radius = np.array([p[2] for p in parts], dtype=np.float64).reshape(-1)

    def __len__(self) -> int:
        return len(self.radius)

    def nearest_on_axis(self, points: np.ndarray) -> np.ndarray:
        """``(..., K, 2)``: the point of each obstacle's segment nearest each of ``points (..., 2)``
        (``a + clip(t, 0, 1) (b - a)``, ``t = (p - a).(b - a) / |b - a|^2``)."""
        p = np.asarray(points, dtype=np.float64)[..., None, :]
        a, ab = self.start, self.end - self.start
        length_sq = np.sum(ab * ab, axis=-1)
        t = np.sum((p - a) * ab, axis=-1) / np.where(length_sq > 0, length_sq, 1.0)
        t = np.clip(np.where(length_sq > 0, t, 0.0), 0.0, 1.0)
        return a + t[..., None] * ab

    def surface_distance(self, points: np.ndarray) -> np.ndarray:
        """``(..., K)``: signed distance from each point to each obstacle's surface (negative inside)."""
        p = np.asarray(points, dtype=np.float64)[..., None, :]
        return np.linalg.norm(p - self.nearest_on_axis(points), axis=-1) - self.radius

    def nearest_surface(self, points: np.ndarray) -> np.ndarray:
        """``(..., K, 2)``: the point of each obstacle's surface nearest each point outside it (a point
        on the axis itself gets the axis point: no direction to go)."""
        p = np.asarray(points, dtype=np.float64)[..., None, :]
        axis = self.nearest_on_axis(points)
        away = p - axis
        gap = np.linalg.norm(away, axis=-1, keepdims=True)
        return axis + away * (self.radius[..., None] / np.where(gap > 0, gap, np.inf))
