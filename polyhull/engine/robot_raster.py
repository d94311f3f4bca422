"""The padded robot in every camera's image: which pixels it covers, and where its shadow starts.

The robot's convex collision pieces are grown by ``robot.padding`` (Minkowski sum with a
cube, :func:`polyhull.occlusion.grow_piece`), their convex hulls are computed once in the
link frames, and every cycle their triangles are rasterised into each camera:

- a pixel is **covered** when its square, grown by one pixel (flying pixels at the robot's
  silhouette), overlaps a triangle's projection;
- its **front** depth is a lower bound of the triangle's depth over that square: the
  triangle's plane is linear in ``w = -1/z`` over the image, so its minimum over the square
  is at a corner, and the triangle is nowhere nearer than its nearest vertex; the larger of
  the two bounds is taken, then the smallest over the triangles;
- the **shadow start** is ``S = front - max(0, 2 tau(front) - padding)``: a reading of the
  robot's surface lies at least ``padding`` behind the padded front and at most ``tau``
  before the surface, and frees up to ``tau`` before the reading, so its free depth is at
  least ``S`` and the pixel is explained by the robot.

The padded robot's occlusion M (``M = F_static \\ F_static+robot``, with this tolerance) is
what these shadows hide from every camera: the monitor adds the padding to the protective
separation distance.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.spatial import ConvexHull

from ..camera import Camera
from ..occlusion import grow_piece
from ..typed import ArrayF32, ArrayF64
from .rounding import down32, up32

__all__ = ["PaddedPieces", "RasterBuffers", "RobotRaster", "rasterize_robot"]


@dataclass(frozen=True, eq=False)
class PaddedPieces:
    """The padded convex robot pieces, as hulls in their link frames.

    Attributes:
        links: Link name of every piece.
        vertices: Hull vertices of every piece in its link frame [m], (K_i, 3) each.
        faces: Hull faces of every piece as convex polygons (the hull's coplanar triangles
            merged), (F_i, P) vertex indices counter-clockwise seen from outside, padded
            with -1 after each face's last vertex.
        padding: The padding [m].
    """

    links: tuple[str, ...]
    vertices: tuple[ArrayF64, ...]
    faces: tuple[np.ndarray, ...]
    padding: float

    @classmethod
    def build(cls, pieces_link: Mapping[str, Sequence[ArrayF64]], padding: float) -> PaddedPieces:
        """Grow every convex piece (link frame) by ``padding`` [m] and take its hull."""
        links, verts, faces = [], [], []
        for name, plist in pieces_link.items():
            for piece in plist:
                grown = grow_piece(np.asarray(piece, dtype=np.float64), padding)
                hull = ConvexHull(grown)
                keep = np.unique(hull.simplices)
                remap = np.full(len(grown), -1, dtype=np.int64)
                remap[keep] = np.arange(len(keep))
                v = np.ascontiguousarray(grown[keep])
                links.append(name)
                verts.append(v)
                faces.append(_polygons(v, remap[hull.simplices], hull.equations))
        return cls(tuple(links), tuple(verts), tuple(faces), float(padding))

    @functools.cached_property
    def all_faces(self) -> np.ndarray:
        """(F, P) every piece's faces, indexing the pieces' vertices stacked in order
        (-1 pads)."""
        if not self.faces:
            return np.zeros((0, 3), dtype=np.int64)
        P = max(f.shape[1] for f in self.faces)
        offsets = np.cumsum([0] + [len(v) for v in self.vertices])[:-1]
        out = []
        for f, o in zip(self.faces, offsets, strict=True):
            g = np.full((len(f), P), -1, dtype=np.int64)
            g[:, : f.shape[1]] = np.where(f >= 0, f + o, -1)
            out.append(g)
        return np.ascontiguousarray(np.concatenate(out))

    def world(self, T_world_links: Mapping[str, ArrayF64]) -> list[ArrayF64]:
        """Hull vertices of every piece in the world frame at the given link poses."""
        out = []
        for name, v in zip(self.links, self.vertices, strict=True):
            T = T_world_links[name]
            out.append(v @ T[:3, :3].T + T[:3, 3])
        return out


COPLANAR = 1e-9
"""Edge-adjacent hull triangles whose planes (unit normal and offset [m]) agree within
this are merged into one face. A face is the convex hull of its triangles' vertices on
the plane; the raster bounds its depth with the plane through three of its vertices plus
the other vertices' deviation from it."""


