"""The robot occlusion M (paper 3.2, SPEC section 2).

``M = F_static \\ F_static+robot``: points some camera sees free in the empty cell but no
camera sees free once the robot stands at q. With ``S_i`` the robot's shadow from camera i
(its body and everything behind it up to the far plane), ``F_static+robot(i) = F_static(i) \\ S_i``.
The shadow of a convex body from a point is convex, so a convex link piece P casts
``hull(P U proj_far(P))``.

Link pieces are grown by the robot padding (a declared tolerance that absorbs depth noise
in front of robot surfaces and the block resolution of camera regions) with the Minkowski
sum of an octahedron of radius ``padding``: it grows every face by at most ``padding``.
The monitor adds the padding to the protective separation distance.
"""

from __future__ import annotations

from collections.abc import Sequence

import manifold3d as m3
import numpy as np

from .camera import Camera
from .regions import check_manifold
from .typed import ArrayF64

__all__ = ["grow_piece", "shadow_hull", "robot_shadows", "robot_occlusion"]

_OCTAHEDRON = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
)


def grow_piece(vertices: ArrayF64, padding: float) -> ArrayF64:
    """Vertices (6K, 3) of a convex piece (K, 3) grown by an octahedron of radius ``padding``."""
    v = np.asarray(vertices, dtype=np.float64)
    if padding <= 0:
        return v
    return (v[:, None, :] + padding * _OCTAHEDRON[None, :, :]).reshape(-1, 3)


def shadow_hull(camera: Camera, vertices_world: ArrayF64) -> m3.Manifold | None:
    """The shadow of a convex piece from ``camera`` up to its far plane, or None.

    Returns None when part of the piece is not in front of the camera (a piece straddling
    the camera plane casts no bounded convex shadow); leaving a shadow out only shrinks M,
    which keeps the region conservative.
    """
    pc = camera.world_to_camera(vertices_world)
    z = pc[:, 2]
    if np.any(z <= 1e-6):
        return None
    far_pts = pc * (camera.far / z)[:, None]
    far_pts = far_pts[z < camera.far]
    pts = camera.camera_to_world(np.concatenate([pc, far_pts]))
    hull = m3.Manifold.hull_points(pts)
    return None if hull.is_empty() else hull


def robot_shadows(camera: Camera, pieces_world: Sequence[ArrayF64]) -> list[m3.Manifold]:
    """Shadows of the (already grown) convex robot pieces from one camera."""
    out = []
    for piece in pieces_world:
        h = shadow_hull(camera, piece)
        if h is not None:
            out.append(h)
    return out


def robot_occlusion(
    cameras: Sequence[Camera],
    free_static: Sequence[m3.Manifold],
    free_static_union: m3.Manifold,
    pieces_world: Sequence[ArrayF64],
) -> m3.Manifold:
    """The robot occlusion M (world frame).

    Args:
        cameras: The cameras, in the order of ``free_static``.
        free_static: F_static(i), the free region of each camera in the empty cell.
        free_static_union: The union of ``free_static`` (precomputed).
        pieces_world: Grown convex robot pieces at q, (K, 3) world vertices each.
    """
    if not pieces_world:
        return m3.Manifold()
    seen_with_robot = []
    for cam, free in zip(cameras, free_static, strict=True):
        if free.is_empty():
            continue
        shadows = robot_shadows(cam, pieces_world)
        seen_with_robot.append(m3.Manifold.batch_boolean([free, *shadows], m3.OpType.Subtract))
    occlusion = m3.Manifold.batch_boolean([free_static_union, *seen_with_robot], m3.OpType.Subtract)
    return check_manifold(occlusion, "robot occlusion M")
