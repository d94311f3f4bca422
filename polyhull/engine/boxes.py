"""Compiled queries on axis-aligned boxes: box/box overlaps and box/triangle meetings.

The dynamic rules ask two questions of this cycle's pieces through their bounding boxes:
which boxes overlap (the components, :func:`overlap_groups`, by sweep and prune) and
which boxes meet any of another set (a margin around pieces, the previous cycle's
components, :func:`any_overlap`, the other set binned in a uniform grid of cubes: a
query tests the boxes of the cells its reach meets). Bounding boxes contain
their pieces, so both answers are supersets of the pieces' own: more grouping and more
meeting, which only keeps more. The cost follows the number of boxes and of overlapping pairs, not the size of
the cell.

A third question asks whether boxes meet a fixed triangle mesh (the surface of the static
region): :class:`TriangleGrid` bins the triangles once in a uniform grid, and
:func:`groups_meet_triangles` tests each box against the triangles of the cells it meets
with the exact triangle/box overlap test (separating axes, Akenine-Moller 2001).
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import GeometryError
from ..typed import ArrayF64
from .threads import share

__all__ = ["OverlapSweep", "overlap_groups", "group_bounds", "any_overlap", "any_near_upright", "TriangleGrid", "groups_meet_triangles"]


@nb.njit(cache=True, nogil=True)
def _find(parent, i):  # pragma: no cover - compiled
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@nb.njit(cache=True, nogil=True)
def _started_before_end(lo_sorted, hi_sorted):  # pragma: no cover - compiled
    """(A,) per axis, the sum over boxes of how many boxes start (``lo``) at or before the
    box's end (``hi``), from each axis' sorted starts and sorted ends (A, N), by merging."""
    n = lo_sorted.shape[1]
    out = np.zeros(lo_sorted.shape[0], dtype=np.int64)
    for a in range(lo_sorted.shape[0]):
        j = 0
        total = 0
        for i in range(n):
            h = hi_sorted[a, i]
            while j < n and lo_sorted[a, j] <= h:
                j += 1
            total += j
        out[a] = total
    return out


@nb.njit(cache=True, nogil=True)
def _strip_arrays(lo, hi, axis, order, z0, w, S):  # pragma: no cover - compiled
    """The boxes [lo, hi] (3, N) binned in ``S`` strips of width ``w`` along z from ``z0``
    (a box in every strip its z extent meets; the outer strips reach to infinity; a box
    with no z extent, inverted or NaN, in none: it meets no box), each strip's boxes in
    sweep ``order`` along ``axis``: (the entries' boxes (E,), their structure of arrays
    (6, E): the start along the axis, the two other axes' bounds (lo, hi, lo, hi), the end
    along the axis; each entry's scan end (E,): the first entry of its strip starting after
    it ends)."""
    n = lo.shape[1]
    b, c = (1, 2) if axis == 0 else ((0, 2) if axis == 1 else (0, 1))
    first = np.empty(n, dtype=np.int64)
    last = np.empty(n, dtype=np.int64)
    count = np.zeros(S + 1, dtype=np.int64)
    for i in range(n):
        zl, zh = lo[2, i], hi[2, i]
        if not zl <= zh:  # inverted or NaN
            first[i], last[i] = 0, -1
            continue
        first[i] = _bin(zl, z0, w, S)
        last[i] = _bin(zh, z0, w, S)
        for st in range(first[i], last[i] + 1):
            count[st + 1] += 1
    for st in range(S):
        count[st + 1] += count[st]
    E = count[S]
    ids = np.empty(E, dtype=np.int64)
    soa = np.empty((6, E))
    fill = count[:-1].copy()
    for k in range(n):
        i = order[k]
        for st in range(first[i], last[i] + 1):
            e = fill[st]
            fill[st] += 1
            ids[e] = i
            soa[0, e] = lo[axis, i]
            soa[1, e] = lo[b, i]
            soa[2, e] = hi[b, i]
            soa[3, e] = lo[c, i]
            soa[4, e] = hi[c, i]
            soa[5, e] = hi[axis, i]
    end = np.empty(E, dtype=np.int64)
    for st in range(S):
        e0, e1 = count[st], count[st + 1]
        if e1 > e0:  # the first entry of the strip starting after each one ends
            end[e0:e1] = np.searchsorted(soa[0, e0:e1], soa[5, e0:e1], side="right") + e0
    return ids, soa, end


@nb.njit(cache=True, nogil=True)
def _scan(ids, soa, end, n, i0, i1):  # pragma: no cover - compiled
    """A union-find forest (n,) over the boxes of the overlaps of entries ``i0 <= i < i1``
    (:func:`_strip_arrays`) with the entries after them in their strip.

    Sweep and prune: each entry scans the entries of its strip that start within its
    extent along the sweep axis. The scan is branch-free (each candidate's overlap along
    the two other axes adds 0 or 1 to a running count, its box kept when it is 1), so it
    costs about a nanosecond per candidate with no mispredicted branches; the union-find
    then joins only the boxes that do overlap."""
    ly, hy, lz, hz = soa[1], soa[2], soa[3], soa[4]
    parent = np.arange(n)
    hits = np.empty(soa.shape[1], dtype=np.int64)
    for i in range(i0, i1):
        y0, y1, z0, z1 = ly[i], hy[i], lz[i], hz[i]
        m = 0
        for j in range(i + 1, end[i]):
            hits[m] = ids[j]
            m += (ly[j] <= y1) & (hy[j] >= y0) & (lz[j] <= z1) & (hz[j] >= z0)
        if m == 0:
            continue
        ri = _find(parent, ids[i])
        for k in range(m):
            rj = _find(parent, hits[k])
            if rj != ri:
                parent[rj] = ri
    return parent


@nb.njit(cache=True, nogil=True)
def _labels(forests):  # pragma: no cover - compiled
    """Labels 0..K-1 (groups numbered by their first box) of the union of the union-find
    forests (P, N) over the boxes."""
    n = forests.shape[1]
    parent = forests[0].copy()
    for f in range(1, forests.shape[0]):
        for x in range(n):
            rx = _find(forests[f], x)
            if rx != x:
                a, b = _find(parent, x), _find(parent, rx)
                if a != b:
                    parent[b] = a
    first = np.full(n, -1, dtype=np.int64)
    labels = np.empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        r = _find(parent, i)
        if first[r] < 0:
            first[r] = count
            count += 1
        labels[i] = first[r]
    return labels


class OverlapSweep:
    """:func:`overlap_groups` in parts: the boxes are binned in horizontal strips (each
    box in every strip its z extent meets: a body standing over the floor's sheet is not
    swept with the sheet under it) and sorted along a sweep axis once, :meth:`scan` scans
    one part (any thread, each part once; the parts hold about equal numbers of candidate
    pairs), and :meth:`labels` joins the parts' forests into the groups (those of one
    scan: the union of the parts' overlaps is every overlap; two boxes that overlap meet
    in a strip)."""

    def __init__(self, lo: ArrayF64, hi: ArrayF64, parts: int = 1) -> None:
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        if lo.ndim != 2 or lo.shape[1:] != (3,) or hi.shape != lo.shape:
            raise GeometryError(f"overlap_groups: expected lo and hi of shape (N, 3), got {lo.shape} and {hi.shape}")
        n = lo.shape[0]
        self._n = n
        parts = max(int(parts), 1)
        lo_t = np.ascontiguousarray(lo.T)  # (3, N)
        hi_t = np.ascontiguousarray(hi.T)
        # the strips: twice the boxes' median height, at most STRIPS of them
        ok = np.isfinite(lo_t[2]) & np.isfinite(hi_t[2]) & (lo_t[2] <= hi_t[2])
        z0, w, S = 0.0, 1.0, 1
        if ok.any():
            zl, zh = lo_t[2][ok], hi_t[2][ok]
            span = float(zh.max() - zl.min())
            w = max(2.0 * float(np.median(zh - zl)), span / STRIPS, 1e-9)
            z0, S = float(zl.min()), int(min(max(np.ceil(span / w), 1), STRIPS))
        # sweep along the axis with the fewest candidate pairs (boxes starting within a box's
        # extent along it), not z when there are strips: per axis, the boxes starting before
        # each box ends (the pairs that start before a box starts add the same n (n - 1) / 2
        # on every axis); numpy's sorts are vectorised, so the sorting stays outside the
        # compiled code
        axis = 0
        if n:
            k = 2 if S > 1 else 3  # the axes to choose from
            started = _started_before_end(np.sort(lo_t[:k], axis=1), np.sort(hi_t[:k], axis=1))
            axis = int(np.argmin(started))
        order = np.argsort(lo_t[axis])
        self._ids, self._soa, self._end = _strip_arrays(lo_t, hi_t, axis, order, z0, w, S)
        # the parts' first entries, at equal shares of the candidates
        E = len(self._ids)
        cand = np.cumsum(np.maximum(self._end - np.arange(E) - 1, 0))  # (an inverted box has none)
        total = float(cand[-1]) if E else 0.0
        cuts = np.searchsorted(cand, total * np.arange(1, parts) / parts, side="right")
        self.bounds = np.concatenate([[0], cuts, [E]]).astype(np.int64)
        """Part p scans the entries ``bounds[p] <= i < bounds[p + 1]`` (strip by strip)."""

    @property
    def parts(self) -> int:
        """The number of parts."""
        return len(self.bounds) - 1

    @property
    def entries(self) -> int:
        """The number of entries: a box once for every strip it is in."""
        return len(self._ids)

    def scan(self, part: int) -> np.ndarray:
        """The union-find forest (N,) of one part's overlaps."""
        return _scan(self._ids, self._soa, self._end, self._n, int(self.bounds[part]), int(self.bounds[part + 1]))

    def labels(self, forests: list[np.ndarray]) -> np.ndarray:
        """(N,) labels 0..K-1 (input order, numbered by each group's first box) from every
        part's forest."""
        if not self._n:
            return np.zeros(0, dtype=np.int64)
        return _labels(np.stack(forests))