def _polygons(vertices: ArrayF64, simplices: np.ndarray, equations: ArrayF64) -> np.ndarray:
    """Convex polygons (F, P) of a hull's coplanar triangles (see :class:`PaddedPieces`)."""
    n_tri = len(simplices)
    parent = np.arange(n_tri)

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = int(parent[i])
        return i

    edges: dict[tuple[int, int], int] = {}
    for t, tri in enumerate(simplices):
        for k in range(3):
            e = (int(min(tri[k], tri[(k + 1) % 3])), int(max(tri[k], tri[(k + 1) % 3])))
            o = edges.setdefault(e, t)
            if o != t and np.abs(equations[o] - equations[t]).max() <= COPLANAR:
                parent[find(t)] = find(o)
    roots = np.array([find(t) for t in range(n_tri)])
    polys = []
    for g in np.unique(roots):
        sel = roots == g
        idx = np.unique(simplices[sel])
        n = equations[sel][0, :3]
        a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)  # (a, b, n) right-handed: counter-clockwise in (a, b) is about n
        d = vertices[idx] - vertices[idx].mean(axis=0)
        xy = np.column_stack([d @ a, d @ b])
        ring = idx if len(idx) == 3 else idx[ConvexHull(xy).vertices]  # counter-clockwise (2-D)
        e1, e2 = xy[1] - xy[0], xy[2] - xy[0]
        if len(ring) == 3 and e1[0] * e2[1] - e1[1] * e2[0] < 0:
            ring = ring[::-1]
        polys.append(ring)
    P = max(len(q) for q in polys)
    out = np.full((len(polys), P), -1, dtype=np.int64)
    for i, q in enumerate(polys):
        out[i, : len(q)] = q
    return out


@dataclass(frozen=True, eq=False)
class RobotRaster:
    """The padded robot in one camera's image.

    Attributes:
        covered: (H, W) pixels the padded robot (grown by one pixel) covers.
        front: (H, W) lower bound of the padded robot's depth over each covered pixel [m]
            (+inf elsewhere).
        back: (H, W) upper bound of the padded robot's farthest depth over each covered
            pixel [m] (-inf elsewhere): behind it, the pixel's ray has left the robot.
        shadow_start: (H, W) depth where the robot's shadow starts [m] (+inf elsewhere):
            for a depth camera just before the padded robot's front (the depth tolerance
            band), for a colour camera ``near`` (binary depth: a pixel the robot changes
            frees nothing, so in the empty cell with the robot its whole ray is hidden).
        rect: (u0, u1, v0, v1) inclusive bounding rectangle of the covered pixels, or
            None when the robot covers none.
        back_min: The least ``back`` over the covered pixels [m] (+inf when none).
    """

    covered: np.ndarray
    front: ArrayF32
    back: ArrayF32
    shadow_start: ArrayF32
    rect: tuple[int, int, int, int] | None = None
    back_min: float = float("inf")


