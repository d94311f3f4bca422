"""Dynamic pieces: the occluded segments of unexplained pixels, carved by the other cameras.

A piece is a convex frustum hexahedron in one camera's image space: a rectangle of whole
pixels ``[u0 - 1/2, u1 + 1/2] x [v0 - 1/2, v1 + 1/2]`` between two z-depths ``z0 < z1``.
Its faces are planar in the world (four through the camera centre, two at constant z), so a
union of pieces is an exact polyhedral set.

Pieces start as the tiles of :func:`polyhull.engine.pixels.tile_segments`. Each piece is
tested against every other camera ``i`` with a frame:

- **covered** by i when its eight vertices are in front of i's near plane, project inside
  i's image, and lie nearer than the *minimum* free depth of i over the pixel box they
  project to: then every point of the (convex) piece is free for i;
- **maybe freed** by i when some vertex is nearer than the *maximum* free depth there.

A piece covered by at least k cameras (the k-of-n rule) is dropped: it is free. A piece
maybe-freed by fewer than k cameras is kept whole: none of its points is free. Otherwise
it is split in two along its longest side (a whole-pixel cut of its rectangle, or its
depth range at the middle), each half shrunk to the pixels and depths whose segments it
still meets, until its size is below ``clip(alpha * d, size_min, size_max)`` where ``d`` is
a lower bound of its distance to the robot (less an optional offset): fine near the robot,
coarse far from it. A
piece that reaches that size undecided is kept: keeping only grows the region.

The pyramids give the minimum and maximum over a superset of the pixel box (aligned cells
of a level with at most eight cells a side), which makes "covered" rarer and "maybe"
commoner: both only keep more. Pieces entirely outside the zone's box are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import NamedTuple

import numba as nb
import numpy as np

from ..camera import Camera
from ..typed import ArrayF64
from .pixels import build_pyramid, project_bounds, push_row, pyramid_layout, update_pyramid
from .threads import share

__all__ = [
    "CameraStack",
    "ImageStack",
    "MTest",
    "PieceSet",
    "PyramidStack",
    "carve",
    "columns_in_m",
    "merge_adjacent",
    "piece_vertices",
    "piece_volumes",
    "vertex_bounds",
]


@dataclass(frozen=True, eq=False)
class CameraStack:
    """The cameras' poses and intrinsics as arrays for the compiled kernels."""

    R_cw: ArrayF64  # (n, 3, 3) world -> camera rotation
    t_cw: ArrayF64  # (n, 3)
    R_wc: ArrayF64  # (n, 3, 3) camera -> world rotation
    t_wc: ArrayF64  # (n, 3)
    intr: ArrayF64  # (n, 4) fx, fy, cx, cy [px]
    size: np.ndarray  # (n, 2) int64 width, height [px]
    near: ArrayF64  # (n,)
    far: ArrayF64  # (n,)

    @classmethod
    def of(cls, cameras: Sequence[Camera]) -> CameraStack:
        """Stack the cameras' parameters."""
        return cls(
            R_cw=np.array([c.T_camera_world[:3, :3] for c in cameras], dtype=np.float64).reshape(-1, 3, 3),
            t_cw=np.array([c.T_camera_world[:3, 3] for c in cameras], dtype=np.float64).reshape(-1, 3),
            R_wc=np.array([c.T_world_camera[:3, :3] for c in cameras], dtype=np.float64).reshape(-1, 3, 3),
            t_wc=np.array([c.T_world_camera[:3, 3] for c in cameras], dtype=np.float64).reshape(-1, 3),
            intr=np.array(
                [[c.intrinsics.fx, c.intrinsics.fy, c.intrinsics.cx, c.intrinsics.cy] for c in cameras],
                dtype=np.float64,
            ).reshape(-1, 4),
            size=np.array([[c.intrinsics.width, c.intrinsics.height] for c in cameras], dtype=np.int64).reshape(-1, 2),
            near=np.array([c.near for c in cameras], dtype=np.float64),
            far=np.array([c.far for c in cameras], dtype=np.float64),
        )


