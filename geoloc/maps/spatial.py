"""A cell index of wall segments (facades) for range queries whose cost does not grow with the map.

Every segment is entered in each square cell its bounding box touches. Only occupied cells are
stored (sorted cell keys with the start of each cell's run of segment ids), so memory grows with
the number of segments, not with the map's extent, and a query looks up only the cells it covers.
The index is built once, when the map's binary copy is written (:mod:`geoloc.maps.store` keeps its arrays,
:meth:`FacadeIndex.arrays` and :meth:`FacadeIndex.from_arrays`), not by every process that reads the map.
"""

from __future__ import annotations

from typing import Any

import numpy as np


class FacadeIndex:
    """Facades (anything with ``start`` and ``end`` (F, 2) arrays, local metres) binned into square cells.

    cell_m: cell side (metres).
    """

    def __init__(self, facades: Any, cell_m: float = 25.0) -> None:
        self.facades = facades
        self.cell_m = float(cell_m)
        start, end = np.asarray(facades.start, dtype=float), np.asarray(facades.end, dtype=float)
        lo, hi = np.minimum(start, end), np.maximum(start, end)
        self.origin = (lo.min(axis=0) if len(lo) else np.zeros(2)) - self.cell_m
        c0 = np.floor((lo - self.origin) / self.cell_m).astype(np.int64)
        c1 = np.floor((hi - self.origin) / self.cell_m).astype(np.int64)
        self.rows = int(c1[:, 1].max()) + 2 if len(c1) else 1  # key = cx * rows + cy
        span = c1 - c0 + 1
        counts = span[:, 0] * span[:, 1]
        owner = np.repeat(np.arange(len(lo)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        cx = c0[owner, 0] + local % span[owner, 0]
        cy = c0[owner, 1] + local // span[owner, 0]
        key = cx * self.rows + cy
        order = np.argsort(key, kind="stable")
        key, self.cell_facades = key[order], owner[order]
        first = np.flatnonzero(np.r_[True, np.diff(key) != 0]) if len(key) else np.zeros(0, dtype=np.int64)
        self.cell_keys = key[first]
        self.cell_start = np.r_[first, len(key)].astype(np.int64)

    ARRAY_NAMES = ("origin", "cell_keys", "cell_start", "cell_facades")
    """The arrays of :meth:`arrays` (with ``cell_m`` and ``rows`` as a (2,) float64 ``shape``)."""

    def arrays(self) -> dict[str, np.ndarray]:
        """The index as named arrays, for :meth:`from_arrays` (what :mod:`geoloc.maps.store` writes)."""
        return {
            **{name: getattr(self, name) for name in self.ARRAY_NAMES},
            "shape": np.array([self.cell_m, self.rows], dtype=np.float64),
        }

    @classmethod
    def from_arrays(cls, facades: Any, arrays: dict[str, np.ndarray]) -> FacadeIndex:
        """The index of ``facades`` from :meth:`arrays` output (no work: the arrays are used as they are)."""
        index = cls.__new__(cls)
        index.facades = facades
        index.cell_m, rows = (float(v) for v in arrays["shape"])
        index.rows = int(rows)
        for name in cls.ARRAY_NAMES:
            setattr(index, name, arrays[name])
        return index

    def facades_near(self, center: np.ndarray, radius_m: float) -> np.ndarray:
        """Sorted ids of facades whose bounding box may lie within ``radius_m`` of any of the (P, 2) ``center``s."""
        center = np.asarray(center, dtype=float).reshape(-1, 2)
        if not len(self.cell_keys) or not len(center):
            return np.zeros(0, dtype=np.int64)
        lo = np.floor((center.min(axis=0) - radius_m - self.origin) / self.cell_m).astype(np.int64)
        hi = np.floor((center.max(axis=0) + radius_m - self.origin) / self.cell_m).astype(np.int64)
        lo = np.maximum(lo, 0)
        hi[1] = min(hi[1], self.rows - 1)
        if np.any(hi < lo):
            return np.zeros(0, dtype=np.int64)
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        wanted = (xs * self.rows + ys).ravel()
        slot = np.searchsorted(self.cell_keys, wanted)
        found = slot < len(self.cell_keys)
        found[found] = self.cell_keys[slot[found]] == wanted[found]
        slot = slot[found]
        starts, ends = self.cell_start[slot], self.cell_start[slot + 1]
        lengths = ends - starts
        index = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
        return unique_ids(self.cell_facades[index], len(self.facades.start))


def unique_ids(ids: np.ndarray, size: int) -> np.ndarray:
    """Sorted distinct values of non-negative integers ``ids`` below ``size``: ``np.unique(ids)``, as int64.

    Through a mask of ``size`` where that is cheaper than sorting (np.unique's hashing costs a fixed ~0.1 ms).
    """
    ids = np.asarray(ids, dtype=np.int64).ravel()
    if size > 16 * len(ids) + 1024:
        return np.unique(ids)
    mask = np.zeros(size, dtype=bool)
    mask[ids] = True
    return np.flatnonzero(mask)
