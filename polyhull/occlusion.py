"""The robot occlusion M (paper 3.2, SPEC section 2).

``M = F_static \\ F_static+robot``: points some camera sees free in the empty cell but no
camera sees free once the robot stands at q. With ``S_i`` the robot's shadow from camera i
(its body and everything behind it up to the far plane), ``F_static+robot(i) = F_static(i) \\ S_i``.
The shadow of a convex body from a point is convex, so a convex link piece P casts
``hull(P U proj_far(P))``.

Link pieces are grown by the robot padding (a declared tolerance that absorbs depth noise
in front of robot surfaces and the block resolution of camera regions) with the Minkowski
sum of a cube of half-size ``padding``: every face moves out by at least ``padding`` and no
point by more than ``padding * sqrt(3)``, the margin the monitor adds to the protective
separation distance.

Per camera, each shadow is grown further by the reach of the camera's block construction
(:func:`resolution_growth`): a measurement consistent with the robot leaves a band of about
``2 tau`` in front of its surfaces and up to two blocks beside its silhouette unfree. That
band is as unobservable as the shadow itself; like the shadow, nobody can enter it without
first being seen in R, and the shadow memory of the monitor keeps such a person in R.
"""

from __future__ import annotations

from collections.abc import Sequence

import manifold3d as m3
import numpy as np

from .camera import Camera
from .regions import check_manifold
from .typed import ArrayF64

__all__ = ["grow_piece", "resolution_growth", "shadow_hull", "robot_shadows", "robot_occlusion"]

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


def resolution_growth(camera: Camera, block: int, depth: float) -> tuple[float, float]:
    """How far the camera's region construction can reach beyond a surface at ``depth`` [m].

    A block takes the minimum free depth of its pixels and a grid corner the minimum of
    its blocks, so a surface seen in a block shortens the free depth up to two blocks
    sideways: ``lateral = 2 * sqrt(2) * block * depth / f``. Along the ray, a measurement
    consistent with the surface frees up to about ``2 * tau`` in front of it.

    Returns:
        (lateral [m], toward the camera [m]).
    """
    f = min(camera.intrinsics.fx, camera.intrinsics.fy)
    lateral = 2.0 * np.sqrt(2.0) * block * depth / f
    toward = 2.0 * float(camera.tau(depth))
    return lateral, toward


def shadow_hull(
    camera: Camera, vertices_world: ArrayF64, block: int = 0
) -> m3.Manifold | None:
    """The shadow of a convex piece from ``camera`` up to its far plane, or None.

    With ``block > 0`` the piece is first grown by :func:`resolution_growth` at its farthest
    depth (a cube sideways, a pull toward the camera), so the shadow covers what the
    camera's block construction leaves unfree around the piece.

    Returns None when part of the piece is not in front of the camera (a piece straddling
    the camera plane casts no bounded convex shadow); leaving a shadow out only shrinks M,
    which keeps the region conservative.
    """
    pc = camera.world_to_camera(vertices_world)
    z = pc[:, 2]
    if np.any(z <= 1e-6):
        return None
    if block > 0:
        lateral, toward = resolution_growth(camera, block, float(z.max()))
        grown = (pc[:, None, :] + lateral * _CUBE[None, :, :]).reshape(-1, 3)
        zg = grown[:, 2]
        if np.any(zg <= 1e-6):
            return None
        pulled = grown * np.maximum(1.0 - toward / zg, 1e-3)[:, None]
        pc = np.concatenate([grown, pulled])
        z = pc[:, 2]
    far_pts = pc * (camera.far / z)[:, None]
    far_pts = far_pts[z < camera.far]
    pts = camera.camera_to_world(np.concatenate([pc, far_pts]))
    hull = m3.Manifold.hull_points(pts)
    return None if hull.is_empty() else hull


def robot_shadows(
    camera: Camera, pieces_world: Sequence[ArrayF64], block: int = 0
) -> list[m3.Manifold]:
    """Shadows of the (already padded) convex robot pieces from one camera."""
    out = []
    for piece in pieces_world:
        h = shadow_hull(camera, piece, block)
        if h is not None:
            out.append(h)
    return out


def robot_occlusion(
    cameras: Sequence[Camera],
    free_static: Sequence[m3.Manifold],
    free_static_union: m3.Manifold,
    pieces_world: Sequence[ArrayF64],
    block: int = 0,
) -> m3.Manifold:
    """The robot occlusion M (world frame).

    Args:
        cameras: The cameras, in the order of ``free_static``.
        free_static: F_static(i), the free region of each camera in the empty cell.
        free_static_union: The union of ``free_static`` (precomputed).
        pieces_world: Padded convex robot pieces at q, (K, 3) world vertices each.
        block: Block side [px] of the camera regions; > 0 grows each shadow by what the
            block construction leaves unfree around the robot (:func:`resolution_growth`),
            so that measured noise bands in front of the robot fall into M.
    """
    if not pieces_world:
        return m3.Manifold()
    seen_with_robot = []
    for cam, free in zip(cameras, free_static, strict=True):
        if free.is_empty():
            continue
        shadows = robot_shadows(cam, pieces_world, block)
        seen_with_robot.append(m3.Manifold.batch_boolean([free, *shadows], m3.OpType.Subtract))
    occlusion = m3.Manifold.batch_boolean([free_static_union, *seen_with_robot], m3.OpType.Subtract)
    return check_manifold(occlusion, "robot occlusion M")