@dataclass(frozen=True, eq=False)
class PieceSet:
    """A union of convex frustum hexahedra (see the module docstring).

    Attributes:
        boxes: (N, 7) camera index, u0, u1, v0, v1 (inclusive pixel indices), z0, z1 [m].
        vertices: (N, 8, 3) world-frame vertices [m]: the near face (z0) counter-clockwise
            from (u0, v0) as seen from the camera, then the far face (z1) likewise.
    """

    boxes: ArrayF64
    vertices: ArrayF64

    @classmethod
    def empty(cls) -> PieceSet:
        """No pieces."""
        return cls(np.zeros((0, 7)), np.zeros((0, 8, 3)))

    def __len__(self) -> int:
        return int(self.boxes.shape[0])

    def select(self, mask: np.ndarray) -> PieceSet:
        """The pieces where ``mask`` (N,) is true (or at the given indices)."""
        return PieceSet(self.boxes[mask], self.vertices[mask])

    @staticmethod
    def concat(sets: Sequence[PieceSet]) -> PieceSet:
        """All pieces of ``sets``."""
        sets = [s for s in sets if len(s)]
        if not sets:
            return PieceSet.empty()
        return PieceSet(np.concatenate([s.boxes for s in sets]), np.concatenate([s.vertices for s in sets]))


def piece_vertices(boxes: ArrayF64, stack: CameraStack) -> ArrayF64:
    """(N, 8, 3) world vertices of pieces ``boxes`` (N, 7)."""
    if boxes.shape[0] == 0:
        return np.zeros((0, 8, 3))
    out = np.empty((boxes.shape[0], 8, 3))
    _piece_vertices(np.ascontiguousarray(boxes, dtype=np.float64), stack.intr, stack.R_wc, stack.t_wc, out)
    return out


@nb.njit(cache=True, nogil=True)
def _piece_vertices(boxes, intr, R, t, out):  # pragma: no cover - compiled
    for n in range(boxes.shape[0]):
        c = int(boxes[n, 0])
        fx, fy, cx, cy = intr[c, 0], intr[c, 1], intr[c, 2], intr[c, 3]
        ua, ub = boxes[n, 1] - 0.5, boxes[n, 2] + 0.5
        va, vb = boxes[n, 3] - 0.5, boxes[n, 4] + 0.5
        for half in range(2):
            z = boxes[n, 5 + half]
            for k in range(4):
                u = ua if k == 0 or k == 3 else ub
                v = va if k < 2 else vb
                x = (u - cx) / fx * z
                y = (v - cy) / fy * z
                for i in range(3):
                    out[n, 4 * half + k, i] = R[c, i, 0] * x + R[c, i, 1] * y + R[c, i, 2] * z + t[c, i]


