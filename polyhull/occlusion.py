"""The robot occlusion M as a manifold (paper 3.2), for inspection.

``M = F_static \\ F_static+robot``: points some camera sees free in the empty cell but no
camera sees free once the robot stands at q. With ``S_i`` the robot's shadow from camera i
(its body and everything behind it up to the far plane), ``F_static+robot(i) = F_static(i) \\ S_i``.
The shadow of a convex body from a point is convex, so a convex link piece P casts
``hull(P U proj_far(P))``.

The cycle does not build this manifold: it works per pixel with the raster of
:mod:`polyhull.engine.robot_raster`. :attr:`polyhull.Verdict.robot_occlusion` builds it
when read, from the same padded pieces, each shadow starting ``band(z)`` [m] before the
piece (the raster's tolerance band), so that it shows the same set at the resolution of the
pieces rather than of the pixels.

Link pieces are padded (``robot.padding``) with the Minkowski sum of a cube of half-size
``padding`` (:func:`grow_piece`): every face moves out by at least ``padding`` and no point
by more than ``padding * sqrt(3)``, the margin the monitor adds to the protective
separation distance.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import manifold3d as m3
import numpy as np

from .camera import Camera
from .regions import check_manifold
from .typed import ArrayF64

__all__ = ["grow_piece", "shadow_hull", "robot_shadows", "robot_occlusion"]

_CUBE = np.array(
    [[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)], dtype=np.float64
)


def grow_piece(vertices: ArrayF64, padding: float) -> ArrayF64:
    """Vertices (8K, 3) of a convex piece (K, 3) grown by a cube of half-size ``padding``.

    The Minkowski sum with the cube moves every face out by at least ``padding`` and no
    point by more than ``padding * sqrt(3)``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if padding <= 0:
        return v
    return (v[:, None, :] + padding * _CUBE[None, :, :]).reshape(-1, 3)


def shadow_hull(
    camera: Camera,
    vertices_world: ArrayF64,
    band: Callable[[ArrayF64], ArrayF64] | None = None,
) -> m3.Manifold | None:
    """The shadow of a convex piece from ``camera`` up to its far plane, or None.

    Args:
        camera: The camera.
        vertices_world: (K, 3) vertices of the convex piece [m].
        band: Optional map from z-depth [m] to how far [m] before the piece the shadow
            starts along each ray (the piece's vertices are pulled toward the camera by it).

    Returns None when part of the piece is not in front of the camera (a piece straddling
    the camera plane casts no bounded convex shadow).
    """
    pc = camera.world_to_camera(vertices_world)
    z = pc[:, 2]
    if np.any(z <= 1e-6):
        return None
    if band is not None:
        pulled = pc * np.maximum(1.0 - np.asarray(band(z)) / z, 1e-3)[:, None]
        pc = np.concatenate([pc, pulled])
        z = pc[:, 2]
    far_pts = pc * (camera.far / z)[:, None]
    far_pts = far_pts[z < camera.far]
    pts = camera.camera_to_world(np.concatenate([pc, far_pts]))
    hull = m3.Manifold.hull_points(pts)
    return None if hull.is_empty() else hull


def robot_shadows(
    camera: Camera,
    pieces_world: Sequence[ArrayF64],
    band: Callable[[ArrayF64], ArrayF64] | None = None,
) -> list[m3.Manifold]:
    """Shadows of the (already padded) convex robot pieces from one camera."""
    out = []
    for piece in pieces_world:
        h = shadow_hull(camera, piece, band)
        if h is not None:
            out.append(h)
    return out


def robot_occlusion(
    cameras: Sequence[Camera],
    free_static: Sequence[m3.Manifold],
    zone: m3.Manifold,
    pieces_world: Sequence[ArrayF64],
    bands: Sequence[Callable[[ArrayF64], ArrayF64] | None] | None = None,
) -> m3.Manifold:
    r"""The robot occlusion M (world frame), by booleans only near the robot's shadows.

    A point of M is free in the empty cell for some camera j and not free with the robot,
    so it lies in j's shadow S_j: M lies in ``U = (S_1 U ... U S_n) ^ zone``, and with
    ``F_i' = F_static(i) ^ U``, ``M = (F_1' U ... U F_n') \ ((F_1' \ S_1) U ... U (F_n' \ S_n))``,
    the same set as ``F_static \ F_static+robot`` (the whole-image free regions meet only
    the small U: seconds, where their union over the whole zone took tens of seconds).

    Args:
        cameras: The cameras, in the order of ``free_static``.
        free_static: F_static(i), the free region of each camera in the empty cell.
        zone: The work cell Z.
        pieces_world: Padded convex robot pieces at q, (K, 3) world vertices each.
        bands: Per camera, the shadow's band before the pieces (see :func:`shadow_hull`).
    """
    if not pieces_world:
        return m3.Manifold()
    bands = list(bands) if bands is not None else [None] * len(cameras)
    shadows = [robot_shadows(cam, pieces_world, band) for cam, band in zip(cameras, bands, strict=True)]
    every = [s for per_camera in shadows for s in per_camera]
    if not every:
        return m3.Manifold()
    near = m3.Manifold.batch_boolean(every, m3.OpType.Add) ^ zone
    free_near, seen_with_robot = [], []
    for free, own in zip(free_static, shadows, strict=True):
        if free.is_empty():
            continue
        f = free ^ near
        free_near.append(f)
        seen_with_robot.append(m3.Manifold.batch_boolean([f, *own], m3.OpType.Subtract))
    if not free_near:
        return m3.Manifold()
    free_static_near = m3.Manifold.batch_boolean(free_near, m3.OpType.Add)
    occlusion = m3.Manifold.batch_boolean([free_static_near, *seen_with_robot], m3.OpType.Subtract)
    return check_manifold(occlusion, "robot occlusion M")