@nb.njit(cache=True, nogil=True)
def _raster(pc, faces, W, H, near, zbuf, zback, rect):  # pragma: no cover - compiled
    """Rasterise convex polygon faces (``faces`` (F, P) indices into the camera-frame,
    pre-scaled vertices ``pc``, -1 padded) into ``zbuf`` (a lower bound of the nearest
    depth) and ``zback`` (an upper bound of the farthest depth), both stored as ``w = -1/z``
    (monotonic in z: :func:`_finish` divides once a pixel, not once a face and pixel);
    grow ``rect`` (u0, u1, v0, v1) to hold every pixel written.

    A ray through a convex piece enters through a face turned towards the camera and
    leaves through one turned away, so front faces write only ``zbuf`` and back faces only
    ``zback`` (faces seen edge-on write both; when some vertex is behind the camera, every
    face writes both). A pixel's square, grown by one pixel, meets a face when it meets
    each edge's inner half-plane; per row that is an interval of u, computed once per row
    (one pixel wider on each side, where the per-pixel test decides, so rounding never
    drops a pixel). Over the square, the face's plane ``w = A u + B v + C`` (through its
    widest fan triangle, ``w = -1/z``) ranges over ``w(centre) -/+ r (|A| + |B|)``, widened by
    the face's vertices' largest deviation from that plane."""
    grow = 1.0  # dilation [px]
    r = 0.5 + grow
    re = r + 1e-6  # the edge tests: a square that touches an edge meets the face
    P = faces.shape[1]
    both_all = False
    for i in range(pc.shape[0]):
        if pc[i, 2] <= 1e-3:
            both_all = True
    us = np.empty(P)
    vs = np.empty(P)
    ws = np.empty(P)
    nx = np.empty(P)
    ny = np.empty(P)
    kk = np.empty(P)
    for f in range(faces.shape[0]):
        m = 0
        behind = False
        while m < P and faces[f, m] >= 0:
            z = pc[faces[f, m], 2]
            if z <= 1e-3:
                behind = True
            m += 1
        if behind or m < 3:
            continue  # behind the camera: left out (the region then reaches the robot: stop)
        wmin = np.inf
        wmax = -np.inf
        for j in range(m):
            q = faces[f, j]
            z = pc[q, 2]
            us[j] = pc[q, 0] / z
            vs[j] = pc[q, 1] / z
            ws[j] = -1.0 / z
            wmin = min(wmin, ws[j])
            wmax = max(wmax, ws[j])
        # facing: the sign of the fan's triple products (camera at the origin)
        q0 = faces[f, 0]
        x0, y0, z0 = pc[q0, 0], pc[q0, 1], pc[q0, 2]
        trip = 0.0
        scale = 0.0
        area = 0.0
        best = 0.0
        jb = 1
        for j in range(1, m - 1):
            qa, qb = faces[f, j], faces[f, j + 1]
            xa, ya, za = pc[qa, 0], pc[qa, 1], pc[qa, 2]
            xb, yb, zb = pc[qb, 0], pc[qb, 1], pc[qb, 2]
            t = x0 * (ya * zb - za * yb) - y0 * (xa * zb - za * xb) + z0 * (xa * yb - ya * xb)
            trip += t
            scale += abs(t)
            ar = (us[j] - us[0]) * (vs[j + 1] - vs[0]) - (us[j + 1] - us[0]) * (vs[j] - vs[0])
            area += ar
            if abs(ar) > best:
                best = abs(ar)
                jb = j
        mode = 0  # 0 both, 1 front (zbuf), 2 back (zback)
        if not both_all and abs(trip) > 1e-9 * scale:
            mode = 1 if trip < 0.0 else 2
        sgn = 1.0 if area >= 0.0 else -1.0
        # plane w = A u + B v + C (degenerate: the nearest / farthest vertex everywhere)
        planar = best > 1e-12
        A = 0.0
        Bc = 0.0
        C = wmin
        dev = 0.0
        if planar:
            u0, v0, w0 = us[0], vs[0], ws[0]
            u1, v1, w1 = us[jb], vs[jb], ws[jb]
            u2, v2, w2 = us[jb + 1], vs[jb + 1], ws[jb + 1]
            ar = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
            A = ((w1 - w0) * (v2 - v0) - (w2 - w0) * (v1 - v0)) / ar
            Bc = ((u1 - u0) * (w2 - w0) - (u2 - u0) * (w1 - w0)) / ar
            C = w0 - A * u0 - Bc * v0
            for j in range(m):
                dev = max(dev, abs(ws[j] - (A * us[j] + Bc * vs[j] + C)))
        spread = r * (abs(A) + abs(Bc)) + dev
        umin = np.inf
        umax = -np.inf
        vmin = np.inf
        vmax = -np.inf
        for j in range(m):
            umin = min(umin, us[j])
            umax = max(umax, us[j])
            vmin = min(vmin, vs[j])
            vmax = max(vmax, vs[j])
        umin -= grow + 0.5
        umax += grow + 0.5
        vmin -= grow + 0.5
        vmax += grow + 0.5
        if umax < -0.5 or vmax < -0.5 or umin > W - 0.5 or vmin > H - 0.5:
            continue
        pu0 = max(int(np.floor(umin + 0.5)), 0)
        pu1 = min(int(np.floor(umax + 0.5)), W - 1)
        pv0 = max(int(np.floor(vmin + 0.5)), 0)
        pv1 = min(int(np.floor(vmax + 0.5)), H - 1)
        # inward edge normals and offsets: val = nx u + ny v + k >= 0 inside (grown);
        # a zero-length edge (repeated vertex) tests nothing
        for j in range(m):
            jn = j + 1 if j + 1 < m else 0
            nx[j] = -(vs[jn] - vs[j]) * sgn
            ny[j] = (us[jn] - us[j]) * sgn
            kk[j] = -nx[j] * us[j] - ny[j] * vs[j] + re * (abs(nx[j]) + abs(ny[j]))
        for v in range(pv0, pv1 + 1):
            lo = W
            hi = -1
            if not planar:
                # the nearest and farthest vertex everywhere (wmin < 0: no vertex behind)
                if mode != 2:
                    _row_min_const(zbuf[v], pu0, pu1, wmin)
                if mode != 1:
                    _row_max_const(zback[v], pu0, pu1, wmax)
                lo, hi = pu0, pu1
            else:
                # the row's pixels: those passing every edge's test, an interval of u per
                # edge (the test is monotonic in u, also in floating point); each bound is
                # found from the threshold and moved until the test itself agrees
                a = pu0
                b = pu1
                for j in range(m):
                    if nx[j] > 0.0:
                        a = max(a, _first_in(nx[j], ny[j], kk[j], v, pu0, pu1))
                    elif nx[j] < 0.0:
                        b = min(b, _last_in(nx[j], ny[j], kk[j], v, pu0, pu1))
                    elif ny[j] * v + kk[j] < 0.0 or not ny[j] * v + kk[j] >= 0.0:
                        b = a - 1
                if a > b:
                    continue
                Bv = Bc * v
                # branch-free (vectorised) spans; wb < 0 (written) over an interval of u,
                # as wb - wmin is monotonic in u
                if mode != 2:
                    _row_min(zbuf[v], a, b, A, Bv, C, spread, wmin)
                if mode != 1:
                    _row_max(zback[v], a, b, A, Bv, C, spread, wmin, wmax)
                for u in range(a, b + 1):
                    if max(A * u + Bv + C - spread, wmin) < 0.0:
                        lo = u
                        break
                for u in range(b, a - 1, -1):
                    if max(A * u + Bv + C - spread, wmin) < 0.0:
                        hi = u
                        break
            if hi >= 0:
                if lo < rect[0]:
                    rect[0] = lo
                if hi > rect[1]:
                    rect[1] = hi
                if v < rect[2]:
                    rect[2] = v
                if v > rect[3]:
                    rect[3] = v


