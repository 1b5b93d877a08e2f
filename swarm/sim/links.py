"""Who heard whom in one tick, for B environments x N robots.

Stored as padded neighbour lists ``index (B, N, K)`` (-1 pads) with weights, which is
what sparse graphs need (a cycle of 1000 robots has 2 neighbours each, not 1000);
``dense`` gives the ``(B, N, N)`` matrix for controllers that aggregate with matmuls.
"""

from __future__ import annotations

import numpy as np

from swarm.sim import kernels


class Links:
    def __init__(self, index: np.ndarray, weight: np.ndarray, dense: np.ndarray | None = None):
        self.index = index
        self.weight = weight
        self._dense = dense

    @classmethod
    def from_dense(cls, adjacency: np.ndarray) -> Links:
        adjacency = np.asarray(adjacency, dtype=np.float64)
        slots = int((adjacency != 0).sum(axis=-1).max(initial=0))
        index = np.empty((*adjacency.shape[:2], slots), dtype=np.int32)
        weight = np.empty((*adjacency.shape[:2], slots))
        kernels.dense_to_lists(adjacency, index, weight)
        return cls(index, weight, adjacency)

    @classmethod
    def disk(cls, positions: np.ndarray, radius_m: float) -> Links:
        """Robots within ``radius_m`` of each other (axle positions ``(B, N, 2)``)."""
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        degrees = np.empty(positions.shape[:2], dtype=np.int64)
        kernels.disk_degrees(positions, float(radius_m), degrees)
        slots = int(degrees.max(initial=0))
        index = np.empty((*positions.shape[:2], slots), dtype=np.int32)
        weight = np.empty((*positions.shape[:2], slots))
        kernels.disk_lists(positions, float(radius_m), index, weight)
        return cls(index, weight)

    @classmethod
    def nobody(cls, batch: int, count: int) -> Links:
        return cls(np.full((batch, count, 0), -1, dtype=np.int32), np.zeros((batch, count, 0)))

    @property
    def shape(self) -> tuple[int, int]:
        return self.index.shape[:2]

    @property
    def dense(self) -> np.ndarray:
        """``(B, N, N)`` weights, built on first use."""
        if self._dense is None:
            batch, count = self.shape
            dense = np.zeros((batch, count, count + 1))  # the extra column swallows the -1 pads
            np.put_along_axis(dense, np.where(self.index < 0, count, self.index), self.weight, axis=-1)
            self._dense = dense[..., :count]
        return self._dense

    def heard_count(self) -> np.ndarray:
        """``(B, N)`` total weight each robot heard (its degree when all weights are 1)."""
        return self.weight.sum(axis=-1)

    def select(self, environments: np.ndarray) -> Links:
        dense = None if self._dense is None else self._dense[environments]
        return Links(self.index[environments], self.weight[environments], dense)


def heard_slots(inbox: np.ndarray, heard: Links, only: tuple[np.ndarray, np.ndarray] | None = None):
    """Per neighbour slot, in slot order: ``(valid (B, N), messages (B, N, D))``, the message each robot
    heard in that slot (``inbox[b, heard.index[b, i, slot]]``; rows without a sender hold the message of
    column 0 and are not ``valid``). Slots nobody heard in are skipped. ``only``: ``(envs, robots)``
    index arrays of R receivers; then ``valid (R,)`` and ``messages (R, D)`` for those alone."""
    batch, count = heard.index.shape[:2]
    envs, robots = (np.arange(batch)[:, None], np.arange(count)[None, :]) if only is None else only
    for slot in range(heard.index.shape[2]):
        sender = heard.index[envs, robots, slot]
        valid = sender >= 0  # -1: none
        if valid.any():
            yield valid, inbox[envs, np.where(valid, sender, 0)]
