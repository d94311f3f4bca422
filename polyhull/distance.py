"""Minimum distance between the region R and the robot with python-fcl.

Robot links are FCL BVH models built once in their link frames; each cycle only their
transforms change. The region is a fresh BVH each cycle. FCL returns -1 or 0 for objects in
collision and its witness points are unreliable there, so a distance <= 0 is contact, and a
fresh ``DistanceResult`` is built for every query.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple

import fcl
import manifold3d as m3
import numpy as np
import trimesh

from .errors import GeometryError
from .typed import ArrayF64

__all__ = ["DistanceResult", "RobotDistanceModel", "manifold_to_fcl"]


class DistanceResult(NamedTuple):
    """Minimum distance between the region and the robot.

    Attributes:
        distance: Minimum distance [m]; inf when the region is empty; 0 on contact.
        points: (2, 3) closest points [m] (on the region, on the robot), or None.
        link: Name of the closest robot link, or None.
    """

    distance: float
    points: ArrayF64 | None
    link: str | None


def _bvh(vertices: ArrayF64, faces: np.ndarray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int32))
    model.endModel()
    return model


def manifold_to_fcl(region: m3.Manifold) -> fcl.CollisionObject | None:
    """An FCL collision object of a manifold's triangles (world frame), None if empty."""
    if region.is_empty():
        return None
    mesh = region.to_mesh64()
    verts = np.asarray(mesh.vert_properties)[:, :3]
    tris = np.asarray(mesh.tri_verts)
    return fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())


class RobotDistanceModel:
    """FCL models of the robot links, for distance queries at changing joint positions."""

    def __init__(self, link_geometry: Mapping[str, trimesh.Trimesh]) -> None:
        """Build one BVH per link.

        Args:
            link_geometry: Collision mesh per link in the link frame.
        """
        self._objects: dict[str, fcl.CollisionObject] = {}
        for name, mesh in link_geometry.items():
            if len(mesh.faces) == 0:
                continue
            self._objects[name] = fcl.CollisionObject(_bvh(mesh.vertices, mesh.faces), fcl.Transform())

    @property
    def link_names(self) -> tuple[str, ...]:
        """Links with geometry."""
        return tuple(self._objects)

    def distance(self, region: m3.Manifold, T_world_links: Mapping[str, ArrayF64]) -> DistanceResult:
        """Minimum distance between ``region`` and the robot at the given link poses.

        Raises:
            GeometryError: FCL failed.
        """
        region_obj = manifold_to_fcl(region)
        if region_obj is None:
            return DistanceResult(math.inf, None, None)
        best = DistanceResult(math.inf, None, None)
        request = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=False)
        for name, obj in self._objects.items():
            T = T_world_links[name]
            obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
            result = fcl.DistanceResult()
            try:
                d = float(fcl.distance(region_obj, obj, request, result))
            except Exception as exc:  # FCL raises plain RuntimeErrors
                raise GeometryError(f"FCL distance to link '{name}' failed: {exc}") from exc
            if not math.isfinite(d):
                raise GeometryError(f"FCL distance to link '{name}' is not finite: {d}")
            if d <= 0.0:
                return DistanceResult(0.0, None, name)
            if d < best.distance:
                pts = np.array([result.nearest_points[0], result.nearest_points[1]], dtype=np.float64)
                best = DistanceResult(d, pts, name)
        return best
