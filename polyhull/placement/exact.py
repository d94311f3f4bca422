"""Exact polyhedral evaluation of the placement objectives (paper section 4).

The same labels as the voxel version (:mod:`polyhull.placement.labels`), but as solids
built by the engine and measured by mesh booleans instead of counted voxels:

- ``F(i)`` is the engine's target-free region of camera ``i``
  (:func:`polyhull.regions.free_region_from_depth` of its free depth image, one pixel per
  block); ``F`` is their union, or the k-of-n fusion (:func:`polyhull.fusion.free_union`);
- the cone of camera ``i`` over its changed pixels is built by the same function with free
  depth ``far`` on changed pixels and ``near`` elsewhere; ``K(i) = cone(i) \\ F(i)`` are
  the points camera ``i`` calls changed;
- ``F' = (F & Z) \\ S \\ T`` (static solids S are always undetectable, targets T never
  target-free), ``changed = ((Z \\ F') & union_i K(i)) \\ S``,
  ``undetectable = Z \\ F' \\ changed``.

The engine builds ``F(i)`` conservatively: its surface over a pixel interpolates corner
values that are the minimum over the adjacent pixels, so ``F(i)`` lies between the
per-pixel prisms of the free depth eroded by a 3 x 3 minimum and those of the free depth
itself. The voxel labels sample the latter; the tests bracket the exact volumes by the
voxel volumes of both images, widened by the boundary voxels
(:func:`~polyhull.placement.labels.boundary_mask`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import manifold3d as m3
import numpy as np

from ..camera import Camera
from ..cell import Zone, mesh_to_manifold
from ..errors import GeometryError
from ..fusion import free_union
from ..raycast import StaticScene
from ..regions import check_manifold, free_region_from_depth
from ..typed import ArrayBool, ArrayF32, ArrayF64
from .labels import free_depth_image
from .objectives import Importance, Objectives, PlacementProblem

__all__ = [
    "ExactRegions",
    "changed_cone",
    "exact_regions",
    "exact_objectives",
    "weighted_volume",
]


@dataclass(frozen=True, eq=False)
class ExactRegions:
    """The three sections of Z as solids (world frame), for one target scene.

    Attributes:
        free: Target-free region F' (plain or k-of-n rule).
        changed: Changed region.
        undetectable: Undetectable region (contains the static solids in Z).
        static: Static solids within Z.
        targets: Targets within Z, outside the static solids.
    """

    free: m3.Manifold
    changed: m3.Manifold
    undetectable: m3.Manifold
    static: m3.Manifold
    targets: m3.Manifold

    def volumes(self) -> dict[str, float]:
        """Volumes [m^3] of every region by name."""
        return {name: float(getattr(self, name).volume()) for name in self.__dataclass_fields__}


def changed_cone(camera: Camera, changed: ArrayBool) -> m3.Manifold:
    """The part of the frustum behind the changed pixels, ``[near, far]`` along their rays.

    Args:
        camera: The camera.
        changed: (H, W) changed-pixel mask at full resolution.

    Returns:
        The cone (world frame), possibly empty.
    """
    mask = np.asarray(changed, dtype=bool)
    free = np.where(mask, camera.far, camera.near)
    return free_region_from_depth(camera, free, block=1)


def _union(parts: Sequence[m3.Manifold]) -> m3.Manifold:
    parts = [p for p in parts if not p.is_empty()]
    if not parts:
        return m3.Manifold()
    return m3.Manifold.batch_boolean(list(parts), m3.OpType.Add)


def exact_regions(
    cameras: Sequence[Camera],
    zone: Zone,
    free_depths: Sequence[ArrayF32 | ArrayF64],
    changed: Sequence[ArrayBool],
    k: int = 1,
    static_solids: Sequence[m3.Manifold] = (),
    targets: Sequence[m3.Manifold] = (),
) -> ExactRegions:
    """Label Z exactly for per-camera free depth images and change masks (one scene).

    Args:
        cameras: The cameras.
        zone: The work cell Z.
        free_depths: Per camera (H, W) free depth [m] at full resolution
            (:func:`~polyhull.placement.labels.free_depth_image`).
        changed: Per camera (H, W) changed-pixel mask.
        k: k of the k-of-n rule (1: plain union).
        static_solids: Static obstacles (world frame).
        targets: Targets (world frame).

    Returns:
        The regions of Z.
    """
    if not (len(cameras) == len(free_depths) == len(changed)):
        raise GeometryError(
            f"need one free depth image and one change mask per camera, got {len(cameras)} "
            f"cameras, {len(free_depths)} images, {len(changed)} masks"
        )
    Z = zone.manifold()
    S = check_manifold(_union(static_solids) ^ Z, "static solids within Z")
    T = check_manifold((_union(targets) ^ Z) - S, "targets within Z")
    free_i = [
        free_region_from_depth(cam, np.asarray(f, dtype=np.float64), block=1)
        for cam, f in zip(cameras, free_depths, strict=True)
    ]
    behind_i = [
        changed_cone(cam, ch) - F for cam, ch, F in zip(cameras, changed, free_i, strict=True)
    ]
    F = check_manifold(
        m3.Manifold.batch_boolean([free_union(free_i, k) ^ Z, S, T], m3.OpType.Subtract),
        "target-free region",
    )
    not_free = Z - F
    C = check_manifold((not_free ^ _union(behind_i)) - S, "changed region")
    U = check_manifold(not_free - C, "undetectable region")
    return ExactRegions(free=F, changed=C, undetectable=U, static=S, targets=T)


def weighted_volume(region: m3.Manifold, importance: Importance | None) -> float:
    """Importance-weighted volume of a region [m^3 x weight] (region weights only).

    Regions override the default weight in order (later regions win), as in
    :meth:`Importance.weights`.
    """
    if importance is None:
        return float(region.volume())
    if importance.field is not None:
        raise GeometryError(
            "the exact f2 needs importance given as regions (boxes); a per-voxel field has no "
            "exact volume"
        )
    total = 0.0
    remaining = region
    for r in reversed(importance.regions):
        size = np.subtract(r.hi, r.lo)
        if np.any(size <= 0):
            continue
        box = m3.Manifold.cube(tuple(size)).translate(tuple(r.lo))
        total += r.weight * float((remaining ^ box).volume())
        remaining = remaining - box
    return total + importance.default * float(remaining.volume())


def exact_objectives(problem: PlacementProblem, cameras: Sequence[Camera]) -> Objectives:
    """f1 to f4 by mesh booleans, means over the target scenes of ``problem``.

    Depth images are rendered at full resolution whatever ``problem.step`` says, and each
    camera region has one block per pixel, so this is slow for large images: it is the
    reference that the voxel evaluation is checked against.

    Args:
        problem: The placement problem (its grid only fixes Z; no voxels are used).
        cameras: The cameras.

    Returns:
        The objective values (see :class:`~polyhull.placement.objectives.Objectives`).
    """
    grid = problem.grid
    zone = Zone(grid.lo, grid.hi)
    params = problem.params
    statics_mesh = [m.trimesh() for m in problem.static_meshes]
    statics = [mesh_to_manifold(m, f"static mesh {n}") for n, m in enumerate(statics_mesh)]
    scene = StaticScene(statics_mesh, problem.floor_z)
    references = [scene.render(cam) for cam in cameras]
    totals = np.zeros(10)
    scenes = problem.target_scenes or ((),)
    for target_arrays in scenes:
        target_meshes = [m.trimesh() for m in target_arrays]
        targets = [mesh_to_manifold(m, f"target mesh {n}") for n, m in enumerate(target_meshes)]
        images = [
            free_depth_image(cam, B, scene.render(cam, dynamic=target_meshes) if targets else B)
            for cam, B in zip(cameras, references, strict=True)
        ]
        frees = [f for f, _ in images]
        masks = [ch for _, ch in images]
        plain = exact_regions(cameras, zone, frees, masks, 1, statics, targets)
        strict = exact_regions(cameras, zone, frees, masks, params.k, statics, targets)
        vol = plain.volumes()
        vol_k = strict.volumes()
        totals += np.array(
            [
                vol["undetectable"],
                weighted_volume(plain.undetectable, params.importance),
                params.w1 * vol["changed"] + params.w2 * vol["undetectable"],
                params.w1 * vol_k["changed"] + params.w2 * vol_k["undetectable"],
                vol["free"],
                vol["changed"],
                vol["undetectable"],
                vol_k["free"],
                vol_k["changed"],
                vol_k["undetectable"],
            ]
        )
    mean = totals / len(scenes)
    return Objectives(*(float(x) for x in mean))
