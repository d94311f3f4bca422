"""The static model: everything about the empty cell, computed once when the monitor is built.

Per camera (:class:`StaticCamera`), from the reference depth B of the empty cell:

- the **band** ``[T, U]`` of measurements consistent with the background, ``CONSISTENT_BAND``
  tolerances wide (4.5 sigma), so that ordinary noise keeps a pixel static. It is
  **edge-aware**: where the reference jumps within a pixel's 3 x 3 neighbourhood by more than
  the band (a static depth edge, where time-of-flight sensors report mixed "flying"
  depths), the pixel takes the widest band of its neighbourhood; a pixel next to one whose
  background lies beyond the range (or within the noise of its limit) frees nothing, so any
  reading there, valid or not, is static;
- the **static free depth** ``f_s``: the least free depth of any measurement in the band.

Fused (:class:`StaticModel`):

- ``F_static(i)``: each camera's free region under a conservative piecewise-linear surface
  of ``f_s`` (:func:`polyhull.regions.conservative_surface`), and the static hull
  ``C_static = Z \\ U F_static(i)`` (k-of-n when configured), minus the solid obstacles:
  ``R2_static``;
- the **noise sheets**: each camera's free depth stops up to ``(1 + CONSISTENT_BAND)`` tau
  short of the floor and of table tops, so R2_static holds a thin sheet over them. The
  part of R2_static within ``floor_shell_height`` above such a surface is removed, except
  within ``floor_shell_margin`` (horizontally) of whatever crosses that height (a blind
  region, a shadow), whose bottom it is. Per cycle, a dynamic component keeps the sheet
  under it (:mod:`polyhull.engine.dynamic_rules`). In front of a vertical face taller than
  ``LOW_FACE`` (a rack, a wall) a person may stand wholly below the face's edge, and the
  sheet measured there can be deeper (0.4 m) than a standing person: it is judged only
  ``plausibility.standing_depth`` deep, and the static region beyond stays;
- the plausibility rules over the remaining components (:mod:`polyhull.plausibility`),
  judged once: ``R3_static``;
- a python-fcl BVH of R3_static (reused every cycle with the identity transform) and a
  voxel grid of where it is, so that per cycle a dynamic component can tell in O(1) whether
  it touches a static one; where the voxels' slack matters, its triangles binned in a
  uniform grid (built on first use) tell exactly which boxes meet its surface
  (:meth:`StaticModel.boxes_meet`).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import fcl
import manifold3d as m3
import numba as nb
import numpy as np
from scipy import ndimage

from ..background import TaughtCamera
from ..cachedir import cache_directory, imported_sources_digest
from ..camera import Camera
from ..cell import Cell, Obstacle
from ..errors import FrameError
from ..fusion import free_union
from ..plausibility import (
    PlausibilityContext,
    RemovedComponent,
    apply_plausibility,
    mesh_volume_centroid,
)
from ..regions import (
    check_manifold,
    conservative_surface,
    consistent_band,
    free_region_from_surface,
)
from ..typed import ArrayF32, ArrayF64
from .boxes import TriangleGrid, groups_meet_triangles

__all__ = [
    "BOX_MEET_TOLERANCE",
    "CONSISTENT_BAND",
    "StaticCamera",
    "Sheet",
    "StaticModel",
    "TouchGrid",
    "remove_sheets",
]

BOX_MEET_TOLERANCE = 1e-9
"""Relative growth of the boxes of :meth:`StaticModel.boxes_meet` beyond their distance:
1e-9 of the coordinates' magnitude [m] (6e-9 m at 6 m), millions of times a float64's
rounding, so that a box touching the surface is never judged apart from it."""

CONSISTENT_BAND = 1.5
"""Width of the static band in depth tolerances (1.5 tau = 4.5 sigma at 3 sigma)."""


def _down32(x: ArrayF64) -> ArrayF32:
    """float32 copy rounded toward -inf (never above ``x``)."""
    y = x.astype(np.float32)
    with np.errstate(invalid="ignore"):
        return np.where(y > x, np.nextafter(y, np.float32(-np.inf)), y).astype(np.float32)


def _up32(x: ArrayF64) -> ArrayF32:
    """float32 copy rounded toward +inf (never below ``x``)."""
    y = x.astype(np.float32)
    with np.errstate(invalid="ignore"):
        return np.where(y < x, np.nextafter(y, np.float32(np.inf)), y).astype(np.float32)


@dataclass(frozen=True, eq=False)
class StaticCamera:
    """One camera's static data (read-only arrays, float32 rounded conservatively).

    Attributes:
        camera: The camera.
        reference: (H, W) reference depth B [m] (+inf where nothing is hit), rounded down.
        lower: (H, W) band lower bound T [m], rounded up (the band only narrows).
        upper: (H, W) band upper bound U [m], rounded down.
        free_static: (H, W) static free depth f_s [m], rounded down; ``near`` where the
            pixel frees nothing.
        block: Block side [px] of the static surface.
        surface: (Hb + 1, Wb + 1) corner values ``w = -1/z`` of the conservative surface of
            ``free_static`` over ``block`` px blocks.
        edge: (H, W) the pixels whose band is their neighbourhood's (a depth camera's
            static edge) and that free something: ``free_static`` is the nearer surface's
            there, and a reading's own exact free depth frees more (the classification
            computes it, :func:`polyhull.engine.pixels.classify_frame`).
        own_free: (H, W) the least free depth of a reading in the pixel's own band (before
            an edge widened it) [m], rounded down: ``free_static`` except at ``edge``
            pixels, where it is the farther surface's. Where another camera's robot shadow
            may cross the wedge between the two, the pixel's segment runs to it
            (:mod:`polyhull.engine.edge_wedges`).
        free_empty: (H, W) the free depth of the empty cell's own reading, ``B - tau(B)``
            [m] (``M = F_static \\ F_static+robot`` is defined from it), rounded down; at least
            ``free_static``, ``near`` where the pixel frees nothing: where a segment ends.
    """

    camera: Camera
    reference: ArrayF32
    lower: ArrayF32
    upper: ArrayF32
    free_static: ArrayF32
    block: int
    surface: ArrayF64
    edge: np.ndarray
    own_free: ArrayF32
    free_empty: ArrayF32

    @classmethod
    def build(
        cls, camera: Camera, reference: np.ndarray, block: int, taught: TaughtCamera | None = None
    ) -> StaticCamera:
        """The static data of ``camera`` from its reference depth (H, W) [m].

        With a taught background (``taught``), the taught median and band replace the
        reference and band wherever the pixel was valid during teaching, and the pixels
        that were not are static-invalid: they free nothing and are never a change
        (:meth:`polyhull.background.TaughtCamera.band`).
        """
        B = np.asarray(reference, dtype=np.float64)
        if B.shape != camera.shape:
            raise FrameError(
                f"camera '{camera.name}': reference shape {B.shape} != image shape {camera.shape}"
            )
        if np.any(np.isnan(B)) or np.any(B <= 0):
            raise FrameError(
                f"camera '{camera.name}': reference depth must be > 0 m or +inf, got NaN or <= 0"
            )
        width = 1.0 if camera.kind == "color" else CONSISTENT_BAND
        T, U = consistent_band(camera, B, width)
        static_invalid = None
        if taught is not None:
            B, T, U, static_invalid = taught.band(camera, B, T, U, width)
        B_far = np.minimum(B, camera.far)
        # Beyond the range, or within the noise of its limit: the reading may be invalid.
        unsure = ~np.isfinite(B) | (B + width * camera.tau(B_far) > camera.far)
        with np.errstate(invalid="ignore"):
            jump = ndimage.maximum_filter(B_far, 3, mode="nearest") - ndimage.minimum_filter(
                B_far, 3, mode="nearest"
            )
            # A depth camera's static edges take their 3 x 3 neighbourhood's band (flying
            # pixels); a colour camera has none, and a widened colour band would admit
            # changed readings (``D < B - tau(D)``), so it keeps its own band everywhere.
            edge = (jump > (U - T)) & (camera.kind != "color")
        T0, U0 = T, U
        T = np.where(edge, ndimage.minimum_filter(T, 3, mode="nearest"), T)
        U = np.where(edge, ndimage.maximum_filter(U, 3, mode="nearest"), U)
        with np.errstate(invalid="ignore"):
            if camera.kind == "color":
                f_s = B - camera.tau(B_far)
            else:
                # min over D in [T, U] of min(D, B) - tau(D): at D = T or D = U.
                f_s = np.minimum(T - camera.tau(T), B - camera.tau(U))
        no_free = ndimage.maximum_filter(unsure, 3, mode="nearest")
        if static_invalid is not None:
            no_free |= static_invalid
        f_s = np.where(no_free, camera.near, np.clip(f_s, camera.near, camera.far))
        widened = (T < T0) | (U > U0)
        edge_px = np.ascontiguousarray(widened & ~no_free & (f_s > camera.near))
        edge_px.setflags(write=False)
        with np.errstate(invalid="ignore"):
            f_own = np.minimum(T0 - camera.tau(T0), B - camera.tau(U0))
        own_free = _down32(np.where(edge_px, np.clip(np.fmax(f_own, f_s), camera.near, camera.far), f_s))
        own_free.setflags(write=False)
        with np.errstate(invalid="ignore"):
            f_e = np.fmax(B_far - camera.tau(B_far), f_s)
        free_empty = _down32(np.where(no_free, camera.near, np.clip(f_e, camera.near, camera.far)))
        free_empty.setflags(write=False)
        w = np.where(f_s > camera.near, -1.0 / f_s, -1.0 / camera.near)
        arrays = {
            "reference": _down32(B),
            "lower": _up32(T),
            "upper": _down32(U),
            "free_static": _down32(f_s),
        }
        for a in arrays.values():
            a.setflags(write=False)
        surface = conservative_surface(w, block)
        surface.setflags(write=False)
        return cls(camera=camera, block=int(block), surface=surface, edge=edge_px, own_free=own_free, free_empty=free_empty, **arrays)

    @property
    def tau_a(self) -> float:
        """``tolerance_sigmas * noise``: tau(z) = max(tau_a z^2, tolerance_min) [m]."""
        return float(self.camera.tolerance_sigmas * self.camera.noise)

    def free_region(self) -> m3.Manifold:
        """F_static(i) in the world frame: in front of the static surface."""
        return free_region_from_surface(self.camera, self.surface, self.block)

    def surface_depth(self, points_world: ArrayF64) -> tuple[ArrayF64, ArrayF64]:
        """(depth of each point [m], surface depth of the pixel it projects to [m]).

        Points outside the image get a surface depth of ``-inf`` (not freed); the static
        free region is where ``near < depth < surface depth``.
        """
        cam = self.camera
        uv, z = cam.project(points_world)
        H, W = cam.shape
        b = self.block
        with np.errstate(invalid="ignore"):
            inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
        x = np.where(inside, (np.nan_to_num(uv[:, 0]) + 0.5) / b, 0.0)
        y = np.where(inside, (np.nan_to_num(uv[:, 1]) + 0.5) / b, 0.0)
        S = self.surface
        i = np.clip(np.floor(x).astype(np.int64), 0, S.shape[1] - 2)
        j = np.clip(np.floor(y).astype(np.int64), 0, S.shape[0] - 2)
        fx, fy = x - i, y - j
        Ga, Gb, Gc, Gd = S[j, i], S[j, i + 1], S[j + 1, i + 1], S[j + 1, i]
        upper = fx >= fy
        w = np.where(upper, Ga + (Gb - Ga) * fx + (Gc - Gb) * fy, Ga + (Gc - Gd) * fx + (Gd - Ga) * fy)
        w = np.minimum(w, -1.0 / cam.far)
        with np.errstate(divide="ignore"):
            depth = np.where(w < 0, -1.0 / w, np.inf)
        return z, np.where(inside, depth, -np.inf)


@dataclass(frozen=True)
class Sheet:
    """A face of a known surface whose noise sheet is judged at precompute.

    The face is the rectangle ``lo <= (x_a, x_b) <= hi`` of the plane ``x_axis = level``,
    where ``(a, b)`` are the two other axes in increasing order; free space lies on the
    ``sign`` side of it.

    Attributes:
        name: ``"floor"`` or ``"<obstacle> +x"`` (the obstacle and the face's normal).
        axis: The axis of the face's normal (0, 1, 2 for x, y, z).
        sign: +1 or -1: the direction of the outward normal along ``axis``.
        level: The face's coordinate along ``axis`` [m].
        lo: Minimum of the face's two other coordinates [m].
        hi: Maximum of the face's two other coordinates [m].
        height: Thickness [m] of the shell judged in front of the face.
    """

    name: str
    axis: int
    sign: int
    level: float
    lo: tuple[float, float]
    hi: tuple[float, float]
    height: float = 0.0

    def to_local(self) -> np.ndarray:
        """(3, 4) rigid transform world -> local frame, where the face is ``z = 0`` with
        free space at ``z > 0`` and the face's rectangle is ``lo <= (x, y) <= hi``."""
        return _sheet_frame(self)[0].copy()

    def world_box(self, pad: float = 0.0) -> tuple[ArrayF64, ArrayF64]:
        """World bounds (lo, hi) of the sheet's slab, grown by ``pad`` [m] on every side."""
        _, lo, hi, _ = _sheet_frame(self)
        return lo - pad, hi + pad

    def local_box(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The face's rectangle in the local frame's (x, y)."""
        return _sheet_frame(self)[3]

    @property
    def down(self) -> int:
        """For a vertical face, the local axis (0 for x, 1 for y) that runs along world z
        (upward); -1 for a horizontal one (the floor, an obstacle's top)."""
        if self.axis == 2:
            return -1
        M = _sheet_frame(self)[0]
        return 0 if M[0, 2] != 0.0 else 1


@functools.cache
def _sheet_frame(sheet: Sheet) -> tuple[np.ndarray, ArrayF64, ArrayF64, tuple[tuple[float, float], tuple[float, float]]]:
    """A sheet's world -> local transform, its slab's world bounds and its local rectangle
    (computed once per sheet: the dynamic rules ask for them every cycle)."""
    a, b = (i for i in range(3) if i != sheet.axis)
    M = np.zeros((3, 4))
    M[0, a] = 1.0
    M[1, b] = 1.0
    M[2, sheet.axis] = float(sheet.sign)
    M[2, 3] = -float(sheet.sign) * sheet.level
    if np.linalg.det(M[:, :3]) < 0:  # keep it a rotation: mirror x and y instead
        M[0, a] = 0.0
        M[0, b] = 1.0
        M[1, a] = 1.0
        M[1, b] = 0.0
    lo3 = np.zeros(3)
    hi3 = np.zeros(3)
    lo3[[a, b]] = sheet.lo
    hi3[[a, b]] = sheet.hi
    p = np.stack([M[:2, :3] @ lo3, M[:2, :3] @ hi3])
    (x0, y0), (x1, y1) = p.min(axis=0), p.max(axis=0)
    W = _to_world(M)
    corners = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (0.0, sheet.height)])
    pts = corners @ W[:, :3].T + W[:, 3]
    M.setflags(write=False)
    box = ((float(x0), float(y0)), (float(x1), float(y1)))
    return M, pts.min(axis=0), pts.max(axis=0), box


def _is_box(obstacle: Obstacle) -> bool:
    """True when the obstacle is an axis-aligned box (its volume fills its bounds)."""
    lo, hi = obstacle.mesh.bounds
    return bool(np.isclose(obstacle.mesh.volume, float(np.prod(hi - lo)), rtol=1e-6))


def sheets_of(cell: Cell) -> tuple[Sheet, ...]:
    """The floor (over the whole zone) and the five exposed faces of box obstacles."""
    z = cell.zone
    out = [Sheet("floor", 2, 1, z.floor_z, (z.min[0], z.min[1]), (z.max[0], z.max[1]))]
    for o in cell.obstacles:
        if not _is_box(o):
            continue
        lo, hi = (np.asarray(x, dtype=np.float64) for x in o.mesh.bounds)
        for axis in range(3):
            others = [i for i in range(3) if i != axis]
            for sign, level in ((1, hi[axis]), (-1, lo[axis])):
                if axis == 2 and sign < 0:
                    continue  # the bottom face stands on the floor
                out.append(
                    Sheet(
                        f"{o.name} {'+' if sign > 0 else '-'}{'xyz'[axis]}",
                        axis,
                        sign,
                        float(level),
                        (float(lo[others[0]]), float(lo[others[1]])),
                        (float(hi[others[0]]), float(hi[others[1]])),
                    )
                )
    return tuple(out)


def sheet_thickness(sheet: Sheet, cameras: Sequence[StaticCamera], spacing: float = 0.05) -> float:
    """How far [m] the static free regions stop short of a face, along its normal.

    At sample points of the face (``spacing`` apart, 1 cm in from its edges), every camera
    that sees the point (its reference depth there is the point's depth, within 1 cm) frees
    up to its static surface on the point's ray; the sheet at the point is the smallest
    such shortfall measured along the face's normal. Returns the largest over the seen
    points (0 when no camera sees the face).
    """
    (x0, y0), (x1, y1) = sheet.local_box()
    xs = np.linspace(x0 + 0.01, x1 - 0.01, max(int((x1 - x0) / spacing), 2))
    ys = np.linspace(y0 + 0.01, y1 - 0.01, max(int((y1 - y0) / spacing), 2))
    gx, gy = np.meshgrid(xs, ys)
    local = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    W = _to_world(sheet.to_local())
    pts = local @ W[:, :3].T + W[:, 3]
    normal = W[:, 2]
    best = np.full(len(pts), np.inf)
    for s in cameras:
        cam = s.camera
        uv, z = cam.project(pts)
        H, Wd = cam.shape
        ui = np.clip(np.floor(np.nan_to_num(uv[:, 0]) + 0.5).astype(np.int64), 0, Wd - 1)
        vi = np.clip(np.floor(np.nan_to_num(uv[:, 1]) + 0.5).astype(np.int64), 0, H - 1)
        B = s.reference[vi, ui].astype(np.float64)
        _, surf = s.surface_depth(pts)
        seen = (z > cam.near) & (np.abs(B - z) < 0.01) & (surf > cam.near)
        c = cam.center
        stop = c + (pts - c) * (np.where(seen, surf, z) / np.where(z > 0, z, 1.0))[:, None]
        gap = np.abs((pts - stop) @ normal)
        best = np.where(seen, np.minimum(best, gap), best)
    seen_any = np.isfinite(best)
    if not seen_any.any():
        return 0.0
    return float(best[seen_any].max())


SHEET_CAP = 0.4
"""Largest sheet thickness [m] judged in front of an obstacle's face."""

LOW_FACE = 1.0
"""[m] A person next to a vertical face whose upper edge is lower than this (a table's
side) rises above that edge unless lying down (``floor_shell_height``), and is seen there.
In front of a taller face (a rack, a wall, a machine) a person may stand or crouch wholly
below its edge, so its noise sheet is judged only ``standing_depth`` deep."""


def measured_sheets(cell: Cell, cameras: Sequence[StaticCamera]) -> tuple[Sheet, ...]:
    """:func:`sheets_of` with each sheet's thickness measured (:func:`sheet_thickness`),
    times 1.25 plus 2 cm (the samples stop 1 cm short of the edges, where the sheet is
    thickest), at most ``SHEET_CAP`` (or the floor's height, if larger), for the faces of
    obstacles; faces no camera sees are left out. The floor's sheet is
    ``plausibility.floor_shell_height`` thick: the stated assumption that nobody lies
    flatter than that; where the floor's sheet is thicker, what crosses that height keeps
    the sheet around it."""
    h_floor = cell.plausibility.floor_shell_height
    out = []
    for s in sheets_of(cell):
        t = sheet_thickness(s, cameras)
        if s.name == "floor":
            h = h_floor  # a thicker sheet somewhere keeps a margin there (the crossing test)
        elif t > 0:
            h = min(1.25 * t + 0.02, max(SHEET_CAP, h_floor))
        else:
            continue
        out.append(replace(s, height=h))
    # The shell around a box also covers its edges: grow each face's rectangle by the
    # thickest sheet of the same obstacle (the floor's rectangle is the whole zone).
    grown = []
    for s in out:
        if s.name == "floor":
            grown.append(s)
            continue
        owner = s.name.rsplit(" ", 1)[0]
        g = max(o.height for o in out if o.name != "floor" and o.name.rsplit(" ", 1)[0] == owner)
        grown.append(replace(s, lo=(s.lo[0] - g, s.lo[1] - g), hi=(s.hi[0] + g, s.hi[1] + g)))
    return tuple(grown)


def _to_world(M: np.ndarray) -> np.ndarray:
    R = M[:, :3]
    out = np.zeros((3, 4))
    out[:, :3] = R.T
    out[:, 3] = -R.T @ M[:, 3]
    return out


SHEET_PITCH = 0.1
"""Cell [m] of the sheets' height maps (and of the dynamic rules' sheet boxes)."""


def sheet_heights(sheet: Sheet, hull_contains, step: float = 0.01) -> np.ndarray:  # noqa: ANN001
    """(nx, ny) the local height [m] up to which C_static may reach inside the sheet's slab,
    per ``SHEET_PITCH`` cell of the face's rectangle (from its low corner).

    C_static is sampled (``hull_contains``, the static model's point oracle) on vertical
    lines through the cells' corners and centres every ``step``; a cell takes the highest
    sample of its 3 x 3 neighbourhood plus ``2 * step``, at most the sheet's height. The
    band in front of a surface varies slowly, so this bounds C_static over the cell; where
    a shadow reaches the slab's top, the cell is as tall as the sheet.
    """
    (x0, y0), (x1, y1) = sheet.local_box()
    nx = max(int(math.ceil((x1 - x0) / SHEET_PITCH)), 1)
    ny = max(int(math.ceil((y1 - y0) / SHEET_PITCH)), 1)
    gx = np.minimum(x0 + SHEET_PITCH * np.arange(2 * nx + 1) / 2.0, x1)
    gy = np.minimum(y0 + SHEET_PITCH * np.arange(2 * ny + 1) / 2.0, y1)
    zs = np.arange(0.0, sheet.height + step, step)
    X, Y, Z = np.meshgrid(gx, gy, zs, indexing="ij")
    local = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    W = _to_world(sheet.to_local())
    inside = np.asarray(hull_contains(local @ W[:, :3].T + W[:, 3])).reshape(X.shape)
    top = np.where(inside.any(axis=2), zs[np.argmax(np.where(inside, zs, -1.0), axis=2)], 0.0)  # (2nx+1, 2ny+1)
    cell = np.zeros((nx, ny))
    for i in range(nx):
        for j in range(ny):
            cell[i, j] = top[2 * i : 2 * i + 3, 2 * j : 2 * j + 3].max()
    grown = ndimage.maximum_filter(cell, size=3, mode="nearest")
    return np.minimum(grown + 2.0 * step, sheet.height)


def removal_depths(cell: Cell, sheets: Sequence[Sheet]) -> tuple[float, ...]:
    """How deep [m] the static model removes each face's noise sheet: its height (the
    floor's ``plausibility.floor_shell_height``), and in front of a vertical face of an
    obstacle whose top is at least ``LOW_FACE`` high, where a person may stand wholly below
    the edge, at most ``plausibility.standing_depth`` (nobody standing against it is
    flatter; the sheet beyond stays in the static region)."""
    p = cell.plausibility
    tops = {o.name: float(np.asarray(o.mesh.bounds)[1][2]) for o in cell.obstacles}
    out = []
    for s in sheets:
        h = s.height if s.height > 0 else p.floor_shell_height
        top = tops.get(s.name.rsplit(" ", 1)[0], -math.inf)
        out.append(min(h, p.standing_depth) if s.down >= 0 and top >= LOW_FACE else h)
    return tuple(out)


def remove_sheets(
    region: m3.Manifold,
    sheets: Sequence[Sheet],
    depths: Sequence[float],
    margin: float,
    not_people: m3.Manifold,
) -> tuple[m3.Manifold, list[RemovedComponent]]:
    """Remove the noise sheet in front of each face: the part of ``region`` within the
    face's removal depth [m] (``depths``, :func:`removal_depths`) of it (over the face's
    rectangle), except within ``margin`` [m] (along the face) of the section of ``region``
    at that depth (minus ``not_people``, e.g. the solids), which may be a person's body
    whose foot or hand is in the sheet. A point in several faces' sheets (along an edge, in
    a corner) is removed only when no face spares it.

    Returns:
        (the region without the sheets, one removal per face that lost something).
    """
    removed: list[RemovedComponent] = []
    if region.is_empty():
        return region, removed
    heights = list(depths)
    raw = []  # every face's whole shell, world frame
    for s, h in zip(sheets, heights, strict=True):
        (x0, y0), (x1, y1) = s.local_box()
        shell = m3.Manifold.cube((x1 - x0, y1 - y0, h + 1e-6)).translate((x0, y0, -1e-6))
        raw.append(shell.transform(_to_world(s.to_local())))
    cut, kept, parts = [], [], []
    for j, (s, h) in enumerate(zip(sheets, heights, strict=True)):
        M = s.to_local()
        (x0, y0), (x1, y1) = s.local_box()
        slab = m3.Manifold.cube((x1 - x0, y1 - y0, h + 1e-6)).translate((x0, y0, -1e-6))
        reach = m3.Manifold.cube((x1 - x0 + 2 * margin, y1 - y0 + 2 * margin, 2 * h + 0.2)).translate(
            (x0 - margin, y0 - margin, -0.1)
        )
        # What crosses this face's shell, besides the other faces' sheets and non-people.
        others = [raw[i].transform(M) for i in range(len(sheets)) if i != j]
        if not not_people.is_empty():
            others.append(not_people.transform(M))
        near = region.transform(M) ^ reach
        crossing = m3.Manifold.batch_boolean([near, *others], m3.OpType.Subtract) if others else near
        section = crossing.slice(h)
        if not section.is_empty():
            grown = section.offset(margin, m3.JoinType.Round) if margin > 0 else section
            spared = m3.Manifold.extrude(grown, h + 4e-6).translate((0.0, 0.0, -2e-6)) ^ slab
            kept.append(spared.transform(_to_world(M)))
            slab = slab - spared
        part = near ^ slab
        if part.is_empty() or part.volume() <= 0.0:
            continue
        parts.append(part.transform(_to_world(M)))
        cut.append(slab.transform(_to_world(M)))
    if not cut:
        return region, removed
    # Where sheets meet (a floor along a wall, a corner), a point is in several slabs: it
    # goes only if none of them spares it (a foot in the corner is spared by the floor's
    # margin around the legs, though the wall's slab has nothing crossing near it).
    spared_any = m3.Manifold.batch_boolean(kept, m3.OpType.Add) if kept else m3.Manifold()
    for part in parts:
        part = part - spared_any
        if part.is_empty() or part.volume() <= 0.0:
            continue
        volume, centroid = mesh_volume_centroid(part)
        removed.append(RemovedComponent("sheet", volume, centroid, part))
    out = region - (m3.Manifold.batch_boolean(cut, m3.OpType.Add) - spared_any)
    return check_manifold(out, "static region without its noise sheets"), removed


def _region_voxels(region: m3.Manifold, lo: ArrayF64, hi: ArrayF64, pitch: float) -> np.ndarray:
    """Voxels (over the box [lo, hi], side ``pitch``) holding a sample of the region's
    surface (sampled finer than half the pitch) or whose centre is enclosed by it."""
    shape = np.maximum(np.ceil((hi - lo) / pitch).astype(np.int64), 1)
    occ = np.zeros(tuple(shape), dtype=bool)
    if not region.is_empty():
        mesh = region.to_mesh64()
        v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        t = np.asarray(mesh.tri_verts, dtype=np.int64)
        a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
        size = np.maximum(np.linalg.norm(b - a, axis=1), np.linalg.norm(c - a, axis=1))
        size = np.maximum(size, np.linalg.norm(c - b, axis=1))
        steps = np.clip(np.ceil(size / (0.5 * pitch)).astype(np.int64), 1, 400)
        for n in np.unique(steps):
            sel = steps == n
            s = np.arange(n + 1) / n
            uu, vv = np.meshgrid(s, s)
            keep = uu + vv <= 1.0
            uu, vv = uu[keep], vv[keep]
            pts = (
                a[sel][:, None, :]
                + uu[None, :, None] * (b[sel] - a[sel])[:, None, :]
                + vv[None, :, None] * (c[sel] - a[sel])[:, None, :]
            ).reshape(-1, 3)
            idx = np.floor((pts - lo) / pitch).astype(np.int64)
            ok = np.all((idx >= 0) & (idx < shape), axis=1)
            occ[tuple(idx[ok].T)] = True
        # The inside: fill the enclosed voxels of every z layer.
        occ = ndimage.binary_fill_holes(occ)
    return occ


@dataclass(frozen=True, eq=False)
class TouchGrid:
    """Where a region is, on a voxel grid: box queries in O(1) by a summed-volume table.

    Attributes:
        origin: (3,) world position of the grid's minimum corner [m].
        pitch: Voxel side [m].
        table: (nx + 1, ny + 1, nz + 1) summed-volume table of the occupied voxels.
    """

    origin: ArrayF64
    pitch: float
    table: np.ndarray

    @classmethod
    def within(cls, region: m3.Manifold, lo: ArrayF64, hi: ArrayF64, pitch: float, distance: float) -> TouchGrid:
        """Voxels that may hold a point within ``distance`` [m] of ``region``, by the
        Euclidean distance transform of :func:`_region_voxels`: a voxel is marked when the
        distance between its centre and a marked voxel's centre is at most ``distance`` plus
        ``(sqrt(3) + 1) pitch`` (both points anywhere in their voxels, and a surface point
        between two samples), a superset."""
        lo = np.asarray(lo, dtype=np.float64)
        occ = _region_voxels(region, lo, np.asarray(hi, dtype=np.float64), pitch)
        if occ.any():
            edt = ndimage.distance_transform_edt(~occ)
            occ = edt <= distance / pitch + math.sqrt(3.0) + 1.0
        table = np.zeros(tuple(np.asarray(occ.shape) + 1), dtype=np.int32)
        table[1:, 1:, 1:] = occ.astype(np.int32).cumsum(0).cumsum(1).cumsum(2)
        return cls(lo, float(pitch), table)

    def any_in(self, lo: ArrayF64, hi: ArrayF64) -> np.ndarray:
        """(N,) whether any marked voxel meets each box [lo, hi] (N, 3) [m]."""
        lo = np.ascontiguousarray(np.atleast_2d(np.asarray(lo, dtype=np.float64)))
        hi = np.ascontiguousarray(np.atleast_2d(np.asarray(hi, dtype=np.float64)))
        out = np.empty(lo.shape[0], dtype=np.bool_)
        _any_in(self.table, self.coarse, COARSE, np.asarray(self.origin, dtype=np.float64), float(self.pitch), lo, hi, out)
        return out

    @functools.cached_property
    def coarse(self) -> np.ndarray:
        """The summed-volume table of COARSE x COARSE x COARSE blocks of voxels (marked when
        one of their voxels is): a box in unmarked blocks is answered from this small
        table, without the large one's cache misses."""
        T = self.table.astype(np.int64)
        occ = np.diff(np.diff(np.diff(T, axis=0), axis=1), axis=2) > 0
        n = -(-np.asarray(occ.shape) // COARSE)
        padded = np.zeros(tuple(n * COARSE), dtype=bool)
        padded[: occ.shape[0], : occ.shape[1], : occ.shape[2]] = occ
        blocks = padded.reshape(n[0], COARSE, n[1], COARSE, n[2], COARSE).any(axis=(1, 3, 5))
        table = np.zeros(tuple(n + 1), dtype=np.int32)
        table[1:, 1:, 1:] = blocks.astype(np.int32).cumsum(0).cumsum(1).cumsum(2)
        return table


COARSE = 8
"""Voxels per side of :attr:`TouchGrid.coarse`'s blocks."""


@nb.njit(cache=True, nogil=True, inline="always")
def _box_sum(T, x0, y0, z0, x1, y1, z1):  # pragma: no cover - compiled
    return (
        T[x1, y1, z1] - T[x0, y1, z1] - T[x1, y0, z1] - T[x1, y1, z0]
        + T[x0, y0, z1] + T[x0, y1, z0] + T[x1, y0, z0] - T[x0, y0, z0]
    )


@nb.njit(cache=True, nogil=True)
def _any_in(T, C, k, origin, pitch, lo, hi, out):  # pragma: no cover - compiled
    """:meth:`TouchGrid.any_in`, one box at a time: the blocks (``C``, ``k`` voxels a
    side) the box's voxels lie in first, the voxels only when a block is marked."""
    n0, n1, n2 = T.shape[0] - 1, T.shape[1] - 1, T.shape[2] - 1
    for i in range(lo.shape[0]):
        x0 = min(max(np.int64(np.floor((lo[i, 0] - origin[0]) / pitch)), 0), n0)
        y0 = min(max(np.int64(np.floor((lo[i, 1] - origin[1]) / pitch)), 0), n1)
        z0 = min(max(np.int64(np.floor((lo[i, 2] - origin[2]) / pitch)), 0), n2)
        x1 = min(max(np.int64(np.floor((hi[i, 0] - origin[0]) / pitch)) + 1, 0), n0)
        y1 = min(max(np.int64(np.floor((hi[i, 1] - origin[1]) / pitch)) + 1, 0), n1)
        z1 = min(max(np.int64(np.floor((hi[i, 2] - origin[2]) / pitch)) + 1, 0), n2)
        if _box_sum(C, x0 // k, y0 // k, z0 // k, -(-x1 // k), -(-y1 // k), -(-z1 // k)) == 0:
            out[i] = False
            continue
        out[i] = _box_sum(T, x0, y0, z0, x1, y1, z1) > 0


@dataclass(frozen=True, eq=False)
class StaticModel:
    """The empty cell's regions, their plausibility verdicts and their distance model.

    Attributes:
        cameras: Every camera's static data, in the cell's order.
        zone: Z as a manifold.
        solids: The union of the solid obstacles O(j).
        free: F_static(i) per camera, clipped to the zone's box.
        hull: C_static = Z minus the union (k-of-n) of the F_static(i).
        region_r2: C_static minus the solids.
        region: R3_static: without its noise sheets and implausible components.
        removed: What the static plausibility removed, each with its rule.
        sheets: The surfaces whose sheets were judged.
        sheet_heights: Per sheet, the height map of C_static inside its slab
            (:func:`sheet_heights`): what a sheet box under a kept piece restores.
        touch: Voxels within ``support_eps`` of R3_static.
        hull_volume: Volume of C_static [m^3].

    :attr:`bvh`, one python-fcl BVH of all of R3_static, is built when first read (the
    engine measures against chunks of it: :class:`polyhull.distance.ChunkedMesh`).
    """

    cameras: tuple[StaticCamera, ...]
    zone: m3.Manifold
    solids: m3.Manifold
    free: tuple[m3.Manifold, ...]
    hull: m3.Manifold
    region_r2: m3.Manifold
    region: m3.Manifold
    removed: tuple[RemovedComponent, ...]
    sheets: tuple[Sheet, ...]
    sheet_heights: tuple[np.ndarray, ...]
    touch: TouchGrid
    hull_volume: float

    @functools.cached_property
    def bvh(self) -> fcl.CollisionObject | None:
        """A python-fcl object of R3_static (None when it is empty), built on first use."""
        from ..distance import manifold_to_fcl

        return manifold_to_fcl(self.region)

    @functools.cached_property
    def region_removed(self) -> m3.Manifold:
        """R2_static minus R3_static, what the static rules removed (the noise sheets over
        the surfaces, mostly), built on first use: a sheet box kept under a piece adds its
        part of this to the region (:meth:`polyhull.verdict.Verdict.region_dynamic_drawing`)."""
        return self.region_r2 - self.region

    @classmethod
    def load_or_build(
        cls, cell: Cell, references: dict[str, np.ndarray], cache_dir: Path | None = None
    ) -> StaticModel:
        """:meth:`build`, through an on-disk cache when the build is slow.

        The cache file is named by a digest of everything the model depends on: the
        cell's cameras, zone, obstacles (their meshes) and parameters, the reference
        images, the taught background, the cache format, polyhull's version, the sources
        of the modules that build it (this one and every module of the package it imports,
        :func:`polyhull.cachedir.imported_sources_digest`) and manifold3d's version; any
        change gives a new name, so a stale entry can never be read. The directory is
        ``$POLYHULL_CACHE_DIR``, else ``$XDG_CACHE_HOME/polyhull``, else
        ``~/.cache/polyhull``; ``POLYHULL_CACHE_DIR=off`` disables it. Only models that
        took longer than ``CACHE_AFTER`` seconds are written.

        The ``polyhull`` logger says what happens (the command line shows it on stderr):
        a build and where its model is cached at INFO, a read from the cache at DEBUG,
        and at WARNING an entry that could not be read (it is rebuilt) or written (every
        monitor of the cell then builds it again).
        """
        directory = cache_dir if cache_dir is not None else cache_directory()
        path = None if directory is None else directory / f"static-{model_key(cell, references)}.npz"
        if path is not None and path.is_file():
            try:
                model = cls._load(cell, references, path)
                log.debug("static model of cell '%s' read from %s", cell.name, path)
                return model
            except Exception as exc:  # noqa: BLE001 - a damaged entry is rebuilt, never trusted
                log.warning("static model cache entry %s could not be read (%s); rebuilding it", path, exc)
                path.unlink(missing_ok=True)
        log.info("building the static model of cell '%s'", cell.name)
        t0 = time.perf_counter()
        model = cls.build(cell, references)
        took = time.perf_counter() - t0
        if path is None:
            log.info("static model built in %.1f s; not cached (POLYHULL_CACHE_DIR is off)", took)
        elif took <= CACHE_AFTER:
            log.info("static model built in %.1f s; not cached (a build of %.0f s or less)", took, CACHE_AFTER)
        else:
            try:
                model._save(path)
                log.info("static model built in %.1f s; cached in %s (read by later monitors of this cell)", took, path)
            except OSError as exc:
                log.warning(
                    "static model built in %.1f s but not cached: cannot write %s (%s); every monitor of "
                    "this cell builds it again (set POLYHULL_CACHE_DIR to a writable folder)", took, path, exc,
                )
        return model

    def _save(self, path: Path) -> None:
        arrays: dict[str, np.ndarray] = {}
        for name in ("hull", "region_r2", "region", "solids"):
            arrays[f"{name}_v"], arrays[f"{name}_t"] = _mesh(getattr(self, name))
        for i, f in enumerate(self.free):
            arrays[f"free{i}_v"], arrays[f"free{i}_t"] = _mesh(f)
        for i, r in enumerate(self.removed):
            arrays[f"removed{i}_v"], arrays[f"removed{i}_t"] = _mesh(r.mesh)
        arrays["removed_rule"] = np.array([r.rule for r in self.removed], dtype=str)
        arrays["removed_volume"] = np.array([r.volume for r in self.removed], dtype=np.float64)
        arrays["removed_centroid"] = np.array([r.centroid for r in self.removed], dtype=np.float64).reshape(-1, 3)
        arrays["sheet_names"] = np.array([s.name for s in self.sheets], dtype=str)
        arrays["sheet_numbers"] = np.array(
            [[s.axis, s.sign, s.level, *s.lo, *s.hi, s.height] for s in self.sheets], dtype=np.float64
        ).reshape(-1, 8)
        for i, h in enumerate(self.sheet_heights):
            arrays[f"sheet_heights{i}"] = h
        arrays["touch_origin"] = self.touch.origin
        arrays["touch_pitch"] = np.array(self.touch.pitch)
        arrays["touch_table"] = self.touch.table
        arrays["hull_volume"] = np.array(self.hull_volume)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez_compressed(tmp, **arrays)  # type: ignore[arg-type]
        os.replace(tmp, path)

    @classmethod
    def _load(cls, cell: Cell, references: dict[str, np.ndarray], path: Path) -> StaticModel:
        with np.load(path, allow_pickle=False) as data:
            block = cell.reconstruction.block
            cams = tuple(
                StaticCamera.build(c, references[c.name], block, _taught(cell, c.name)) for c in cell.cameras
            )
            mf = {n: _manifold(data[f"{n}_v"], data[f"{n}_t"]) for n in ("hull", "region_r2", "region", "solids")}
            free = tuple(_manifold(data[f"free{i}_v"], data[f"free{i}_t"]) for i in range(len(cams)))
            removed = tuple(
                RemovedComponent(
                    str(rule), float(vol), cen, _manifold(data[f"removed{i}_v"], data[f"removed{i}_t"])
                )
                for i, (rule, vol, cen) in enumerate(
                    zip(data["removed_rule"], data["removed_volume"], data["removed_centroid"], strict=True)
                )
            )
            sheets = tuple(
                Sheet(str(n), int(a), int(sg), float(lv), (float(l0), float(l1)), (float(h0), float(h1)), float(h))
                for n, (a, sg, lv, l0, l1, h0, h1, h) in zip(data["sheet_names"], data["sheet_numbers"], strict=True)
            )
            heights = tuple(np.asarray(data[f"sheet_heights{i}"]) for i in range(len(sheets)))
            touch = TouchGrid(np.asarray(data["touch_origin"]), float(data["touch_pitch"]), np.asarray(data["touch_table"]))
            hull_volume = float(data["hull_volume"])
        return cls(
            cameras=cams,
            zone=cell.zone.manifold(),
            solids=mf["solids"],
            free=free,
            hull=mf["hull"],
            region_r2=mf["region_r2"],
            region=mf["region"],
            removed=removed,
            sheets=sheets,
            sheet_heights=heights,
            touch=touch,
            hull_volume=hull_volume,
        )

    @classmethod
    def build(cls, cell: Cell, references: dict[str, np.ndarray]) -> StaticModel:
        """Precompute the static model of ``cell`` from the references (H, W) [m]."""
        from ..errors import PolyhullError

        block = cell.reconstruction.block
        cams = []
        for cam in cell.cameras:
            if cam.name not in references:
                raise PolyhullError(f"no reference depth for camera '{cam.name}'")
            cams.append(StaticCamera.build(cam, references[cam.name], block, _taught(cell, cam.name)))
        zone = cell.zone.manifold()
        box = _zone_box(zone, 0.01)
        free = tuple(s.free_region() ^ box for s in cams)
        k = cell.reconstruction.k_of_n
        fused = free_union([f for f in free if not f.is_empty()], k)
        hull = check_manifold(zone - fused, "static hull C_static")
        solids_list = [o.manifold() for o in cell.solid_obstacles]
        solids = m3.Manifold.batch_boolean(solids_list, m3.OpType.Add) if solids_list else m3.Manifold()
        r2 = check_manifold(hull - solids, "static region R2_static")
        p = cell.plausibility
        sheets = measured_sheets(cell, cams) if p.floor_shell else ()
        heights = tuple(sheet_heights(sh, lambda pts: _hull_contains(cams, pts, k)) for sh in sheets)
        rest, removed_sheets = remove_sheets(r2, sheets, removal_depths(cell, sheets), p.floor_shell_margin, solids)
        support = (
            m3.Manifold.batch_boolean([o.manifold() for o in cell.obstacles], m3.OpType.Add)
            if cell.obstacles
            else m3.Manifold()
        )
        ctx = PlausibilityContext(
            zone=cell.zone,
            params=p,
            support=support,
            known_objects=tuple(o.manifold() for o in cell.obstacles),
        )
        result = apply_plausibility(rest, ctx)
        region = check_manifold(result.region, "static region R3_static")
        lo = np.asarray(cell.zone.min) - 0.1
        hi = np.asarray(cell.zone.max) + 0.1
        touch = TouchGrid.within(region, lo, hi, pitch=0.05, distance=p.support_eps)
        return cls(
            cameras=tuple(cams),
            zone=zone,
            solids=solids,
            free=free,
            hull=hull,
            region_r2=r2,
            region=region,
            removed=tuple(removed_sheets) + tuple(result.removed),
            sheets=sheets,
            sheet_heights=heights,
            touch=touch,
            hull_volume=float(hull.volume()),
        )

    def boxes_meet(
        self, lo: ArrayF64, hi: ArrayF64, distance: float, groups: np.ndarray | None = None, n_groups: int = 1
    ) -> np.ndarray:
        """(G,) for each group of axis-aligned boxes [lo, hi] (N, 3) [m], whether some box of
        the group, grown by ``distance`` [m] on every side, meets the surface of R3_static.

        A grown box that does not meet it lies wholly outside R3_static, so everything in
        the box [lo, hi] is farther than ``distance`` from R3_static, or wholly inside it.
        Each grown box is tested exactly against the triangles of R3_static's mesh in the
        grid cells it meets (:func:`polyhull.engine.boxes.groups_meet_triangles`: a solid
        box against the triangles, so a box that holds a whole static component meets it
        too), until each group has one that meets it. The boxes grow by a further
        ``BOX_MEET_TOLERANCE`` (relative to the coordinates' magnitude) so that rounding
        never turns a touching box into one that does not meet: the answer holds every box
        that python-fcl's box-against-mesh collision finds meeting, and more only for
        boxes within about ``BOX_MEET_TOLERANCE`` times the coordinates of the surface.

        Args:
            lo: (N, 3) box minima [m].
            hi: (N, 3) box maxima [m].
            distance: Growth of the boxes [m].
            groups: (N,) the group 0..G-1 of each box; None: all boxes are one group.
            n_groups: G.
        """
        out = np.zeros(n_groups, dtype=bool)
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        grid = self._triangle_grid
        if grid is None or len(lo) == 0:
            return out
        groups = np.zeros(len(lo), dtype=np.int64) if groups is None else np.asarray(groups, dtype=np.int64)
        scale = np.maximum(np.abs(lo).max(axis=1), np.abs(hi).max(axis=1))
        grow = (distance + BOX_MEET_TOLERANCE * (1.0 + scale))[:, None]
        return groups_meet_triangles(grid, lo - grow, hi + grow, groups, n_groups)

    def prepare(self) -> None:
        """Build now what the cycles would build on first use (the triangle grid of
        :meth:`boxes_meet`, and its compiled kernel loaded by one query), so that no cycle
        pays for it."""
        _ = self._triangle_grid
        _ = self.touch.coarse
        corner = np.asarray(self.zone.bounding_box()[:3], dtype=np.float64).reshape(1, 3)
        self.boxes_meet(corner, corner + 0.01, 0.01, np.zeros(1, dtype=np.int64), 1)

    @functools.cached_property
    def _triangle_grid(self) -> TriangleGrid | None:
        """R3_static's triangles in a uniform grid (built on first use), None when empty."""
        if self.region.is_empty():
            return None
        vertices, triangles = _mesh(self.region)
        return TriangleGrid.of(vertices, triangles)

    def hull_contains(self, points_world: ArrayF64, k_of_n: int = 1) -> np.ndarray:
        """(N,) whether points lie in C_static: fewer than k cameras' static surfaces free them.

        The independent point oracle of the static mesh (the same surfaces, no booleans).
        """
        return _hull_contains(self.cameras, points_world, k_of_n)


def _taught(cell: Cell, name: str) -> TaughtCamera | None:
    """The taught background of camera ``name`` of ``cell``, if it has one."""
    return None if cell.background is None else cell.background.get(name)


def _hull_contains(cameras: Sequence[StaticCamera], points_world: ArrayF64, k_of_n: int) -> np.ndarray:
    pts = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    count = np.zeros(len(pts), dtype=np.int64)
    for s in cameras:
        z, surf = s.surface_depth(pts)
        count += (z > s.camera.near) & (z < surf)
    return count < k_of_n


log = logging.getLogger(__name__)

CACHE_AFTER = 2.0
"""Static models that take longer than this [s] to build are cached on disk."""

_CACHE_FORMAT = b"polyhull-static-model-10"


def model_key(cell: Cell, references: dict[str, np.ndarray]) -> str:
    """A digest of everything the static model depends on (see :meth:`StaticModel.load_or_build`)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(_CACHE_FORMAT)
    from .. import __version__

    h.update(__version__.encode())
    # the code that builds the model (this module and what it imports, so an edit needs no
    # version bump) and the geometry kernel's version
    h.update(imported_sources_digest(__name__).encode())
    h.update(_distribution_version("manifold3d").encode())
    h.update(repr((cell.zone, cell.reconstruction, cell.plausibility)).encode())
    for cam in cell.cameras:
        h.update(
            repr((cam.name, cam.kind, cam.intrinsics, cam.near, cam.far, cam.noise, cam.tolerance_sigmas, cam.tolerance_min)).encode()
        )
        h.update(np.ascontiguousarray(cam.T_world_camera, dtype=np.float64).tobytes())
        ref = references.get(cam.name)
        h.update(b"-" if ref is None else np.ascontiguousarray(ref, dtype=np.float64).tobytes())
    h.update(b"no taught background" if cell.background is None else cell.background.digest())
    for o in cell.obstacles:
        h.update(repr((o.name, o.solid)).encode())
        h.update(np.ascontiguousarray(o.mesh.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(o.mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _distribution_version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _mesh(m: m3.Manifold) -> tuple[np.ndarray, np.ndarray]:
    if m.is_empty():
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _manifold(v: np.ndarray, t: np.ndarray) -> m3.Manifold:
    if len(t) == 0:
        return m3.Manifold()
    m = m3.Manifold(m3.Mesh64(vert_properties=np.asarray(v, dtype=np.float64), tri_verts=np.asarray(t, dtype=np.uint32)))
    return check_manifold(m, "cached static model")


def _zone_box(zone: m3.Manifold, margin: float) -> m3.Manifold:
    bb = zone.bounding_box()
    lo = [float(x) - margin for x in bb[:3]]
    hi = [float(x) + margin for x in bb[3:]]
    return m3.Manifold.cube([b - a for a, b in zip(lo, hi, strict=True)]).translate(lo)