STRIPS = 1024
"""Most strips of :class:`OverlapSweep`."""


def overlap_groups(lo: ArrayF64, hi: ArrayF64) -> np.ndarray:
    """(N,) labels 0..K-1 of the connected groups of overlapping boxes [lo, hi] (N, 3).

    Boxes are closed: boxes that only touch overlap. Groups are numbered in the order of
    their first box (box 0 is in group 0). (:class:`OverlapSweep` in one part.)
    """
    sweep = OverlapSweep(lo, hi)
    return sweep.labels([sweep.scan(0)])


@nb.njit(cache=True, nogil=True)
def _group_bounds(labels, lo, hi, clo, chi):  # pragma: no cover - compiled
    for i in range(labels.shape[0]):
        k = labels[i]
        for a in range(3):
            clo[k, a] = min(clo[k, a], lo[i, a])
            chi[k, a] = max(chi[k, a], hi[i, a])


def group_bounds(labels: np.ndarray, lo: ArrayF64, hi: ArrayF64, K: int) -> tuple[ArrayF64, ArrayF64]:
    """(K, 3) bounds of the union of each group's boxes [lo, hi] (N, 3) (``labels`` (N,)
    in 0..K-1; +inf / -inf for an empty group)."""
    clo = np.full((K, 3), np.inf)
    chi = np.full((K, 3), -np.inf)
    _group_bounds(
        np.ascontiguousarray(labels, dtype=np.int64),
        np.ascontiguousarray(lo, dtype=np.float64),
        np.ascontiguousarray(hi, dtype=np.float64),
        clo,
        chi,
    )
    return clo, chi