@nb.njit(cache=True, nogil=True, inline="always")
def _first_in(nx, ny, k, v, u0, u1):  # pragma: no cover - compiled
    """The least u in [u0, u1 + 1] with ``nx u + ny v + k >= 0`` (nx > 0; u1 + 1: none;
    NaN: none)."""
    t = -(ny * v + k) / nx
    if not t == t:
        return u1 + 1
    u = int(min(max(np.ceil(t), u0), u1 + 1))
    while u > u0 and nx * (u - 1) + ny * v + k >= 0.0:
        u -= 1
    while u <= u1 and not nx * u + ny * v + k >= 0.0:
        u += 1
    return u


@nb.njit(cache=True, nogil=True, inline="always")
def _last_in(nx, ny, k, v, u0, u1):  # pragma: no cover - compiled
    """The greatest u in [u0 - 1, u1] with ``nx u + ny v + k >= 0`` (nx < 0; u0 - 1: none;
    NaN: none)."""
    t = -(ny * v + k) / nx
    if not t == t:
        return u0 - 1
    u = int(min(max(np.floor(t), u0 - 1), u1))
    while u < u1 and nx * (u + 1) + ny * v + k >= 0.0:
        u += 1
    while u >= u0 and not nx * u + ny * v + k >= 0.0:
        u -= 1
    return u


