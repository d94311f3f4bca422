"""Edge wedges and sheet tiles: where a static band meets another camera's robot shadow.

At a depth camera's static edge the band is the pixel's 3 x 3 neighbourhood's (flying
pixels, :mod:`polyhull.engine.static_model`), so a reading anywhere between the nearer and
the farther surface is static, and the static free depth ``f_s`` is the nearer surface's.
Behind it lies the pixel's **wedge**: its ray from ``f_s`` to ``own_free``, the least free
depth of a reading of the pixel's own background. The static model counts the wedge as
hidden from the camera, which is conservative for ``C_static``. But a segment's end is the
depth the static scene (and the robot) lets the camera see free, and the robot occlusion
``M = F_static \\ F_static+robot`` is defined from the empty cell, where the pixel reads its
own background and sees its wedge free. Ending the pixel's segment at ``f_s`` would count a
wedge point that another camera sees only in the empty cell (now behind the robot) as M,
and a person standing there, read by this pixel in front of its own background (within
the widened band, so static), would be lost.

So the segment of an edge pixel runs to ``own_free`` wherever its wedge may meet another
camera's robot shadow, and a reading in front of its own band then has a segment (the
other cameras carve it like any other). Elsewhere the wedge changes nothing: a wedge point
the other cameras see free with the robot is free, and one they do not see even in the
empty cell lies in ``C_static``. The test is conservative, per cycle and per camera pair:
the image rectangle of the wedge's eight corners (its pixel's corners at both depths,
projected once) against the rectangle of each padded robot piece's vertices, and the
wedge's farthest depth against the piece's nearest, in the other camera (a colour
camera's robot hides its whole ray). About 1,000 edge pixels a camera, against 15 pieces.

The same holds away from edges, thinner: a static pixel's band sheet, from ``f_s`` to the
empty cell's free depth ``B - tau(B)``, is what the empty cell shows the camera, and a
foot lying in it is read as the surface (static). Where another camera's robot shadow
crosses the sheet, the foot is not M, and only that camera's sheet holds it. So per
tile of the image (:class:`SheetTiles`), the sheet's box is projected into the other
cameras once, and each cycle the tiles whose sheet may meet another camera's robot
shadow are candidates; the pixel classification runs their segments to ``B - tau(B)``
near a surface seen in front of the band (a person: within the floor shell's lateral
margin of it, :mod:`polyhull.engine.pixels`). Elsewhere such a sheet is the floor's noise
under the robot's shadows, which the floor-shell rule would remove.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numba as nb
import numpy as np

from ..camera import Camera

__all__ = ["EdgeWedges", "SheetTiles", "robot_boxes"]


def robot_boxes(cameras: Sequence[Camera], pieces: Sequence[np.ndarray]) -> list[np.ndarray | None]:
    """Per camera, the padded robot's pieces (world hull vertices, (K_i, 3) each) in its
    image: (P, 5) rows u0, u1, v0, v1 (the pixel rectangle of a piece's vertices, grown by
    two pixels: the raster covers a pixel whose square, grown by one, meets the piece; the
    whole image when a vertex is not in front of the camera) and zmin (the piece's nearest
    depth less twice the depth tolerance there, where the raster's shadow may start [m];
    0 for a colour camera, whose robot hides the whole ray);
    None where no piece is in the image (the robot shadows nothing there). A piece's shadow
    lies in its rectangle, beyond its nearest depth: the pieces' boxes bound the robot's
    shadow far more tightly than one box of the whole arm."""
    if not len(pieces):
        return [None] * len(cameras)
    sizes = np.array([len(p) for p in pieces], dtype=np.int64)
    verts = np.ascontiguousarray(np.concatenate(pieces), dtype=np.float64)
    out: list[np.ndarray | None] = []
    for cam in cameras:
        H, W = cam.shape
        k = cam.intrinsics
        b = np.empty((len(pieces), 5))
        n = _piece_boxes(
            verts, sizes, np.ascontiguousarray(cam.T_camera_world, dtype=np.float64), k.fx, k.fy, k.cx, k.cy, W, H,
            float(cam.tolerance_sigmas * cam.noise), float(cam.tolerance_min), cam.kind == "color", b,
        )
        out.append(b[:n] if n else None)
    return out


@nb.njit(cache=True, nogil=True)
def _piece_boxes(verts, sizes, T, fx, fy, cx, cy, W, H, tau_a, tau_min, binary, out):  # pragma: no cover - compiled
    """Write the rows of :func:`robot_boxes` of the pieces in the image into ``out``
    (pieces ``sizes`` vertices each, stacked in ``verts``); returns their count."""
    n = 0
    j = 0
    for p in range(sizes.shape[0]):
        xmin = np.inf
        xmax = -np.inf
        ymin = np.inf
        ymax = -np.inf
        zmin = np.inf
        bad = False
        for q in range(j, j + sizes[p]):
            x, y, z = verts[q, 0], verts[q, 1], verts[q, 2]
            pz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            px = (T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]) / pz
            py = (T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]) / pz
            bad |= not (pz > 1e-9 and px == px and py == py)  # (NaN: min and max would skip it)
            xmin = min(xmin, px)
            xmax = max(xmax, px)
            ymin = min(ymin, py)
            ymax = max(ymax, py)
            zmin = min(zmin, pz)
        j += sizes[p]
        if bad:  # a vertex not in front of the camera, or not a number: the whole image
            out[n, 0], out[n, 1], out[n, 2], out[n, 3], out[n, 4] = -np.inf, np.inf, -np.inf, np.inf, 0.0
            n += 1
            continue
        u0 = fx * xmin + cx - 2.0
        u1 = fx * xmax + cx + 2.0
        v0 = fy * ymin + cy - 2.0
        v1 = fy * ymax + cy + 2.0
        if u1 < -0.5 or v1 < -0.5 or u0 > W - 0.5 or v0 > H - 0.5:
            continue  # outside the image
        out[n, 0], out[n, 1], out[n, 2], out[n, 3] = u0, u1, v0, v1
        out[n, 4] = 0.0 if binary else zmin - 2.0 * max(tau_a * zmin * zmin, tau_min)
        n += 1
    return n


class _Wedges(NamedTuple):
    """One camera's wedges: pixels (n, 2) as (v, u), their ``own_free`` (n,) [m], the other
    cameras' indices (J,), and in each other camera's image the wedges' rectangle and
    farthest depth [m], (5, J, n): u0, u1, v0, v1, zmax."""

    vu: np.ndarray
    end: np.ndarray
    others: np.ndarray
    boxes: np.ndarray


class EdgeWedges:
    """Every camera's edge wedges, projected into the other cameras once."""

    def __init__(self, wedges: list[_Wedges]) -> None:
        self._wedges = wedges

    @classmethod
    def build(cls, statics: Sequence[object]) -> EdgeWedges:
        """From the static cameras (:class:`polyhull.engine.static_model.StaticCamera`: their
        ``camera``, ``edge``, ``free_static`` and ``own_free``)."""
        cams = [s.camera for s in statics]  # type: ignore[attr-defined]
        wedges = []
        for i, s in enumerate(statics):
            cam: Camera = s.camera  # type: ignore[attr-defined]
            fs = np.asarray(s.free_static, dtype=np.float64)  # type: ignore[attr-defined]
            own = np.asarray(s.own_free, dtype=np.float64)  # type: ignore[attr-defined]
            v, u = np.nonzero(np.asarray(s.edge) & (own > fs))  # type: ignore[attr-defined]
            corners = _corners(cam, u, v, fs[v, u], own[v, u])  # (n, 8, 3) world
            others, boxes = _project(cams, i, corners)
            wedges.append(_Wedges(np.column_stack([v, u]).astype(np.int64), own[v, u].astype(np.float32), others, boxes))
        return cls(wedges)

    def count(self, i: int) -> int:
        """Camera ``i``'s number of edge wedges."""
        return len(self._wedges[i].end)

    def ends(self, i: int, robots: Sequence[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``i``'s edge pixels (m, 2) as (v, u) whose wedge may meet another camera's
        robot shadow this cycle (``robots``: :func:`robot_boxes`), and their segment end
        ``own_free`` (m,) [m]."""
        w = self._wedges[i]
        hit = _meets(w.others, w.boxes, robots)
        return w.vu[hit], w.end[hit]


class SheetTiles:
    """Every depth camera's image tiles whose band sheet (``f_s`` to ``B - tau(B)``) is not
    empty, projected into the other cameras once, with the reach of a person's feet."""

    def __init__(
        self, tiles: list[_Wedges], reach: list[np.ndarray], depths: list[np.ndarray], ends: list[np.ndarray],
        shapes: list[tuple[int, int]], margin: float, lift: float,
    ) -> None:
        self._tiles = tiles
        self._reach = reach
        self._depths = depths
        self._ends = ends
        self._shapes = shapes
        self.margin = margin
        self.lift = lift

    @classmethod
    def build(cls, statics: Sequence[object], tile: int, margin: float, height: float) -> SheetTiles:
        """From the static cameras (their ``camera``, ``edge``, ``free_static`` and
        ``free_empty``), for tiles of ``tile`` px and the floor shell's lateral ``margin``
        [m]: a tile's reach [tiles] is the margin in its image at its nearest sheet depth,
        plus one tile (the surface seen may lie anywhere in its own tile); in depth, a
        surface seen within the margin of the sheet's depths reaches it. Only a lower leg
        reaches: a surface seen within ``lift = height + margin`` [m] in front of its
        reference (``height``: the floor shell's; the feet lie in the shell). A pixel's
        sheet is only its part outside ``C_static`` (which holds the rest, and the
        floor-shell rule keeps it under a person): it ends at :func:`_sheet_ends`."""
        cams = [s.camera for s in statics]  # type: ignore[attr-defined]
        tiles, reach, depths, ends, shapes = [], [], [], [], []
        for i, s in enumerate(statics):
            cam: Camera = s.camera  # type: ignore[attr-defined]
            H, W = cam.shape
            nv, nu = -(-H // tile), -(-W // tile)
            fs = np.asarray(s.free_static, dtype=np.float64)  # type: ignore[attr-defined]
            fe = _sheet_ends(statics, i)
            sheet = fe > fs
            pad = ((0, nv * tile - H), (0, nu * tile - W))
            z0 = np.pad(np.where(sheet, fs, np.inf), pad, constant_values=np.inf)
            z1 = np.pad(np.where(sheet, fe, -np.inf), pad, constant_values=-np.inf)
            z0 = z0.reshape(nv, tile, nu, tile).min(axis=(1, 3))
            z1 = z1.reshape(nv, tile, nu, tile).max(axis=(1, 3))
            tv, tu = np.nonzero(np.isfinite(z0))
            # the tile's corners as a pixel block: (u0 - 0.5 .. u1 + 0.5) at both depths
            u_lo, v_lo = tu * tile, tv * tile
            u_hi, v_hi = np.minimum(u_lo + tile, W) - 1, np.minimum(v_lo + tile, H) - 1
            corners = _block_corners(cam, u_lo, u_hi, v_lo, v_hi, z0[tv, tu], z1[tv, tu])
            others, boxes = _project(cams, i, corners)
            k = cam.intrinsics
            r = np.zeros((nv, nu), dtype=np.int64)
            r[tv, tu] = np.ceil(margin * max(k.fx, k.fy) / (np.maximum(z0[tv, tu], cam.near) * tile)).astype(np.int64) + 1
            tiles.append(_Wedges(np.column_stack([tv, tu]).astype(np.int64), z1[tv, tu].astype(np.float32), others, boxes))
            reach.append(np.minimum(r, max(nv, nu)))
            depths.append(np.stack([z0, z1]))
            ends.append(fe.astype(np.float32))
            shapes.append((nv, nu))
        return cls(tiles, reach, depths, ends, shapes, float(margin), float(height + margin))

    def reach(self, i: int) -> np.ndarray:
        """Camera ``i``'s (n_v, n_u) reach of every tile [tiles] (0: no sheet)."""
        return self._reach[i]

    def ends(self, i: int) -> np.ndarray:
        """Camera ``i``'s (H, W) float32 end of every pixel's sheet [m] (``f_s``: none)."""
        return self._ends[i]

    def depths(self, i: int) -> np.ndarray:
        """Camera ``i``'s (2, n_v, n_u) least and greatest depth of every tile's sheet [m]
        (+inf and -inf: none)."""
        return self._depths[i]

    def cycle(self, i: int, robots: Sequence[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
        """Camera ``i``'s ``sheets`` argument of
        :func:`polyhull.engine.pixels.classify_frame` this cycle: its candidate tiles, their
        reach and depths, its sheet ends, the margin and the lift."""
        return self.candidates(i, robots), self._reach[i], self._depths[i], self._ends[i], self.margin, self.lift

    def candidates(self, i: int, robots: Sequence[np.ndarray | None]) -> np.ndarray:
        """Camera ``i``'s (n_v, n_u) tiles whose sheet may meet another camera's robot
        shadow this cycle (``robots``: :func:`robot_boxes`)."""
        t = self._tiles[i]
        out = np.zeros(self._shapes[i], dtype=np.bool_)
        hit = _meets(t.others, t.boxes, robots)
        out[t.vu[hit, 0], t.vu[hit, 1]] = True
        return out


SHEET_SAMPLES = 17
"""Depths sampled along each pixel's sheet to find its part outside ``C_static``."""


def _sheet_ends(statics: Sequence[object], i: int) -> np.ndarray:
    """(H, W) camera ``i``'s sheet ends [m]: the farthest of ``SHEET_SAMPLES`` depths from
    ``f_s`` to ``B - tau(B)`` that another camera frees in the empty cell (outside
    ``C_static``), one sample step farther (at most ``B - tau(B)``); ``f_s`` where none is
    (the whole sheet lies in ``C_static``), at edge pixels (their wedges) and for a colour
    camera. The samples resolve the sheet to a sixteenth of its depth (1 to 2 cm); they
    are tried from the far end, each pixel until one is free."""
    s = statics[i]
    cam: Camera = s.camera  # type: ignore[attr-defined]
    fs = np.asarray(s.free_static, dtype=np.float64)  # type: ignore[attr-defined]
    fe = np.asarray(s.free_empty, dtype=np.float64)  # type: ignore[attr-defined]
    out = fs.copy()
    if cam.kind == "color":
        return out
    v, u = np.nonzero((fe > fs) & ~np.asarray(s.edge))  # type: ignore[attr-defined]
    z0, z1 = fs[v, u], fe[v, u]
    step = (z1 - z0) / (SHEET_SAMPLES - 1)
    k = cam.intrinsics
    # camera-frame rays with unit z, in the world frame (origin: the camera's centre)
    T = cam.T_world_camera
    rays = np.column_stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(len(u))]) @ T[:3, :3].T
    others = []
    for j, sj in enumerate(statics):
        if j != i:
            cj: Camera = sj.camera  # type: ignore[attr-defined]
            ij = cj.intrinsics
            others.append((cj.T_camera_world, np.array([ij.fx, ij.fy, ij.cx, ij.cy]), np.asarray(sj.free_static)))  # type: ignore[attr-defined]
    last = np.full(len(v), -1, dtype=np.int64)
    for n in range(SHEET_SAMPLES - 1, -1, -1):
        todo = np.nonzero(last < 0)[0]
        if not len(todo):
            break
        z = z0[todo] + n * step[todo]
        freed = np.zeros(len(todo), dtype=np.bool_)
        for Tj, kj, fsj in others:
            _freed(rays[todo], z, T[:3, 3].copy(), Tj, kj, fsj, freed)
        last[todo[freed]] = n
    some = last >= 0
    out[v[some], u[some]] = np.minimum(z0[some] + (last[some] + 1) * step[some], z1[some])
    return out


@nb.njit(cache=True, nogil=True)
def _freed(rays, z, origin, T, k, fs, out):  # pragma: no cover - compiled
    """``out[n] |= the point origin + z[n] rays[n] lies in front of the static free depth
    ``fs`` of the pixel it projects to in the camera of ``T`` (world to camera) and
    intrinsics ``k`` (fx, fy, cx, cy)``."""
    H, W = fs.shape
    for n in range(rays.shape[0]):
        if out[n]:
            continue
        x = origin[0] + z[n] * rays[n, 0]
        y = origin[1] + z[n] * rays[n, 1]
        w = origin[2] + z[n] * rays[n, 2]
        cx = T[0, 0] * x + T[0, 1] * y + T[0, 2] * w + T[0, 3]
        cy = T[1, 0] * x + T[1, 1] * y + T[1, 2] * w + T[1, 3]
        cz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * w + T[2, 3]
        if cz <= 0.0:
            continue
        pu = np.floor(k[0] * cx / cz + k[2] + 0.5)
        pv = np.floor(k[1] * cy / cz + k[3] + 0.5)
        if pu < 0 or pv < 0 or pu >= W or pv >= H:
            continue
        if cz < fs[int(pv), int(pu)]:
            out[n] = True


def _project(cams: Sequence[Camera], i: int, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The other cameras' indices (J,) and, in each of their images, the rectangle and
    farthest depth of each box's corners ``corners`` (n, 8, 3) world, (5, J, n): u0, u1,
    v0, v1, zmax (unbounded when a corner is not in front of that camera)."""
    others = np.array([j for j in range(len(cams)) if j != i], dtype=np.int64)
    boxes = np.empty((5, len(others), len(corners)))
    for n, j in enumerate(others):
        uv, z = cams[j].project(corners.reshape(-1, 3))
        uv = uv.reshape(-1, 8, 2)
        z = z.reshape(-1, 8)
        behind = np.any(z <= 1e-9, axis=1)
        with np.errstate(invalid="ignore"):
            b = np.stack(
                [uv[:, :, 0].min(axis=1), uv[:, :, 0].max(axis=1), uv[:, :, 1].min(axis=1), uv[:, :, 1].max(axis=1), z.max(axis=1)]
            )
        b[:, behind] = np.array([-np.inf, np.inf, -np.inf, np.inf, np.inf])[:, None]
        boxes[:, n] = b
    return others, boxes


def _meets(others: np.ndarray, boxes: np.ndarray, robots: Sequence[np.ndarray | None]) -> np.ndarray:
    """(n,) the boxes (:func:`_project`) that may meet another camera's robot shadow: their
    rectangle overlaps a robot piece's (:func:`robot_boxes`) and their farthest depth is
    beyond its nearest."""
    out = np.zeros(boxes.shape[2], dtype=np.bool_)
    for n, j in enumerate(others):
        r = robots[j]
        if r is not None:
            _meets_kernel(boxes[:, n], r, out)
    return out


@nb.njit(cache=True, nogil=True)
def _meets_kernel(b, r, out):  # pragma: no cover - compiled
    """``out[t] |= box t (``b`` (5, n)) meets a piece box of ``r`` (P, 5)``."""
    for t in range(b.shape[1]):
        if out[t]:
            continue
        for p in range(r.shape[0]):
            if b[1, t] >= r[p, 0] and b[0, t] <= r[p, 1] and b[3, t] >= r[p, 2] and b[2, t] <= r[p, 3] and b[4, t] >= r[p, 4]:
                out[t] = True
                break


def _block_corners(
    cam: Camera, u0: np.ndarray, u1: np.ndarray, v0: np.ndarray, v1: np.ndarray, z0: np.ndarray, z1: np.ndarray
) -> np.ndarray:
    """(n, 8, 3) world points: the corners of the pixel blocks [u0, u1] x [v0, v1] at
    z-depths ``z0`` and ``z1``."""
    k = cam.intrinsics
    us = np.stack([u0 - 0.5, u1 + 0.5, u1 + 0.5, u0 - 0.5] * 2, axis=1)
    vs = np.stack([v0 - 0.5, v0 - 0.5, v1 + 0.5, v1 + 0.5] * 2, axis=1)
    z = np.column_stack([z0, z0, z0, z0, z1, z1, z1, z1])
    pts = np.stack([(us - k.cx) / k.fx * z, (vs - k.cy) / k.fy * z, z], axis=2)
    return cam.camera_to_world(pts.reshape(-1, 3)).reshape(-1, 8, 3)


def _corners(cam: Camera, u: np.ndarray, v: np.ndarray, z0: np.ndarray, z1: np.ndarray) -> np.ndarray:
    """(n, 8, 3) world points: the corners of pixels (u, v) at z-depths ``z0`` and ``z1``."""
    return _block_corners(cam, u, u, v, v, z0, z1)