@nb.njit(cache=True, nogil=True, inline="always")
def _bin(x, x0, cell, n):  # pragma: no cover - compiled
    """The grid column (or row) of coordinate ``x``, clamped to [0, n - 1]."""
    f = (x - x0) / cell
    if f <= 0.0:
        return 0
    if f >= n - 1:
        return n - 1
    return int(f)


@nb.njit(cache=True, nogil=True)
def _bin_boxes(blo, bhi, o, cell, n):  # pragma: no cover - compiled
    """The boxes binned in a grid of ``n`` (3,) cubic cells of side ``cell`` from ``o``
    (3,) (the outer cells extend to infinity): (start (n0 n1 n2 + 1,), items) such that
    ``items[start[c]:start[c + 1]]`` are the boxes whose extent meets cell
    ``c = (iz n1 + iy) n0 + ix``."""
    m = blo.shape[0]
    nc = n[0] * n[1] * n[2]
    start = np.zeros(nc + 1, dtype=np.int64)
    items = np.empty(0, dtype=np.int64)
    fill = start[:-1]
    for counting in (True, False):  # count each cell's boxes, then list them
        for j in range(m):
            ix0, ix1 = _bin(blo[j, 0], o[0], cell, n[0]), _bin(bhi[j, 0], o[0], cell, n[0])
            iy0, iy1 = _bin(blo[j, 1], o[1], cell, n[1]), _bin(bhi[j, 1], o[1], cell, n[1])
            iz0, iz1 = _bin(blo[j, 2], o[2], cell, n[2]), _bin(bhi[j, 2], o[2], cell, n[2])
            for iz in range(iz0, iz1 + 1):
                for iy in range(iy0, iy1 + 1):
                    for ix in range(ix0, ix1 + 1):
                        c = (iz * n[1] + iy) * n[0] + ix
                        if counting:
                            start[c + 1] += 1
                        else:
                            items[fill[c]] = j
                            fill[c] += 1
        if counting:
            for c in range(nc):
                start[c + 1] += start[c]
            items = np.empty(start[nc], dtype=np.int64)
            fill = start[:-1].copy()
    return start, items