@nb.njit(cache=True, nogil=True, inline="always")
def _row_min(row, a, b, A, Bv, C, spread, wmin):  # pragma: no cover - compiled
    """``row[u] = min(row[u], wb(u))`` for u in [a, b] where ``wb < 0``."""
    for u in range(a, b + 1):
        wb = max(A * u + Bv + C - spread, wmin)
        x = wb if wb < 0.0 else np.inf
        row[u] = min(row[u], x)


@nb.njit(cache=True, nogil=True, inline="always")
def _row_max(row, a, b, A, Bv, C, spread, wmin, wmax):  # pragma: no cover - compiled
    """``row[u] = max(row[u], wf(u))`` for u in [a, b] where ``wb < 0``."""
    for u in range(a, b + 1):
        wc = A * u + Bv + C
        wb = max(wc - spread, wmin)
        wf = min(wc + spread, wmax)
        x = wf if wb < 0.0 else -np.inf
        row[u] = max(row[u], x)


@nb.njit(cache=True, nogil=True, inline="always")
def _row_min_const(row, a, b, x):  # pragma: no cover - compiled
    for u in range(a, b + 1):
        row[u] = min(row[u], x)


@nb.njit(cache=True, nogil=True, inline="always")
def _row_max_const(row, a, b, x):  # pragma: no cover - compiled
    for u in range(a, b + 1):
        row[u] = max(row[u], x)


