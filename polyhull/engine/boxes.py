"""Axis-aligned box overlaps by sweep and prune (sort along x, scan the overlapping run).

The dynamic rules ask two questions of this cycle's pieces through their bounding boxes:
which boxes overlap (the components) and which boxes meet any of another set (a margin
around pieces, the previous cycle's components). Bounding boxes contain their pieces, so
both answers are supersets of the pieces' own: more grouping and more meeting, which only
keeps more. The cost follows the number of boxes and of overlapping pairs, not the size of
the cell.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..typed import ArrayF64

__all__ = ["overlap_groups", "any_overlap"]


@nb.njit(cache=True, nogil=True)
def _find(parent, i):  # pragma: no cover - compiled
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@nb.njit(cache=True, nogil=True)
def _groups(lo, hi):  # pragma: no cover - compiled
    """Union-find labels of boxes sorted by ``lo[:, 0]`` (the sweep axis first)."""
    n = lo.shape[0]
    parent = np.arange(n)
    for i in range(n):
        hx, ly, hy, lz, hz = hi[i, 0], lo[i, 1], hi[i, 1], lo[i, 2], hi[i, 2]
        for j in range(i + 1, n):
            if lo[j, 0] > hx:
                break
            if lo[j, 1] <= hy and hi[j, 1] >= ly and lo[j, 2] <= hz and hi[j, 2] >= lz:
                ri = _find(parent, i)
                rj = _find(parent, j)
                if ri != rj:
                    parent[ri] = rj
    labels = np.empty(n, dtype=np.int64)
    for i in range(n):
        labels[i] = _find(parent, i)
    return labels


def overlap_groups(lo: ArrayF64, hi: ArrayF64) -> np.ndarray:
    """(N,) labels 0..K-1 of the connected groups of overlapping boxes [lo, hi] (N, 3)."""
    if lo.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    # sweep along the axis with the fewest candidate pairs (boxes starting within a box's
    # extent along it), the others tested per pair
    best, best_pairs = 0, -1
    for a in range(3):
        keys = np.sort(lo[:, a])
        pairs = int((np.searchsorted(keys, hi[:, a], side="right") - np.searchsorted(keys, lo[:, a])).sum())
        if best_pairs < 0 or pairs < best_pairs:
            best, best_pairs = a, pairs
    axes = [best] + [a for a in range(3) if a != best]
    order = np.argsort(lo[:, best], kind="stable")
    roots = np.empty(lo.shape[0], dtype=np.int64)
    roots[order] = _groups(
        np.ascontiguousarray(lo[order][:, axes], dtype=np.float64),
        np.ascontiguousarray(hi[order][:, axes], dtype=np.float64),
    )
    _, labels = np.unique(roots, return_inverse=True)
    return labels.astype(np.int64).reshape(-1)


@nb.njit(cache=True, nogil=True)
def _any(qlo, qhi, blo, bhi, order, keys, extent, out):  # pragma: no cover - compiled
    for i in range(qlo.shape[0]):
        start = np.searchsorted(keys, qlo[i, 0] - extent, side="left")
        for a in range(start, order.shape[0]):
            if keys[a] > qhi[i, 0]:
                break
            j = order[a]
            if (
                bhi[j, 0] >= qlo[i, 0]
                and blo[j, 1] <= qhi[i, 1]
                and bhi[j, 1] >= qlo[i, 1]
                and blo[j, 2] <= qhi[i, 2]
                and bhi[j, 2] >= qlo[i, 2]
            ):
                out[i] = True
                break


def any_overlap(qlo: ArrayF64, qhi: ArrayF64, blo: ArrayF64, bhi: ArrayF64) -> np.ndarray:
    """(N,) whether each query box [qlo, qhi] (N, 3) meets any box [blo, bhi] (M, 3)."""
    out = np.zeros(qlo.shape[0], dtype=bool)
    if qlo.shape[0] == 0 or blo.shape[0] == 0:
        return out
    blo = np.ascontiguousarray(blo, dtype=np.float64)
    bhi = np.ascontiguousarray(bhi, dtype=np.float64)
    qlo = np.ascontiguousarray(qlo, dtype=np.float64)
    qhi = np.ascontiguousarray(qhi, dtype=np.float64)
    # A query scans the boxes starting within the longest box's extent before it: the few
    # long boxes are scanned in a pass of their own, so they do not widen every scan.
    ext = bhi[:, 0] - blo[:, 0]
    cut = float(np.quantile(ext, 0.9))
    for part in (np.nonzero(ext <= cut)[0], np.nonzero(ext > cut)[0]):
        if len(part) == 0:
            continue
        order = part[np.argsort(blo[part, 0], kind="stable")]
        keys = np.ascontiguousarray(blo[order, 0])
        _any(qlo, qhi, blo, bhi, order, keys, float(ext[part].max()), out)
    return out