def vertex_bounds(vertices: ArrayF64) -> tuple[ArrayF64, ArrayF64]:
    """(N, 3) minima and (N, 3) maxima of each piece's vertices (N, K, 3): its bounding
    box (compiled: numpy's strided ``min(axis=1)`` costs ~1 ms for 5,000 pieces)."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    n = v.shape[0]
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    if n and v.shape[1]:
        _vertex_bounds(v, lo, hi)
    elif n:
        lo.fill(np.inf)
        hi.fill(-np.inf)
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _vertex_bounds(v, lo, hi):  # pragma: no cover - compiled
    for i in range(v.shape[0]):
        for a in range(3):
            mn = v[i, 0, a]
            mx = mn
            for k in range(1, v.shape[1]):
                x = v[i, k, a]
                mn = min(mn, x)
                mx = max(mx, x)
            lo[i, a] = mn
            hi[i, a] = mx


_MERGE_AXES = (
    # (the columns that must be equal, the low and high column of the merged extent);
    # columns: camera, u0, u1, v0, v1, z0, z1
    ((0, 1, 2, 3, 4), 5, 6),  # depth: z1 of one is z0 of the other
    ((0, 3, 4, 5, 6), 1, 2),  # u: u1 + 1 of one is u0 of the other
    ((0, 1, 2, 5, 6), 3, 4),  # v
)


def merge_adjacent(boxes: ArrayF64) -> ArrayF64:
    """Pieces ``boxes`` (N, 7) with every two of one camera that are adjacent along u, v or
    depth with equal extents along the two others merged into one (their union is that
    one frustum box: the same set, in fewer pieces), until none is left. Carving splits a
    piece in halves that are often both kept whole: a mesh of the union is then built from
    a third as many pieces (drawing, lazy regions)."""
    b = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 7)
    changed = True
    while changed and len(b) > 1:
        changed = False
        for same, lo, hi in _MERGE_AXES:
            order = np.lexsort(tuple(b[:, c] for c in (lo, *reversed(same))))
            a, n = order[:-1], order[1:]
            gap = 1.0 if lo != 5 else 0.0  # whole pixels along u and v, depths meet exactly
            m = np.all(b[a][:, same] == b[n][:, same], axis=1) & (b[a, hi] + gap == b[n, lo])
            if not m.any():
                continue
            # in each run of mergeable neighbours, every other pair (no piece twice a pass)
            k = np.arange(len(m))
            start = np.maximum.accumulate(np.where(m & ~np.concatenate([[False], m[:-1]]), k, 0))
            take = m & ((k - start) % 2 == 0)
            b[a[take], hi] = b[n[take], hi]
            b = np.delete(b, n[take], axis=0)
            changed = True
    return b


def piece_volumes(boxes: ArrayF64, stack: CameraStack) -> ArrayF64:
    """(N,) volumes [m^3] of pieces: ``du dv / (fx fy) * (z1^3 - z0^3) / 3``."""
    if boxes.shape[0] == 0:
        return np.zeros(0)
    c = boxes[:, 0].astype(np.int64)
    du = boxes[:, 2] - boxes[:, 1] + 1.0
    dv = boxes[:, 4] - boxes[:, 3] + 1.0
    return du * dv / (stack.intr[c, 0] * stack.intr[c, 1]) * (boxes[:, 6] ** 3 - boxes[:, 5] ** 3) / 3.0


@nb.njit(cache=True, nogil=True)
def _range(mins, maxs, image, offsets, shapes, nlev, pu0, pu1, pv0, pv1, zlo, zhi):  # pragma: no cover - compiled
    """(min, max) of a pyramid over a superset of pixel box [pu0, pu1] x [pv0, pv1]; level 0
    is the image (at ``offsets[0]`` in ``image``). The caller only asks whether a piece
    spanning depths [zlo, zhi] is covered (``zhi < min``) and maybe freed (``zlo < max``):
    once some row has shown it neither covered nor decided free (``min <= zhi`` and
    ``max > zlo``), the rest cannot change the answers and is not read (the values
    returned then bound the box's true ones by the same answers)."""
    lev = 0
    while lev < nlev - 1 and (((pu1 >> lev) - (pu0 >> lev)) >= 8 or ((pv1 >> lev) - (pv0 >> lev)) >= 8):
        lev += 1
    off = offsets[lev]
    w = shapes[lev, 1]
    lo = np.float32(np.inf)
    hi = np.float32(-np.inf)
    if lev == 0:
        for r in range(pv0, pv1 + 1):
            base = off + r * w
            for c in range(pu0, pu1 + 1):
                x = image[base + c]
                lo = min(lo, x)
                hi = max(hi, x)
            if lo <= zhi and hi > zlo:
                break
        return lo, hi
    for r in range(pv0 >> lev, (pv1 >> lev) + 1):
        base = off + r * w
        for c in range(pu0 >> lev, (pu1 >> lev) + 1):
            lo = min(lo, mins[base + c])
            hi = max(hi, maxs[base + c])
        if lo <= zhi and hi > zlo:
            break
    return lo, hi


@nb.njit(cache=True, nogil=True)
def _vertices(c, u0, u1, v0, v1, z0, z1, R_wc, t_wc, intr, out):  # pragma: no cover - compiled
    fx, fy, cx, cy = intr[c, 0], intr[c, 1], intr[c, 2], intr[c, 3]
    ua, ub, va, vb = u0 - 0.5, u1 + 0.5, v0 - 0.5, v1 + 0.5
    k = 0
    for h in range(2):
        z = z0 if h == 0 else z1
        for j in range(4):
            u = ua if (j == 0 or j == 3) else ub
            v = va if j < 2 else vb
            x = (u - cx) / fx * z
            y = (v - cy) / fy * z
            for a in range(3):
                out[k, a] = R_wc[c, a, 0] * x + R_wc[c, a, 1] * y + R_wc[c, a, 2] * z + t_wc[c, a]
            k += 1


@nb.njit(cache=True, nogil=True)
def _refine(free, end, img_off, W, u0, u1, v0, v1, z0, z1):  # pragma: no cover - compiled
    """Shrink a piece to the pixels and depths of the segments it meets; n = 0 if none."""
    nu0, nu1, nv0, nv1 = u1 + 1, u0 - 1, v1 + 1, v0 - 1
    nz0 = np.inf
    nz1 = -np.inf
    for v in range(v0, v1 + 1):
        base = img_off + v * W
        for u in range(u0, u1 + 1):
            f = np.float64(free[base + u])
            e = np.float64(end[base + u])
            a = max(f, z0)
            b = min(e, z1)
            if a < b:
                nu0 = min(nu0, u)
                nu1 = max(nu1, u)
                nv0 = min(nv0, v)
                nv1 = max(nv1, v)
                nz0 = min(nz0, a)
                nz1 = max(nz1, b)
    if nu1 < nu0:
        return 0, 0, 0, 0, 0, 0.0, 0.0
    return 1, nu0, nu1, nv0, nv1, nz0, nz1


@nb.njit(cache=True, nogil=True)
def _carve(
    init, R_cw, t_cw, R_wc, t_wc, intr, size, near, active,
    mins, maxs, pyr_image, pyr_off, pyr_shape, nlev, free, end, img_off,
    spheres, zlo, zhi, k_of_n, alpha, size_min, size_max, max_pieces, d_offset, sheet_z, sheet_reach,
    m_test, mins2, maxs2, pyr_image2, mins3, maxs3, pyr_image3,
):  # pragma: no cover - compiled
    n_cam = R_cw.shape[0]
    cap = max(64, 4 * init.shape[0])
    stack = np.empty((cap, 7), dtype=np.float64)
    ns = 0
    for i in range(init.shape[0]):
        stack[ns] = init[i]
        ns += 1
    out_cap = max(64, init.shape[0])
    out = np.empty((out_cap, 7), dtype=np.float64)
    no = 0
    verts = np.empty((8, 3), dtype=np.float64)
    halves = np.empty((2, 7), dtype=np.float64)
    overflow = False
    while ns > 0:
        ns -= 1
        c = int(stack[ns, 0])
        u0 = int(stack[ns, 1])
        u1 = int(stack[ns, 2])
        v0 = int(stack[ns, 3])
        v1 = int(stack[ns, 4])
        z0 = stack[ns, 5]
        z1 = stack[ns, 6]
        _vertices(c, u0, u1, v0, v1, z0, z1, R_wc, t_wc, intr, verts)
        # Entirely outside the zone's box: not part of the region.
        outside = False
        for a in range(3):
            all_lo = True
            all_hi = True
            for j in range(8):
                if verts[j, a] >= zlo[a]:
                    all_lo = False
                if verts[j, a] <= zhi[a]:
                    all_hi = False
            if all_lo or all_hi:
                outside = True
        if outside:
            continue
        n_cover = 0
        n_maybe = 0
        # with ``m_test``: the segment ends (2) and the static free depth (3) of M's test
        n_cover2 = 0
        n_maybe2 = 0
        n_cover3 = 1  # the piece's own camera: its segments lie in front of its f_s
        n_maybe3 = 0
        for i in range(n_cam):
            if i == c:
                continue
            if not active[i]:
                n_maybe3 += 1  # no frame now, but it may see the piece free in the empty cell
                continue
            umin, umax, vmin, vmax, zmin, zmax = project_bounds(
                verts, R_cw[i], t_cw[i], intr[i, 0], intr[i, 1], intr[i, 2], intr[i, 3], 1e-9
            )
            if zmax <= near[i]:
                continue  # before i's near plane: nothing free
            if zmin <= 1e-9:
                n_maybe += 1  # crosses i's camera plane: undecided
                n_maybe2 += 1
                n_maybe3 += 1
                continue
            W = size[i, 0]
            H = size[i, 1]
            pu0 = int(np.floor(umin + 0.5 - 1e-6))
            pu1 = int(np.floor(umax + 0.5 + 1e-6))
            pv0 = int(np.floor(vmin + 0.5 - 1e-6))
            pv1 = int(np.floor(vmax + 0.5 + 1e-6))
            if pu1 < 0 or pv1 < 0 or pu0 > W - 1 or pv0 > H - 1:
                continue  # outside i's image: not seen
            inside = pu0 >= 0 and pv0 >= 0 and pu1 <= W - 1 and pv1 <= H - 1
            ru0, ru1, rv0, rv1 = max(pu0, 0), min(pu1, W - 1), max(pv0, 0), min(pv1, H - 1)
            lo, hi = _range(mins, maxs, pyr_image, pyr_off[i], pyr_shape[i], nlev[i], ru0, ru1, rv0, rv1, zmin, zmax)
            if inside and zmin > near[i] and zmax < lo:
                n_cover += 1
                if n_cover >= k_of_n:
                    break  # seen free by enough cameras: dropped whatever the others see
            elif zmin < hi:
                n_maybe += 1
            if m_test:
                lo2, hi2 = _range(mins2, maxs2, pyr_image2, pyr_off[i], pyr_shape[i], nlev[i], ru0, ru1, rv0, rv1, zmin, zmax)
                if inside and zmin > near[i] and zmax < lo2:
                    n_cover2 += 1
                    if n_cover2 >= k_of_n:
                        break  # enough cameras would see it free with the robot: not in M
                elif zmin < hi2:
                    n_maybe2 += 1
                lo3, hi3 = _range(mins3, maxs3, pyr_image3, pyr_off[i], pyr_shape[i], nlev[i], ru0, ru1, rv0, rv1, zmin, zmax)
                if inside and zmin > near[i] and zmax < lo3:
                    n_cover3 += 1
                elif zmin < hi3:
                    n_maybe3 += 1
        if n_cover >= k_of_n:
            continue
        keep = n_cover + n_maybe < k_of_n
        if m_test:
            if n_cover2 >= k_of_n or n_cover3 + n_maybe3 < k_of_n:
                continue  # outside M: free with the robot, or inside C_static (never M)
            # whole only when every point is in M: hidden with the robot, free without
            keep = keep and n_cover2 + n_maybe2 < k_of_n and n_cover3 >= k_of_n
        if not keep:
            # size budget from a lower bound of the distance to the robot
            cxm = 0.0
            cym = 0.0
            czm = 0.0
            for j in range(8):
                cxm += verts[j, 0] / 8.0
                cym += verts[j, 1] / 8.0
                czm += verts[j, 2] / 8.0
            rad = 0.0
            for j in range(8):
                dx = verts[j, 0] - cxm
                dy = verts[j, 1] - cym
                dz = verts[j, 2] - czm
                rad = max(rad, np.sqrt(dx * dx + dy * dy + dz * dz))
            d = np.inf
            for s in range(spheres.shape[0]):
                dx = spheres[s, 0] - cxm
                dy = spheres[s, 1] - cym
                dz = spheres[s, 2] - czm
                d = min(d, np.sqrt(dx * dx + dy * dy + dz * dz) - spheres[s, 3])
            d = max(d - rad - d_offset, 0.0)
            # no robot (d infinite): the largest size
            allowed = size_max if d == np.inf else min(max(alpha * d, size_min), size_max)
            if d < sheet_reach:
                # crossing the top of the floor's noise sheet near the robot: the crossing
                # decides whether the sheet under it is kept, so split it finely
                vz0 = np.inf
                vz1 = -np.inf
                for j in range(8):
                    vz0 = min(vz0, verts[j, 2])
                    vz1 = max(vz1, verts[j, 2])
                if vz0 < sheet_z and vz1 >= sheet_z:
                    allowed = size_min
            ext_z = z1 - z0
            # a single pixel column cannot be split across: only splittable sides count
            # (a budget below a pixel's footprint would otherwise halve the depth forever)
            ext_u = (u1 - u0 + 1) * z1 / intr[c, 0] if u1 > u0 else 0.0
            ext_v = (v1 - v0 + 1) * z1 / intr[c, 1] if v1 > v0 else 0.0
            if ext_z <= 1e-6:
                ext_z = 0.0
            ext = max(ext_z, max(ext_u, ext_v))
            if not ext > allowed or no + ns >= max_pieces:  # (a NaN budget keeps)
                if no + ns >= max_pieces:
                    overflow = True
                keep = True
            else:
                # split along the longest side
                if ext_u >= ext_z and ext_u >= ext_v and u1 > u0:
                    m = (u0 + u1) // 2
                    halves[0, 1], halves[0, 2], halves[0, 3], halves[0, 4] = u0, m, v0, v1
                    halves[1, 1], halves[1, 2], halves[1, 3], halves[1, 4] = m + 1, u1, v0, v1
                    halves[0, 5], halves[0, 6], halves[1, 5], halves[1, 6] = z0, z1, z0, z1
                elif ext_v >= ext_z and v1 > v0:
                    m = (v0 + v1) // 2
                    halves[0, 1], halves[0, 2], halves[0, 3], halves[0, 4] = u0, u1, v0, m
                    halves[1, 1], halves[1, 2], halves[1, 3], halves[1, 4] = u0, u1, m + 1, v1
                    halves[0, 5], halves[0, 6], halves[1, 5], halves[1, 6] = z0, z1, z0, z1
                else:
                    zm = 0.5 * (z0 + z1)
                    halves[0, 1], halves[0, 2], halves[0, 3], halves[0, 4] = u0, u1, v0, v1
                    halves[1, 1], halves[1, 2], halves[1, 3], halves[1, 4] = u0, u1, v0, v1
                    halves[0, 5], halves[0, 6], halves[1, 5], halves[1, 6] = z0, zm, zm, z1
                for h in range(2):
                    ok, a0, a1, b0, b1, c0, c1 = _refine(
                        free, end, img_off[c], size[c, 0],
                        int(halves[h, 1]), int(halves[h, 2]), int(halves[h, 3]), int(halves[h, 4]),
                        halves[h, 5], halves[h, 6],
                    )
                    if ok == 0:
                        continue
                    stack = push_row(stack, ns, (float(c), float(a0), float(a1), float(b0), float(b1), float(c0), float(c1)))
                    ns += 1
        if keep:
            out = push_row(out, no, (float(c), float(u0), float(u1), float(v0), float(v1), float(z0), float(z1)))
            no += 1
    return out[:no], overflow


@dataclass(frozen=True)
class CarveParams:
    """How finely undecided pieces are split.

    Attributes:
        alpha: A piece at distance d [m] from the robot is split down to ``alpha * d``.
        size_min: Smallest piece size [m] (near the robot).
        size_max: Largest piece size [m] (far from the robot).
        max_pieces: Bound on the pieces of one cycle; past it, undecided pieces are kept
            whole (conservative) and the cycle reports it.
    """

    alpha: float = 0.25
    size_min: float = 0.05
    size_max: float = 0.5
    max_pieces: int = 200_000


class PyramidStack(NamedTuple):
    """Every camera's free-depth pyramids in one flat array (built once per cycle).

    Level 0 of camera i's pyramids is its free depth image itself, read from ``image``
    (the :class:`ImageStack` the pyramids were allocated for: build them after the
    images are final, and do not change the images while the pyramids are in use).

    Attributes:
        mins: All cameras' min pyramids (levels 1..), one after the other.
        maxs: The max pyramids, likewise.
        image: The free depth images, flat (:attr:`ImageStack.flat`): level 0.
        offsets: (n, L) where camera i's level l starts in ``mins`` (level 0: in ``image``).
        shapes: (n, L, 2) the (rows, cols) of each level.
        levels: (n,) the levels of each camera (0 without a frame).
    """

    mins: np.ndarray
    maxs: np.ndarray
    image: np.ndarray
    offsets: np.ndarray
    shapes: np.ndarray
    levels: np.ndarray

    @classmethod
    def allocate(cls, free: ImageStack) -> PyramidStack:
        """Room for the pyramids of ``free``'s images (written by :meth:`build_camera`)."""
        n = len(free.offsets)
        layouts = [pyramid_layout(*free.shape(i)) for i in range(n)]
        L = max(len(o) for o, _ in layouts)
        offsets = np.zeros((n, L), dtype=np.int64)
        shapes = np.ones((n, L, 2), dtype=np.int64)
        levels = np.zeros(n, dtype=np.int64)
        base = 0
        for i, (o, shp) in enumerate(layouts):
            offsets[i, : len(o)] = o + base
            offsets[i, 0] = free.offsets[i]
            shapes[i, : len(o)] = shp
            levels[i] = len(o)
            base += int((shp[1:, 0] * shp[1:, 1]).sum())
        mins, maxs = np.empty(base, dtype=np.float32), np.empty(base, dtype=np.float32)
        return cls(mins, maxs, free.flat, offsets, shapes, levels)

    def build_camera(self, i: int) -> None:
        """Write camera ``i``'s pyramids of its free depth image (thread-safe per camera)."""
        views = self._camera(i)
        if views is not None:
            build_pyramid(*views)

    def update_camera(self, i: int, changed: np.ndarray) -> None:
        """Update camera ``i``'s pyramids after its free depth image changed only in the
        ``changed`` blocks (:attr:`polyhull.engine.pixels.PixelBuffers.changed`)."""
        views = self._camera(i)
        if views is not None:
            update_pyramid(*views, changed)

    def _camera(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Camera ``i``'s (image, mins, maxs, level offsets, level shapes), None without
        levels above the image."""
        L = int(self.levels[i])
        if L < 2:
            return None
        shp = self.shapes[i, :L]
        H, W = int(shp[0, 0]), int(shp[0, 1])
        o0 = int(self.offsets[i, 0])
        image = self.image[o0 : o0 + H * W].reshape(H, W)
        start = int(self.offsets[i, 1])
        o = self.offsets[i, :L] - start
        o[0] = 0
        size = int((shp[1:, 0] * shp[1:, 1]).sum())
        return image, self.mins[start : start + size], self.maxs[start : start + size], o, shp

    def only(self, active: np.ndarray) -> PyramidStack:
        """The same pyramids, with the cameras not ``active`` left out (no levels)."""
        return self._replace(levels=np.where(np.asarray(active, dtype=bool), self.levels, 0))

    @classmethod
    def build(cls, free: ImageStack, active: np.ndarray) -> PyramidStack:
        """The pyramids of the active cameras' free depth images."""
        out = cls.allocate(free)
        for i in np.nonzero(active)[0]:
            out.build_camera(int(i))
        return out.only(active)


class MTest(NamedTuple):
    """The pyramids of :func:`carve`'s test for the robot occlusion M."""

    ends: PyramidStack  # the cycle's segment ends: free depth of the empty cell with the padded robot
    static: PyramidStack  # the static free depth f_s


def columns_in_m(
    xy: ArrayF64, heights: ArrayF64, stack: CameraStack, static_free: ImageStack, ends: ImageStack, active: np.ndarray, k_of_n: int
) -> ArrayF64:
    """(C,) the lowest of ``heights`` (H,) [m] at which each vertical column ``xy`` (C, 2)
    lies in the robot's occlusion M (by definition ``M = F_static \\ F_static+robot``, k
    of n), +inf where it does at none. A point is in M when at least k cameras see it free
    in the empty cell (in front of ``static_free``, the static free depth ``f_s``) and
    fewer do with the robot (in front of ``ends``, the cycle's segment ends: the empty
    cell's free depth with the padded robot). Cameras not ``active`` count for neither."""
    out = np.empty(len(xy), dtype=np.float64)
    _columns_in_m(
        np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2), np.ascontiguousarray(heights, dtype=np.float64),
        stack.R_cw, stack.t_cw, stack.intr, stack.size, stack.near, np.asarray(active, dtype=np.bool_),
        static_free.flat, ends.flat, static_free.offsets, int(k_of_n), out,
    )
    return out


@nb.njit(cache=True, nogil=True)
def _columns_in_m(xy, heights, R_cw, t_cw, intr, size, near, active, fs, ends, off, k, out):  # pragma: no cover - compiled
    for c in range(xy.shape[0]):
        out[c] = np.inf
        for h in range(heights.shape[0]):
            n_static = 0
            n_robot = 0
            for i in range(R_cw.shape[0]):
                if not active[i]:
                    continue
                px, py, pz = xy[c, 0], xy[c, 1], heights[h]
                x = R_cw[i, 0, 0] * px + R_cw[i, 0, 1] * py + R_cw[i, 0, 2] * pz + t_cw[i, 0]
                y = R_cw[i, 1, 0] * px + R_cw[i, 1, 1] * py + R_cw[i, 1, 2] * pz + t_cw[i, 1]
                z = R_cw[i, 2, 0] * px + R_cw[i, 2, 1] * py + R_cw[i, 2, 2] * pz + t_cw[i, 2]
                if not z > near[i]:
                    continue
                u = np.floor(intr[i, 0] * x / z + intr[i, 2] + 0.5)
                v = np.floor(intr[i, 1] * y / z + intr[i, 3] + 0.5)
                if not (u >= 0 and u < size[i, 0] and v >= 0 and v < size[i, 1]):
                    continue
                j = off[i] + int(v) * size[i, 0] + int(u)
                if z < fs[j]:
                    n_static += 1
                if z < ends[j]:
                    n_robot += 1
                    if n_robot >= k:
                        break  # k cameras would see it with the robot: not in M
            if n_static >= k and n_robot < k:
                out[c] = heights[h]
                break


class ImageStack:
    """Per-camera images in one flat float32 buffer, each camera's image a view of it.

    The engine writes the cycle's free depth and segment ends straight into these views,
    so carving reads every camera's image without a copy.
    """

    def __init__(self, stack: CameraStack, fill: float | None = 0.0) -> None:
        sizes = stack.size[:, 0] * stack.size[:, 1]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        n = int(sizes.sum())
        # fill None: every image is written before it is read
        self.flat = np.empty(n, dtype=np.float32) if fill is None else np.full(n, fill, dtype=np.float32)
        self._shapes = [(int(h), int(w)) for w, h in stack.size]

    def shape(self, i: int) -> tuple[int, int]:
        """Camera ``i``'s image shape (H, W)."""
        return self._shapes[i]

    def image(self, i: int) -> np.ndarray:
        """Camera ``i``'s (H, W) image (a view of :attr:`flat`)."""
        H, W = self._shapes[i]
        o = int(self.offsets[i])
        return self.flat[o : o + H * W].reshape(H, W)


def carve(
    initial: ArrayF64,
    stack: CameraStack,
    active: np.ndarray,
    pyramids: PyramidStack,
    free: ImageStack,
    end: ImageStack,
    robot_spheres: ArrayF64,
    zone_lo: ArrayF64,
    zone_hi: ArrayF64,
    k_of_n: int,
    params: CarveParams,
    offset: float = 0.0,
    sheet: tuple[float, float] = (0.0, 0.0),
    pool: Executor | None = None,
    m_test: MTest | None = None,
) -> tuple[PieceSet, bool]:
    """Carve the initial pieces (N, 7) by every other active camera's free depth.

    ``offset`` [m] is subtracted from every piece's distance to the robot before its size
    budget is taken: with the distance of the nearest piece, pieces there are split down
    to ``size_min`` (see :mod:`polyhull.engine.refine`). ``sheet = (z, reach)``: a piece
    that crosses the height ``z`` [m] (the top of the floor's noise sheet) within ``reach``
    of that offset is split down to ``size_min`` too.

    ``m_test``: for the shadow memory's pieces, which stand for part of ``C n M``
    (:mod:`polyhull.engine.memory`; by definition ``M = F_static \\ F_static+robot``,
    here with the padded robot): pyramids laid out as ``pyramids`` (the same cameras and
    shapes) of the cycle's segment ends, which are the free depth of the empty cell with
    the padded robot, and of the static free depth ``f_s``. A piece that at least k other
    cameras see wholly in front of their segment ends is outside M (what of it is in C lies
    in those cameras' segments, the other pieces); a piece that fewer than k cameras, its
    own counted, can see in front of ``f_s`` is inside ``C_static``, which M never meets:
    both are dropped. A piece is kept whole only when it is
    decided for M as well; otherwise it is split as any undecided piece.

    With a ``pool`` and enough pieces, the initial pieces are carved in two halves, on
    this thread and one of the pool's (:func:`polyhull.engine.threads.share`; every piece is carved on its own, so the result is the
    same set of pieces; the halves' outputs are concatenated, the first half's first), each
    half with half the piece budget.

    Returns:
        (the kept pieces, True if the piece budget was reached).
    """
    if initial.shape[0] == 0:
        return PieceSet.empty(), False
    initial = np.ascontiguousarray(initial, dtype=np.float64)
    args = (
        stack.R_cw, stack.t_cw, stack.R_wc, stack.t_wc, stack.intr, stack.size, stack.near,
        np.asarray(active, dtype=np.bool_),
        pyramids.mins, pyramids.maxs, pyramids.image, pyramids.offsets, pyramids.shapes, pyramids.levels,
        free.flat, end.flat, free.offsets,
        np.ascontiguousarray(robot_spheres, dtype=np.float64).reshape(-1, 4),
        np.asarray(zone_lo, dtype=np.float64), np.asarray(zone_hi, dtype=np.float64),
        int(k_of_n), float(params.alpha), float(params.size_min), float(params.size_max),
    )
    if m_test is None:  # (the same arrays, unread: one compiled signature)
        m_args = (False, *([pyramids.mins, pyramids.maxs, pyramids.image] * 2))
    else:
        for pyr in m_test:
            if not (np.array_equal(pyr.offsets, pyramids.offsets) and np.array_equal(pyr.shapes, pyramids.shapes)):
                raise ValueError("carve: the pyramids of m_test must be laid out as the free depth pyramids")
        m_args = (True, m_test.ends.mins, m_test.ends.maxs, m_test.ends.image, m_test.static.mins, m_test.static.maxs, m_test.static.image)
    tail = (float(offset), float(sheet[0]), float(sheet[1]), *m_args)
    if pool is None or initial.shape[0] < PARALLEL_MIN:
        boxes, overflow = _carve(initial, *args, int(params.max_pieces), *tail)
        return PieceSet(boxes, piece_vertices(boxes, stack)), bool(overflow)
    budget = max(int(params.max_pieces) // 2, 1)

    def half(part: ArrayF64) -> tuple[ArrayF64, ArrayF64, bool]:
        b, o = _carve(part, *args, budget, *tail)
        return b, piece_vertices(b, stack), bool(o)

    # interleaved halves: neighbouring tiles (similar work) go to both threads; contiguous
    # copies, so that the kernel has one signature (one compiled version to load)
    done = share(pool, half, (np.ascontiguousarray(initial[0::2]), np.ascontiguousarray(initial[1::2])))
    return (
        PieceSet(np.concatenate([d[0] for d in done]), np.concatenate([d[1] for d in done])),
        any(d[2] for d in done),
    )


PARALLEL_MIN = 64
"""Fewest initial pieces that :func:`carve` splits over a pool's threads."""