class RasterBuffers:
    """One camera's images for :func:`rasterize_robot`, reused from cycle to cycle.

    The depth buffers are reset after each use, only where they were written; the output
    images are reset where the last raster wrote them, so a raster built into them is
    valid until the next one (the monitor keeps one set per leased cycle).
    """

    def __init__(self, shape: tuple[int, int], scratch: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Images of ``shape`` (H, W); ``scratch`` are depth buffers (float64, +inf and
        -inf) to share with other sets of the same camera (they are left reset)."""
        H, W = shape
        if scratch is None:
            scratch = (np.full((H, W), np.inf, dtype=np.float64), np.full((H, W), -np.inf, dtype=np.float64))
        self.zbuf, self.zback = scratch
        self._images = _empty_images(H, W)
        self._rect: tuple[int, int, int, int] | None = None
        # an empty reset: the kernel is compiled (or loaded) here, when the buffers are
        # made, not in the first cycle that reuses them
        _reset(*self._images, 0, -1, 0, -1)

    def take(self) -> tuple[np.ndarray, ArrayF32, ArrayF32, ArrayF32]:
        """The images, reset to "not covered"."""
        if self._rect is not None:
            u0, u1, v0, v1 = self._rect
            _reset(*self._images, int(u0), int(u1), int(v0), int(v1))
            self._rect = None
        return self._images

    def written(self, rect: tuple[int, int, int, int] | None) -> None:
        """Record the rectangle the images were written in."""
        self._rect = rect


@nb.njit(cache=True, nogil=True)
def _reset(covered, front, back, start, u0, u1, v0, v1):  # pragma: no cover - compiled
    """Reset the covered pixels of ``[u0, u1] x [v0, v1]`` to "not covered" (the images
    are written only there: about half of the rectangle)."""
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            if covered[v, u]:
                covered[v, u] = False
                front[v, u] = np.inf
                back[v, u] = -np.inf
                start[v, u] = np.inf


def _empty_images(H: int, W: int) -> tuple[np.ndarray, ArrayF32, ArrayF32, ArrayF32]:
    return (
        np.zeros((H, W), dtype=np.bool_),
        np.full((H, W), np.inf, dtype=np.float32),
        np.full((H, W), -np.inf, dtype=np.float32),
        np.full((H, W), np.inf, dtype=np.float32),
    )


def rasterize_robot(
    camera: Camera,
    pieces_world: Sequence[ArrayF64],
    pieces: PaddedPieces,
    buffers: RasterBuffers | None = None,
) -> RobotRaster:
    """The padded robot at the given world-frame hull vertices, in ``camera``'s image.

    With ``buffers`` (one camera's, reused) only the robot's rectangle of the images is
    written; the raster returned lives in them until they are used again."""
    H, W = camera.shape
    k = camera.intrinsics
    if buffers is None:
        buffers = RasterBuffers((H, W))
    rect = np.array([W, -1, H, -1], dtype=np.int64)
    try:
        if len(pieces_world):
            # every piece in one call: the triangles index the stacked vertices
            pc = camera.world_to_camera(np.concatenate(pieces_world))
            # Pixel coordinates are (fx x + cx z) / z: pre-scale so the kernel divides once.
            pix = np.column_stack([k.fx * pc[:, 0] + k.cx * pc[:, 2], k.fy * pc[:, 1] + k.cy * pc[:, 2], pc[:, 2]])
            _raster(pix, pieces.all_faces, W, H, float(camera.near), buffers.zbuf, buffers.zback, rect)
        covered, front, back, start = buffers.take()
        box: tuple[int, int, int, int] | None = None
        back_min = np.inf
        if rect[1] >= rect[0]:
            out = np.array([W, -1, H, -1], dtype=np.int64)  # the covered pixels' rectangle
            back_min = _finish(
                buffers.zbuf, buffers.zback, int(rect[0]), int(rect[1]), int(rect[2]), int(rect[3]),
                float(camera.near), float(camera.tolerance_sigmas * camera.noise), float(camera.tolerance_min),
                float(pieces.padding), camera.kind == "color", covered, front, back, start, out,
            )
            if out[1] >= out[0]:
                box = (int(out[0]), int(out[1]), int(out[2]), int(out[3]))
        buffers.written(box)
    except BaseException:
        # never leave a depth buffer half written for the next raster (a nearer front
        # would explain more readings by the robot)
        buffers.zbuf.fill(np.inf)
        buffers.zback.fill(-np.inf)
        buffers.written((0, W - 1, 0, H - 1))
        raise
    return RobotRaster(covered, front, back, start, box, float(back_min))


@nb.njit(cache=True, nogil=True)
def _finish(zbuf, zback, u0, u1, v0, v1, near, a, tmin, padding, binary, covered, front, back, start, out):  # pragma: no cover - compiled
    """float32 images, rounded outward, and the shadow start ``front - max(0, 2 tau - pad)``
    (``near`` for a ``binary``-depth camera: its whole ray is hidden), over the rectangle
    ``[u0, u1] x [v0, v1]``; the depth buffers are reset there. Grows ``out`` (u0, u1, v0,
    v1) to the covered pixels' rectangle; returns their least back depth.

    A pixel is covered when both a front and a back face wrote it: a ray through its grown
    square that meets a piece enters through a front face and leaves through a back face,
    whose (superset) half-plane tests both pass, so only pixels no ray hits are left out
    (the per-edge tests pass a few of those near a face's sharp corners)."""
    back_min = np.float32(np.inf)
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            wn = zbuf[v, u]
            wx = zback[v, u]
            if wn == np.inf:
                if wx != -np.inf:
                    zback[v, u] = -np.inf
                continue
            zbuf[v, u] = np.inf
            if wx == -np.inf:
                continue
            zback[v, u] = -np.inf
            z = max(-1.0 / wn, near)
            zb = -1.0 / wx if wx < 0.0 else np.inf
            covered[v, u] = True
            front[v, u] = down32(z)
            b32 = up32(zb)
            back[v, u] = b32
            back_min = min(back_min, b32)
            out[0] = min(out[0], u)
            out[1] = max(out[1], u)
            out[2] = min(out[2], v)
            out[3] = max(out[3], v)
            if binary:
                start[v, u] = down32(near)
            else:
                tau = max(a * z * z, tmin)
                s = max(z - max(0.0, 2.0 * tau - padding), near)
                start[v, u] = down32(s)
    return back_min