@nb.njit(cache=True, nogil=True)
def _any(qlo, qhi, blo, bhi, start, items, o, cell, n, reach, dims, seen, out):  # pragma: no cover - compiled
    """For each query box: does a box (binned by :func:`_bin_boxes`) meet it? The
    candidates are the boxes of the cells the query's box grown by ``reach`` meets (a box
    that meets the grown query meets one of them), each tested once (``seen`` (M,), -1 at
    first, holds the last query that tested a box). A candidate meets the query when it
    overlaps the query's box grown by ``reach`` on every side and their Euclidean gap
    over the first ``dims`` axes (3, or 2: in x, y only) is at most ``reach``. The box the
    last hit found is tested first (consecutive queries, a column's slabs or a tile's
    neighbours, mostly meet the same box), then the boxes of the query's centre cell,
    then the other cells'. A query that meets nothing visits only the cells within its
    reach, along z too: the cells are cubes, not columns, so a query in the floor's
    sheet does not scan the body standing above it."""
    r2 = reach * reach
    last = -1
    n0, n1 = n[0], n[1]
    for i in range(qlo.shape[0]):
        l0, l1, l2 = qlo[i, 0] - reach, qlo[i, 1] - reach, qlo[i, 2] - reach
        h0, h1, h2 = qhi[i, 0] + reach, qhi[i, 1] + reach, qhi[i, 2] + reach
        if last >= 0 and _meets(qlo, qhi, blo, bhi, i, last, l0, l1, l2, h0, h1, h2, reach, r2, dims):
            out[i] = True
            continue
        ix0, ix1 = _bin(l0, o[0], cell, n0), _bin(h0, o[0], cell, n0)
        iy0, iy1 = _bin(l1, o[1], cell, n1), _bin(h1, o[1], cell, n1)
        iz0, iz1 = _bin(l2, o[2], cell, n[2]), _bin(h2, o[2], cell, n[2])
        cx = _bin(0.5 * (qlo[i, 0] + qhi[i, 0]), o[0], cell, n0)
        cy = _bin(0.5 * (qlo[i, 1] + qhi[i, 1]), o[1], cell, n1)
        cz = _bin(0.5 * (qlo[i, 2] + qhi[i, 2]), o[2], cell, n[2])
        sx, sy = ix1 - ix0 + 1, iy1 - iy0 + 1
        hit = False
        for k in range(-1, sx * sy * (iz1 - iz0 + 1)):
            if k < 0:
                c = (cz * n1 + cy) * n0 + cx
            else:
                c = ((iz0 + k // (sx * sy)) * n1 + iy0 + (k // sx) % sy) * n0 + ix0 + k % sx
            for a in range(start[c], start[c + 1]):
                j = items[a]
                if seen[j] == i:
                    continue
                seen[j] = i
                if _meets(qlo, qhi, blo, bhi, i, j, l0, l1, l2, h0, h1, h2, reach, r2, dims):
                    hit = True
                    last = j
                    break
            if hit:
                break
        out[i] = hit


@nb.njit(cache=True, nogil=True, inline="always")
def _meets(qlo, qhi, blo, bhi, i, j, l0, l1, l2, h0, h1, h2, reach, r2, dims):  # pragma: no cover - compiled
    """Whether box j meets query i: it overlaps the query's box grown by ``reach``
    ([l0, h0] x [l1, h1] x [l2, h2]) and their gap over the first ``dims`` axes is at
    most ``reach`` (``r2`` its square)."""
    if blo[j, 0] <= h0 and bhi[j, 0] >= l0 and blo[j, 1] <= h1 and bhi[j, 1] >= l1 and blo[j, 2] <= h2 and bhi[j, 2] >= l2:
        return reach == 0.0 or _gap2(qlo, qhi, blo, bhi, i, j, dims) <= r2
    return False


@nb.njit(cache=True, nogil=True, inline="always")
def _gap2(qlo, qhi, blo, bhi, i, j, dims):  # pragma: no cover - compiled
    """Squared Euclidean gap between query box i and box j over their first ``dims`` axes
    (0 when they overlap)."""
    g2 = 0.0
    for a in range(dims):
        g = max(blo[j, a] - qhi[i, a], qlo[i, a] - bhi[j, a], 0.0)
        g2 += g * g
    return g2


@nb.njit(cache=True, nogil=True)
def _query_bounds(qlo, qhi, reach, finite, glo, ghi):  # pragma: no cover - compiled
    """Mark the queries whose coordinates are all finite (``finite``); their bounds grown
    by ``reach`` into ``glo``, ``ghi`` (3,). False when no query is finite."""
    for a in range(3):
        glo[a] = np.inf
        ghi[a] = -np.inf
    anyf = False
    for i in range(qlo.shape[0]):
        ok = True
        for a in range(3):
            ok &= np.isfinite(qlo[i, a]) & np.isfinite(qhi[i, a])
        finite[i] = ok
        if ok:
            anyf = True
            for a in range(3):
                glo[a] = min(glo[a], qlo[i, a] - reach)
                ghi[a] = max(ghi[a], qhi[i, a] + reach)
    return anyf


@nb.njit(cache=True, nogil=True)
def _near_boxes(blo, bhi, glo, ghi):  # pragma: no cover - compiled
    """The boxes that meet [glo, ghi]: (True, their indices, the grid's origin (3,) and
    extent (3,) over them and [glo, ghi]), or False first when some box has a non-finite
    coordinate."""
    m = blo.shape[0]
    idx = np.empty(m, dtype=np.int64)
    k = 0
    bmin = np.full(3, np.inf)
    bmax = np.full(3, -np.inf)
    for j in range(m):
        meet = True
        for a in range(3):
            if not (np.isfinite(blo[j, a]) and np.isfinite(bhi[j, a])):
                return False, idx[:0], bmin, bmax
            meet &= (blo[j, a] <= ghi[a]) & (bhi[j, a] >= glo[a])
        if meet:
            idx[k] = j
            k += 1
            for a in range(3):
                bmin[a] = min(bmin[a], blo[j, a])
                bmax[a] = max(bmax[a], bhi[j, a])
    o = np.maximum(glo, bmin)
    side = np.maximum(np.minimum(ghi, bmax) - o, 0.0)
    return True, idx[:k], o, side


@nb.njit(cache=True, nogil=True)
def _median_extent(blo, bhi):  # pragma: no cover - compiled
    """The median of the boxes' extents over the three axes."""
    k = blo.shape[0]
    ext = np.empty(3 * k)
    for t in range(k):
        for a in range(3):
            ext[3 * t + a] = bhi[t, a] - blo[t, a]
    return np.median(ext) if k else 0.0


@nb.njit(cache=True, nogil=True)
def _any_brute(qlo, qhi, blo, bhi, reach, dims, out):  # pragma: no cover - compiled
    """:func:`_any` without a grid: each query against every box (a few queries)."""
    r2 = reach * reach
    for i in range(qlo.shape[0]):
        l0, l1, l2 = qlo[i, 0] - reach, qlo[i, 1] - reach, qlo[i, 2] - reach
        h0, h1, h2 = qhi[i, 0] + reach, qhi[i, 1] + reach, qhi[i, 2] + reach
        for j in range(blo.shape[0]):
            if _meets(qlo, qhi, blo, bhi, i, j, l0, l1, l2, h0, h1, h2, reach, r2, dims):
                out[i] = True
                break


def any_overlap(
    qlo: ArrayF64,
    qhi: ArrayF64,
    blo: ArrayF64,
    bhi: ArrayF64,
    pool: Executor | None = None,
    reach: float = 0.0,
    upright: bool = False,
) -> np.ndarray:
    """(N,) whether each query box [qlo, qhi] (N, 3) meets any box [blo, bhi] (M, 3), or
    with ``reach`` [m] comes within that Euclidean distance of one (the box grown by a
    ball, not by a cube: along a diagonal a cube reaches sqrt(3) times as far); with
    ``upright``, within ``reach`` horizontally (the Euclidean gap in x, y) and along z (the
    box grown by an upright cylinder of that radius and half-height).
    With a ``pool`` and many queries, the queries are split over this thread and one of the
    pool's."""
    out = np.zeros(qlo.shape[0], dtype=bool)
    if qlo.shape[0] == 0 or blo.shape[0] == 0:
        return out
    blo = np.ascontiguousarray(blo, dtype=np.float64)
    bhi = np.ascontiguousarray(bhi, dtype=np.float64)
    qlo = np.ascontiguousarray(qlo, dtype=np.float64)
    qhi = np.ascontiguousarray(qhi, dtype=np.float64)
    # nothing is known of a box with a non-finite coordinate: it may meet anything
    finite = np.empty(len(qlo), dtype=np.bool_)
    glo, ghi = np.empty(3), np.empty(3)
    if not _query_bounds(qlo, qhi, float(reach), finite, glo, ghi):
        out[:] = True  # no finite query
        return out
    # only the boxes that meet the queries' bounds (grown by the reach) can meet a query
    # (the queries often lie in one part of the boxes: the pieces in the floor's sheet,
    # under a person's pieces); with the grid's origin, extent and cell (see _near_boxes)
    ok, near, o, side = _near_boxes(blo, bhi, glo, ghi)
    if not ok:
        out[:] = True  # a box with a non-finite coordinate
        return out
    if len(near) < len(blo):
        if len(near) == 0:
            out[~finite] = True
            return out
        blo, bhi = blo[near], bhi[near]
    if not finite.all():  # (answered at the end)
        qlo, qhi = np.where(finite[:, None], qlo, 0.0), np.where(finite[:, None], qhi, 0.0)
    if len(qlo) <= BRUTE_QUERIES:
        # a few queries: each against every box costs less than binning the boxes
        _any_brute(qlo, qhi, blo, bhi, float(reach), 2 if upright else 3, out)
        out[~finite] = True
        return out
    # the boxes binned in a grid of cubes over the queries' reach (cells at least the
    # boxes' median extent and half the reach, at most GRID_CELLS of them; the boxes beyond
    # the grid fall into its outer cells, which reach to infinity)
    cell = max(float(_median_extent(blo, bhi)), float(reach) / 2.0, 1e-3)
    n = np.clip(np.ceil(side / cell), 1, GRID_CELLS).astype(np.int64)
    while int(np.prod(n)) > GRID_CELLS:
        cell *= 1.25
        n = np.clip(np.ceil(side / cell), 1, GRID_CELLS).astype(np.int64)
    start, items = _bin_boxes(blo, bhi, o, cell, n)

    def run(sl: slice) -> np.ndarray:
        ql, qh = np.ascontiguousarray(qlo[sl]), np.ascontiguousarray(qhi[sl])
        out_ = np.zeros(len(ql), dtype=bool)
        seen = np.full(len(blo), -1, dtype=np.int64)
        _any(ql, qh, blo, bhi, start, items, o, cell, n, float(reach), 2 if upright else 3, seen, out_)
        return out_

    if pool is None or len(qlo) < ANY_PARALLEL_MIN:
        out = run(slice(None))
    else:
        # interleaved halves: neighbouring queries (similar work) go to both threads
        even, odd = share(pool, run, (slice(0, None, 2), slice(1, None, 2)))
        out[0::2], out[1::2] = even, odd
    out[~finite] = True
    return out


def any_near_upright(
    qlo: ArrayF64, qhi: ArrayF64, blo: ArrayF64, bhi: ArrayF64, margin: float, pool: Executor | None = None
) -> np.ndarray:
    """(N,) whether each query box [qlo, qhi] (N, 3) comes within ``margin`` [m] of any box
    [blo, bhi] (M, 3) horizontally (a disc in x, y) and within ``margin`` along z: each
    box grown by an upright cylinder of that radius and half-height (world frame, z up).
    The shell rule's margin: a foot inside the floor's sheet reaches as far from the leg in
    every horizontal direction, and a square (a cube's growth) reaches sqrt(2) times as far
    along its diagonals as any foot does."""
    return any_overlap(qlo, qhi, blo, bhi, pool, reach=float(margin), upright=True)


ANY_PARALLEL_MIN = 512
"""Fewest queries :func:`any_overlap` splits over two threads."""

BRUTE_QUERIES = 8
"""Most queries :func:`any_overlap` tests against every box, without binning the boxes (a
query against a box costs a few nanoseconds; binning a box, tens)."""

GRID_CELLS = 16384
"""Most cells of :func:`any_overlap`'s grid (its cubes are at least the boxes' median
extent and half the reach, larger when that many would not cover the queries' reach)."""


@nb.njit(cache=True, nogil=True, inline="always")
def _apart(ax, ay, az, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz):  # pragma: no cover - compiled
    """Whether the axis (ax, ay, az) separates the triangle (x0, y0, z0) (x1, y1, z1)
    (x2, y2, z2), relative to the box's centre, from the box of half sides (hx, hy, hz):
    the projections, both closed, do not meet."""
    p0 = ax * x0 + ay * y0 + az * z0
    p1 = ax * x1 + ay * y1 + az * z1
    p2 = ax * x2 + ay * y2 + az * z2
    r = hx * abs(ax) + hy * abs(ay) + hz * abs(az)
    return min(p0, p1, p2) > r or max(p0, p1, p2) < -r


@nb.njit(cache=True, nogil=True, inline="always")
def _edge_apart(ex, ey, ez, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz):  # pragma: no cover - compiled
    """Whether a box axis crossed with the edge (ex, ey, ez) separates them."""
    return (
        _apart(0.0, -ez, ey, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz)
        or _apart(ez, 0.0, -ex, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz)
        or _apart(-ey, ex, 0.0, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz)
    )


@nb.njit(cache=True, nogil=True)
def _triangle_meets_box(p0, p1, p2, c, h):  # pragma: no cover - compiled
    """Whether the closed triangle p0 p1 p2 meets the closed box of centre c and half
    sides h (all (3,)): no separating axis among the box's three face normals, the
    triangle's normal and the nine cross products of a box axis with a triangle edge
    (Akenine-Moller, "Fast 3D triangle-box overlap testing", 2001). Exact up to rounding
    (a few ulps of the coordinates); a degenerate triangle is tested as its segment."""
    hx, hy, hz = h[0], h[1], h[2]
    x0, y0, z0 = p0[0] - c[0], p0[1] - c[1], p0[2] - c[2]
    x1, y1, z1 = p1[0] - c[0], p1[1] - c[1], p1[2] - c[2]
    x2, y2, z2 = p2[0] - c[0], p2[1] - c[1], p2[2] - c[2]
    # the box's face normals: the triangle's bounds against the box
    if min(x0, x1, x2) > hx or max(x0, x1, x2) < -hx:
        return False
    if min(y0, y1, y2) > hy or max(y0, y1, y2) < -hy:
        return False
    if min(z0, z1, z2) > hz or max(z0, z1, z2) < -hz:
        return False
    # the box's axes crossed with the three edges
    if _edge_apart(x1 - x0, y1 - y0, z1 - z0, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz):
        return False
    if _edge_apart(x2 - x1, y2 - y1, z2 - z1, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz):
        return False
    if _edge_apart(x0 - x2, y0 - y2, z0 - z2, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz):
        return False
    # the triangle's plane
    ax, ay, az = x1 - x0, y1 - y0, z1 - z0
    bx, by, bz = x2 - x1, y2 - y1, z2 - z1
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    return not _apart(nx, ny, nz, x0, y0, z0, x1, y1, z1, x2, y2, z2, hx, hy, hz)


@nb.njit(cache=True, nogil=True, inline="always")
def _cell(x, origin, pitch, n):  # pragma: no cover - compiled
    """The grid index of coordinate x along an axis, clamped to 0..n-1 (monotone in x;
    0 for NaN)."""
    k = np.floor((x - origin) / pitch)
    if not k >= 0.0:
        return 0
    if k > n - 1:
        return n - 1
    return int(k)


@nb.njit(cache=True, nogil=True)
def _bin_pass(vertices, triangles, origin, pitch, dims, slack, at, items, fill):  # pragma: no cover - compiled
    """One pass over the (triangle, cell) pairs that meet, cells grown by ``slack`` [m]:
    count them in ``at[cell + 1]`` (``fill`` False), or write each triangle at
    ``items[at[cell]]`` and advance ``at[cell]`` (``fill`` True)."""
    ny, nz = dims[1], dims[2]
    h = np.full(3, 0.5 * pitch + slack)
    c = np.empty(3)
    k0 = np.empty(3, dtype=np.int64)
    k1 = np.empty(3, dtype=np.int64)
    for t in range(triangles.shape[0]):
        p0 = vertices[triangles[t, 0]]
        p1 = vertices[triangles[t, 1]]
        p2 = vertices[triangles[t, 2]]
        for a in range(3):
            k0[a] = _cell(min(p0[a], p1[a], p2[a]), origin[a], pitch, dims[a])
            k1[a] = _cell(max(p0[a], p1[a], p2[a]), origin[a], pitch, dims[a])
        # a small triangle is listed in every cell of its bounds (a few more candidates),
        # a large one only in the cells it meets
        exact = (k1[0] - k0[0] + 1) * (k1[1] - k0[1] + 1) * (k1[2] - k0[2] + 1) > 8
        for x in range(k0[0], k1[0] + 1):
            c[0] = origin[0] + (x + 0.5) * pitch
            for y in range(k0[1], k1[1] + 1):
                c[1] = origin[1] + (y + 0.5) * pitch
                for z in range(k0[2], k1[2] + 1):
                    c[2] = origin[2] + (z + 0.5) * pitch
                    if exact and not _triangle_meets_box(p0, p1, p2, c, h):
                        continue
                    k = (x * ny + y) * nz + z
                    if fill:
                        items[at[k]] = t
                        at[k] += 1
                    else:
                        at[k + 1] += 1


@nb.njit(cache=True, nogil=True)
def _bin_triangles(vertices, triangles, origin, pitch, dims, slack):  # pragma: no cover - compiled
    """CSR (start, items) of the triangles meeting each cell grown by ``slack`` [m]."""
    n_cells = dims[0] * dims[1] * dims[2]
    start = np.zeros(n_cells + 1, dtype=np.int64)
    items = np.empty(0, dtype=np.int64)
    _bin_pass(vertices, triangles, origin, pitch, dims, slack, start, items, False)
    for k in range(n_cells):
        start[k + 1] += start[k]
    items = np.empty(start[n_cells], dtype=np.int64)
    at = start[:-1].copy()
    _bin_pass(vertices, triangles, origin, pitch, dims, slack, at, items, True)
    return start, items


@nb.njit(cache=True, nogil=True)
def _box_meets(vertices, triangles, tlo, thi, origin, pitch, dims, start, items, lo, hi):  # pragma: no cover - compiled
    """Whether the closed box [lo, hi] (3,) meets a triangle of the grid."""
    ny, nz = dims[1], dims[2]
    c = 0.5 * (lo + hi)
    # half sides that reach lo and hi from c despite the rounding of c
    h = np.maximum(hi - c, c - lo)
    x0 = _cell(lo[0], origin[0], pitch, dims[0])
    x1 = _cell(hi[0], origin[0], pitch, dims[0])
    y0 = _cell(lo[1], origin[1], pitch, dims[1])
    y1 = _cell(hi[1], origin[1], pitch, dims[1])
    z0 = _cell(lo[2], origin[2], pitch, dims[2])
    z1 = _cell(hi[2], origin[2], pitch, dims[2])
    for x in range(x0, x1 + 1):
        for y in range(y0, y1 + 1):
            for z in range(z0, z1 + 1):
                k = (x * ny + y) * nz + z
                for m in range(start[k], start[k + 1]):
                    t = items[m]
                    if (
                        tlo[t, 0] > hi[0] or thi[t, 0] < lo[0]
                        or tlo[t, 1] > hi[1] or thi[t, 1] < lo[1]
                        or tlo[t, 2] > hi[2] or thi[t, 2] < lo[2]
                    ):
                        continue
                    tri = triangles[t]
                    if _triangle_meets_box(vertices[tri[0]], vertices[tri[1]], vertices[tri[2]], c, h):
                        return True
    return False


@nb.njit(cache=True, nogil=True)
def _groups_meet(vertices, triangles, tlo, thi, origin, pitch, dims, start, items, lo, hi, groups, out):  # pragma: no cover - compiled
    for i in range(lo.shape[0]):
        g = groups[i]
        if out[g]:
            continue
        if not (np.all(np.isfinite(lo[i])) and np.all(np.isfinite(hi[i]))):
            out[g] = True  # nothing is known of it: it may meet
            continue
        if _box_meets(vertices, triangles, tlo, thi, origin, pitch, dims, start, items, lo[i], hi[i]):
            out[g] = True


@dataclass(frozen=True, eq=False)
class TriangleGrid:
    """A triangle mesh binned in a uniform grid of cubes, for :func:`groups_meet_triangles`.

    Every triangle is listed in each cell it meets (cells grown by a millionth of the
    pitch, so rounding never drops one; a triangle whose bounds span at most 2 x 2 x 2
    cells in all of them), so a box meets a triangle only if it meets one listed in a
    cell the box meets.

    Attributes:
        vertices: (V, 3) vertex positions [m].
        triangles: (T, 3) vertex indices.
        lower: (T, 3) the triangles' minima [m]; ``upper`` their maxima.
        origin: (3,) the grid's first corner [m] (the vertices' minima).
        pitch: The cells' side [m].
        dims: (3,) the number of cells along x, y, z.
        start: (C + 1,) where each cell's triangles start in ``items`` (cell
            ``(x * dims[1] + y) * dims[2] + z``).
        items: The triangle indices of the cells, one cell after another.
    """

    vertices: ArrayF64
    triangles: np.ndarray
    lower: ArrayF64
    upper: ArrayF64
    origin: ArrayF64
    pitch: float
    dims: np.ndarray
    start: np.ndarray
    items: np.ndarray

    MAX_CELLS = 1 << 21
    """The most cells a grid has (the pitch grows until it fits)."""

    @classmethod
    def of(cls, vertices: ArrayF64, triangles: np.ndarray, pitch: float | None = None) -> TriangleGrid:
        """Bin ``triangles`` (T, 3) of ``vertices`` (V, 3) [m].

        Args:
            vertices: (V, 3) finite vertex positions [m].
            triangles: (T, 3) vertex indices, T >= 1.
            pitch: The cells' side [m]; None: four times the median side of the
                triangles' bounding boxes (a few triangles per cell on a fine mesh), more
                when the grid would exceed ``MAX_CELLS`` cells.
        """
        v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
        t = np.ascontiguousarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(t) == 0 or not np.all(np.isfinite(v)):
            raise GeometryError(
                f"triangle grid: expected >= 1 triangle and finite vertices, got {len(t)} triangles"
                + ("" if np.all(np.isfinite(v)) else " and non-finite vertices")
            )
        if t.min() < 0 or t.max() >= len(v):
            raise GeometryError(f"triangle grid: vertex indices must lie in 0..{len(v) - 1}, got {t.min()}..{t.max()}")
        corners = v[t]  # (T, 3, 3)
        lower = corners.min(axis=1)
        upper = corners.max(axis=1)
        origin = v.min(axis=0)
        span = v.max(axis=0) - origin
        if pitch is None:
            pitch = 4.0 * float(np.median((upper - lower).max(axis=1)))
        pitch = max(float(pitch), 1e-6 * max(float(span.max()), 1e-3))
        while np.prod(np.floor(span / pitch) + 1) > cls.MAX_CELLS:
            pitch *= 1.25
        dims = (np.floor(span / pitch) + 1).astype(np.int64)
        start, items = _bin_triangles(v, t, origin, pitch, dims, 1e-6 * pitch)
        for a in (v, t, lower, upper, origin, dims, start, items):
            a.setflags(write=False)
        return cls(v, t, lower, upper, origin, pitch, dims, start, items)


def groups_meet_triangles(
    grid: TriangleGrid, lo: ArrayF64, hi: ArrayF64, groups: np.ndarray, n_groups: int
) -> np.ndarray:
    """(G,) for each group 0..G-1 of closed boxes [lo, hi] (N, 3) [m], whether some box of
    it meets a triangle of ``grid`` (touching counts; a box holding a triangle whole meets
    it; a box with a non-finite coordinate is taken to meet). Exact up to rounding (a few
    ulps of the coordinates): grow the boxes by more than that for an answer that never
    misses a touching triangle.

    Args:
        grid: The triangles.
        lo: (N, 3) box minima [m].
        hi: (N, 3) box maxima [m].
        groups: (N,) the group of each box, in 0..G-1.
        n_groups: G.
    """
    out = np.zeros(n_groups, dtype=bool)
    lo = np.ascontiguousarray(lo, dtype=np.float64)
    hi = np.ascontiguousarray(hi, dtype=np.float64)
    groups = np.ascontiguousarray(groups, dtype=np.int64)
    if lo.ndim != 2 or lo.shape[1:] != (3,) or hi.shape != lo.shape or groups.shape != lo.shape[:1]:
        raise GeometryError(
            f"boxes against triangles: expected lo, hi (N, 3) and groups (N,), got {lo.shape}, {hi.shape}, {groups.shape}"
        )
    if len(lo) == 0:
        return out
    if groups.min() < 0 or groups.max() >= n_groups:
        raise GeometryError(f"boxes against triangles: groups must lie in 0..{n_groups - 1}, got {groups.min()}..{groups.max()}")
    _groups_meet(
        grid.vertices,
        grid.triangles,
        grid.lower,
        grid.upper,
        grid.origin,
        grid.pitch,
        grid.dims,
        grid.start,
        grid.items,
        lo,
        hi,
        groups,
        out,
    )
    return out
