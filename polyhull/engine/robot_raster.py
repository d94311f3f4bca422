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

The padded robot's occlusion M (SPEC section 2, with this tolerance) is what these shadows
hide from every camera: the monitor adds the padding to the protective separation distance.
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

__all__ = ["PaddedPieces", "RasterBuffers", "RobotRaster", "rasterize_robot"]


@dataclass(frozen=True, eq=False)
class PaddedPieces:
    """The padded convex robot pieces, as hulls in their link frames.

    Attributes:
        links: Link name of every piece.
        vertices: Hull vertices of every piece in its link frame [m], (K_i, 3) each.
        triangles: Hull triangles of every piece (indices into its vertices), (F_i, 3).
        padding: The padding [m].
    """

    links: tuple[str, ...]
    vertices: tuple[ArrayF64, ...]
    triangles: tuple[np.ndarray, ...]
    padding: float

    @classmethod
    def build(cls, pieces_link: Mapping[str, Sequence[ArrayF64]], padding: float) -> PaddedPieces:
        """Grow every convex piece (link frame) by ``padding`` [m] and take its hull."""
        links, verts, tris = [], [], []
        for name, plist in pieces_link.items():
            for piece in plist:
                grown = grow_piece(np.asarray(piece, dtype=np.float64), padding)
                hull = ConvexHull(grown)
                keep = np.unique(hull.simplices)
                remap = np.full(len(grown), -1, dtype=np.int64)
                remap[keep] = np.arange(len(keep))
                links.append(name)
                verts.append(np.ascontiguousarray(grown[keep]))
                tris.append(np.ascontiguousarray(remap[hull.simplices]))
        return cls(tuple(links), tuple(verts), tuple(tris), float(padding))

    @functools.cached_property
    def all_triangles(self) -> np.ndarray:
        """(F, 3) every piece's triangles, indexing the pieces' vertices stacked in order."""
        offsets = np.cumsum([0] + [len(v) for v in self.vertices])[:-1]
        if not self.triangles:
            return np.zeros((0, 3), dtype=np.int64)
        return np.ascontiguousarray(np.concatenate([t + o for t, o in zip(self.triangles, offsets, strict=True)]))

    def world(self, T_world_links: Mapping[str, ArrayF64]) -> list[ArrayF64]:
        """Hull vertices of every piece in the world frame at the given link poses."""
        out = []
        for name, v in zip(self.links, self.vertices, strict=True):
            T = T_world_links[name]
            out.append(v @ T[:3, :3].T + T[:3, 3])
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
        shadow_start: (H, W) depth where the robot's shadow starts [m] (+inf elsewhere).
        rect: (u0, u1, v0, v1) inclusive pixel rectangle holding every covered pixel, or
            None when the robot covers none.
    """

    covered: np.ndarray
    front: ArrayF32
    back: ArrayF32
    shadow_start: ArrayF32
    rect: tuple[int, int, int, int] | None = None


@nb.njit(cache=True, nogil=True)
def _raster(pc, tris, W, H, near, zbuf, zback, rect):  # pragma: no cover - compiled
    """Rasterise triangles (camera-frame vertices ``pc``) into ``zbuf`` (a lower bound of
    the nearest depth) and ``zback`` (an upper bound of the farthest depth); grow ``rect``
    (u0, u1, v0, v1) to hold every pixel written.

    A pixel's square, grown by one pixel, meets a triangle when it meets each edge's
    inner half-plane; per row that is an interval of u, computed once per row (one pixel
    wider on each side, where the per-pixel test decides, so rounding never drops a
    pixel). Over the square, the triangle's plane ``w = A u + B v + C`` ranges over
    ``w(centre) -/+ r (|A| + |B|)``."""
    grow = 1.0  # dilation [px]
    r = 0.5 + grow
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        z0, z1, z2 = pc[i0, 2], pc[i1, 2], pc[i2, 2]
        if z0 <= 1e-3 or z1 <= 1e-3 or z2 <= 1e-3:
            continue  # behind the camera: left out (the region then reaches the robot: stop)
        u0 = pc[i0, 0] / z0
        v0 = pc[i0, 1] / z0
        u1 = pc[i1, 0] / z1
        v1 = pc[i1, 1] / z1
        u2 = pc[i2, 0] / z2
        v2 = pc[i2, 1] / z2
        w0, w1, w2 = -1.0 / z0, -1.0 / z1, -1.0 / z2
        wmin = min(w0, min(w1, w2))
        wmax = max(w0, max(w1, w2))
        area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
        sgn = 1.0 if area >= 0 else -1.0
        # Plane w = A u + B v + C (degenerate: the nearest vertex everywhere).
        planar = abs(area) > 1e-12
        A = 0.0
        Bc = 0.0
        C = wmin
        if planar:
            A = ((w1 - w0) * (v2 - v0) - (w2 - w0) * (v1 - v0)) / area
            Bc = ((u1 - u0) * (w2 - w0) - (u2 - u0) * (w1 - w0)) / area
            C = w0 - A * u0 - Bc * v0
        spread = r * (abs(A) + abs(Bc))
        umin = min(u0, min(u1, u2)) - grow - 0.5
        umax = max(u0, max(u1, u2)) + grow + 0.5
        vmin = min(v0, min(v1, v2)) - grow - 0.5
        vmax = max(v0, max(v1, v2)) + grow + 0.5
        if umax < -0.5 or vmax < -0.5 or umin > W - 0.5 or vmin > H - 0.5:
            continue
        pu0 = max(int(np.floor(umin + 0.5)), 0)
        pu1 = min(int(np.floor(umax + 0.5)), W - 1)
        pv0 = max(int(np.floor(vmin + 0.5)), 0)
        pv1 = min(int(np.floor(vmax + 0.5)), H - 1)
        # inward edge normals and offsets: val = nx u + ny v + k >= 0 inside (grown)
        n0x = -(v1 - v0) * sgn
        n0y = (u1 - u0) * sgn
        n1x = -(v2 - v1) * sgn
        n1y = (u2 - u1) * sgn
        n2x = -(v0 - v2) * sgn
        n2y = (u0 - u2) * sgn
        # the edge tests use r + 1e-6 px: a square that touches an edge meets the
        # triangle whatever the rounding
        re = r + 1e-6
        k0 = -n0x * u0 - n0y * v0 + re * (abs(n0x) + abs(n0y))
        k1 = -n1x * u1 - n1y * v1 + re * (abs(n1x) + abs(n1y))
        k2 = -n2x * u2 - n2y * v2 + re * (abs(n2x) + abs(n2y))
        for v in range(pv0, pv1 + 1):
            a = float(pu0)
            b = float(pu1)
            if planar:
                # the row's interval from the three half-planes
                for e in range(3):
                    if e == 0:
                        nx, c = n0x, n0y * v + k0
                    elif e == 1:
                        nx, c = n1x, n1y * v + k1
                    else:
                        nx, c = n2x, n2y * v + k2
                    if nx > 0.0:
                        a = max(a, np.floor(-c / nx) - 1.0)
                    elif nx < 0.0:
                        b = min(b, np.ceil(-c / nx) + 1.0)
                    elif c < 0.0:
                        b = a - 1.0
                if not a <= b:  # (NaN-safe)
                    continue
            for u in range(int(a), int(b) + 1):
                if planar:
                    if n0x * u + n0y * v + k0 < 0.0 or n1x * u + n1y * v + k1 < 0.0 or n2x * u + n2y * v + k2 < 0.0:
                        continue
                    wc = A * u + Bc * v + C
                    wb = max(wc - spread, wmin)
                    wf = min(wc + spread, wmax)
                else:
                    wb = wmin
                    wf = wmax
                if wb >= 0.0:
                    continue
                z = -1.0 / wb
                z = max(z, near)
                if z < zbuf[v, u]:
                    zbuf[v, u] = z
                zf = -1.0 / wf if wf < 0.0 else np.inf
                if zf > zback[v, u]:
                    zback[v, u] = zf
                if u < rect[0]:
                    rect[0] = u
                if u > rect[1]:
                    rect[1] = u
                if v < rect[2]:
                    rect[2] = v
                if v > rect[3]:
                    rect[3] = v


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

    def take(self) -> tuple[np.ndarray, ArrayF32, ArrayF32, ArrayF32]:
        """The images, reset to "not covered"."""
        if self._rect is not None:
            u0, u1, v0, v1 = self._rect
            covered, front, back, start = self._images
            covered[v0 : v1 + 1, u0 : u1 + 1] = False
            front[v0 : v1 + 1, u0 : u1 + 1] = np.inf
            back[v0 : v1 + 1, u0 : u1 + 1] = -np.inf
            start[v0 : v1 + 1, u0 : u1 + 1] = np.inf
            self._rect = None
        return self._images

    def written(self, rect: tuple[int, int, int, int] | None) -> None:
        """Record the rectangle the images were written in."""
        self._rect = rect


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
            _raster(pix, pieces.all_triangles, W, H, float(camera.near), buffers.zbuf, buffers.zback, rect)
        covered, front, back, start = buffers.take()
        box: tuple[int, int, int, int] | None = None
        if rect[1] >= rect[0]:
            box = (int(rect[0]), int(rect[1]), int(rect[2]), int(rect[3]))
            _finish(
                buffers.zbuf, buffers.zback, box[0], box[1], box[2], box[3], float(camera.near),
                float(camera.tolerance_sigmas * camera.noise), float(camera.tolerance_min),
                float(pieces.padding), covered, front, back, start,
            )
        buffers.written(box)
    except BaseException:
        # never leave a depth buffer half written for the next raster (a nearer front
        # would explain more readings by the robot)
        buffers.zbuf.fill(np.inf)
        buffers.zback.fill(-np.inf)
        buffers.written((0, W - 1, 0, H - 1))
        raise
    return RobotRaster(covered, front, back, start, box)


@nb.njit(cache=True, nogil=True)
def _finish(zbuf, zback, u0, u1, v0, v1, near, a, tmin, padding, covered, front, back, start):  # pragma: no cover - compiled
    """float32 images, rounded outward, and the shadow start ``front - max(0, 2 tau - pad)``,
    over the rectangle ``[u0, u1] x [v0, v1]``; the depth buffers are reset there."""
    ninf = np.float32(-np.inf)
    pinf = np.float32(np.inf)
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            z = zbuf[v, u]
            if z == np.inf:
                continue
            zb = zback[v, u]
            zbuf[v, u] = np.inf
            zback[v, u] = -np.inf
            covered[v, u] = True
            f = np.float32(z)
            if f > z:
                f = np.nextafter(f, ninf)
            front[v, u] = f
            b = np.float32(zb)
            if b < zb:
                b = np.nextafter(b, pinf)
            back[v, u] = b
            tau = max(a * z * z, tmin)
            s = max(z - max(0.0, 2.0 * tau - padding), near)
            s32 = np.float32(s)
            if s32 > s:
                s32 = np.nextafter(s32, ninf)
            start[v, u] = s32
