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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.spatial import ConvexHull

from ..camera import Camera
from ..occlusion import grow_piece
from ..typed import ArrayF32, ArrayF64

__all__ = ["PaddedPieces", "RobotRaster", "rasterize_robot"]


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
    """

    covered: np.ndarray
    front: ArrayF32
    back: ArrayF32
    shadow_start: ArrayF32


@nb.njit(cache=True, nogil=True)
def _raster(pc, tris, W, H, near, zbuf, zback):  # pragma: no cover - compiled
    """Rasterise triangles (camera-frame vertices ``pc``) into ``zbuf`` (a lower bound of
    the nearest depth) and ``zback`` (an upper bound of the farthest depth)."""
    grow = 1.0  # dilation [px]
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
        # Edge functions with inward normals.
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
        r = 0.5 + grow
        for v in range(pv0, pv1 + 1):
            for u in range(pu0, pu1 + 1):
                if planar:
                    inside = True
                    for e in range(3):
                        if e == 0:
                            ax, ay, bx, by = u0, v0, u1, v1
                        elif e == 1:
                            ax, ay, bx, by = u1, v1, u2, v2
                        else:
                            ax, ay, bx, by = u2, v2, u0, v0
                        nx = -(by - ay) * sgn
                        ny = (bx - ax) * sgn
                        val = nx * (u - ax) + ny * (v - ay) + r * (abs(nx) + abs(ny))
                        if val < 0.0:
                            inside = False
                            break
                    if not inside:
                        continue
                    wc = min(
                        min(A * (u - r) + Bc * (v - r), A * (u + r) + Bc * (v - r)),
                        min(A * (u - r) + Bc * (v + r), A * (u + r) + Bc * (v + r)),
                    ) + C
                    wb = max(wc, wmin)
                    wx = max(
                        max(A * (u - r) + Bc * (v - r), A * (u + r) + Bc * (v - r)),
                        max(A * (u - r) + Bc * (v + r), A * (u + r) + Bc * (v + r)),
                    ) + C
                    wf = min(wx, wmax)
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


def rasterize_robot(
    camera: Camera, pieces_world: Sequence[ArrayF64], pieces: PaddedPieces
) -> RobotRaster:
    """The padded robot at the given world-frame hull vertices, in ``camera``'s image."""
    H, W = camera.shape
    k = camera.intrinsics
    zbuf = np.full((H, W), np.inf, dtype=np.float64)
    zback = np.full((H, W), -np.inf, dtype=np.float64)
    for verts, tris in zip(pieces_world, pieces.triangles, strict=True):
        pc = camera.world_to_camera(verts)
        # Pixel coordinates are (fx x + cx z) / z: pre-scale so the kernel divides once.
        pix = np.column_stack([k.fx * pc[:, 0] + k.cx * pc[:, 2], k.fy * pc[:, 1] + k.cy * pc[:, 2], pc[:, 2]])
        _raster(pix, tris, W, H, float(camera.near), zbuf, zback)
    covered = np.zeros((H, W), dtype=np.bool_)
    front = np.empty((H, W), dtype=np.float32)
    back = np.empty((H, W), dtype=np.float32)
    start = np.empty((H, W), dtype=np.float32)
    _finish(
        zbuf, zback, float(camera.near), float(camera.tolerance_sigmas * camera.noise),
        float(camera.tolerance_min), float(pieces.padding), covered, front, back, start,
    )
    return RobotRaster(covered, front, back, start)


@nb.njit(cache=True, nogil=True)
def _finish(zbuf, zback, near, a, tmin, padding, covered, front, back, start):  # pragma: no cover - compiled
    """float32 images, rounded outward, and the shadow start ``front - max(0, 2 tau - pad)``."""
    H, W = zbuf.shape
    ninf = np.float32(-np.inf)
    pinf = np.float32(np.inf)
    for v in range(H):
        for u in range(W):
            z = zbuf[v, u]
            if z == np.inf:
                covered[v, u] = False
                front[v, u] = pinf
                back[v, u] = ninf
                start[v, u] = pinf
                continue
            covered[v, u] = True
            f = np.float32(z)
            if f > z:
                f = np.nextafter(f, ninf)
            front[v, u] = f
            b = np.float32(zback[v, u])
            if b < zback[v, u]:
                b = np.nextafter(b, pinf)
            back[v, u] = b
            tau = max(a * z * z, tmin)
            s = max(z - max(0.0, 2.0 * tau - padding), near)
            s32 = np.float32(s)
            if s32 > s:
                s32 = np.nextafter(s32, ninf)
            start[v, u] = s32
