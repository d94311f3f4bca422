"""Ray casting: z-depth images of triangle meshes and the floor plane.

This is the core shared by the depth simulator (:mod:`polyhull.simulator`), the monitor
(the reference depth ``B_i``, the empty cell's) and the placement optimiser.

Meshes go through trimesh's Embree intersector (``trimesh.ray.ray_pyembree``, backed by
``embreex``), which only answers *which triangle* a ray hits first; the hit distance is then
computed in float64 from that triangle's plane, so depths carry no float32 error from
Embree. The floor is the unbounded analytic plane ``z = floor_z``.

Every image here is **z-depth** (the distance along the optical axis, as depth cameras
report it), not ray length: camera rays are built with a unit z component in the camera
frame (:meth:`polyhull.camera.Camera.pixel_rays`), so the ray parameter of a hit *is* its
z-depth. ``+inf`` marks pixels whose ray hits nothing. Nothing is clipped to the camera
range here; that is a sensor effect (:class:`polyhull.simulator.SensorEffects`).
"""

from __future__ import annotations

import warnings
import weakref
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np
import trimesh

from .camera import Camera
from .errors import GeometryError
from .typed import ArrayF32, ArrayF64, ArrayI64

if TYPE_CHECKING:
    from .cell import Cell

__all__ = [
    "MeshCaster",
    "StaticScene",
    "camera_rays_world",
    "floor_depth",
    "render_depth",
    "render_reference",
]

# A hit whose ray meets the triangle plane at |cos| below this is grazing: its plane
# distance is ill-conditioned, so the nearest vertex depth of the triangle is used instead.
_GRAZING_COS = 1e-9


class _Intersector(Protocol):
    def intersects_first(self, ray_origins: ArrayF64, ray_directions: ArrayF64) -> ArrayI64: ...


def _make_intersector(mesh: trimesh.Trimesh) -> _Intersector:
    """Embree intersector of ``mesh``; the pure-numpy one (with a warning) without embreex."""
    try:
        from trimesh.ray import ray_pyembree
    except ImportError:  # pragma: no cover - embreex is a core dependency
        warnings.warn(
            "embreex is not installed: ray casting falls back to trimesh's slow pure-numpy "
            "intersector; pip install embreex",
            RuntimeWarning,
            stacklevel=3,
        )
        from trimesh.ray import ray_triangle

        return ray_triangle.RayMeshIntersector(mesh)  # type: ignore[no-any-return]
    return ray_pyembree.RayMeshIntersector(mesh)  # type: ignore[no-any-return]


def _concatenate(meshes: Sequence[trimesh.Trimesh], what: str) -> trimesh.Trimesh | None:
    """One mesh of all non-empty ``meshes``, or None when there are no triangles at all."""
    parts: list[trimesh.Trimesh] = []
    for i, mesh in enumerate(meshes):
        if not isinstance(mesh, trimesh.Trimesh):
            raise GeometryError(
                f"{what}[{i}] must be a trimesh.Trimesh, got {type(mesh).__name__}"
            )
        if len(mesh.faces) == 0:
            continue
        if not np.all(np.isfinite(mesh.vertices)):
            raise GeometryError(f"{what}[{i}] has non-finite vertices")
        parts.append(mesh)
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    vertices = []
    faces = []
    offset = 0
    for mesh in parts:
        vertices.append(np.asarray(mesh.vertices, dtype=np.float64))
        faces.append(np.asarray(mesh.faces, dtype=np.int64) + offset)
        offset += len(mesh.vertices)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


class MeshCaster:
    """First-hit ray queries against a fixed set of triangle meshes.

    The meshes are concatenated and handed to Embree once, at construction; every query
    after that only traces rays. Meshes need not be watertight.

    Args:
        meshes: Triangle meshes in the world frame [m]; empty meshes are ignored.
    """

    def __init__(self, meshes: Sequence[trimesh.Trimesh]) -> None:
        mesh = _concatenate(meshes, "meshes")
        self._mesh = mesh
        if mesh is None:
            self._intersector: _Intersector | None = None
            return
        triangles = np.asarray(mesh.triangles, dtype=np.float64)  # (F, 3, 3)
        self._vertex0 = triangles[:, 0, :]  # (F, 3)
        self._triangles = triangles
        normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        self._normals = normals  # (F, 3), not normalised: the plane distance does not need it
        self._intersector = _make_intersector(mesh)

    @property
    def mesh(self) -> trimesh.Trimesh | None:
        """The concatenated mesh (world frame), or None when there are no triangles."""
        return self._mesh

    @property
    def is_empty(self) -> bool:
        """True when there is nothing to hit."""
        return self._intersector is None

    def first_hit(self, origins: ArrayF64, directions: ArrayF64) -> ArrayF64:
        """Ray parameter of the first hit of each ray, +inf where a ray hits nothing.

        The hit point is ``origins + t * directions``, so ``t`` is in units of the length
        of each direction (directions need not be unit vectors; with camera rays of unit z
        it is the z-depth).

        Args:
            origins: (N, 3) ray origins [m], world frame.
            directions: (N, 3) ray directions, world frame.

        Returns:
            (N,) float64 ray parameters, ``>= 0`` or ``+inf``.
        """
        o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        if o.shape != d.shape:
            o = np.broadcast_to(o, d.shape)
        t = np.full(len(d), np.inf)
        if self._intersector is None or len(d) == 0:
            return t
        tri = np.asarray(self._intersector.intersects_first(o, d), dtype=np.int64)
        hit = np.flatnonzero(tri >= 0)
        if len(hit) == 0:
            return t
        faces = tri[hit]
        n = self._normals[faces]
        oh = o[hit]
        dh = d[hit]
        denom = np.einsum("ij,ij->i", n, dh)
        numer = np.einsum("ij,ij->i", n, self._vertex0[faces] - oh)
        norm_n = np.linalg.norm(n, axis=1)
        norm_d = np.linalg.norm(dh, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hit = numer / denom
        grazing = ~(np.abs(denom) > _GRAZING_COS * norm_n * norm_d) | ~np.isfinite(t_hit)
        if np.any(grazing):
            # Degenerate or edge-on triangle: the nearest of its vertices along the ray.
            g = np.flatnonzero(grazing)
            verts = self._triangles[faces[g]] - oh[g, None, :]  # (G, 3, 3)
            along = np.einsum("gkj,gj->gk", verts, dh[g]) / (norm_d[g, None] ** 2)
            t_hit[g] = along.min(axis=1)
        t[hit] = np.maximum(t_hit, 0.0)
        return t

    def depth(
        self,
        camera: Camera,
        step: int = 1,
        rays: tuple[ArrayF64, ArrayF64] | None = None,
    ) -> ArrayF32:
        """z-depth image [m] of the meshes seen by ``camera``; +inf where nothing is hit.

        Only the pixels inside the image rectangle of the meshes' bounding box are traced
        (exact culling: a box in front of the camera projects inside the hull of its
        projected corners).

        Args:
            camera: The camera.
            step: Use every ``step``-th pixel in u and v (pixel centres 0, step, 2 step...).
            rays: The camera centre and world ray directions from
                :func:`camera_rays_world` (same ``step``), to reuse across calls.

        Returns:
            (ceil(H / step), ceil(W / step)) float32 z-depth [m].
        """
        center, directions = camera_rays_world(camera, step) if rays is None else rays
        shape = directions.shape[:2]
        depth = np.full(shape, np.inf, dtype=np.float32)
        if self._mesh is None:
            return depth
        window = self._pixel_window(camera, step, shape)
        if window is None:
            return depth
        (r0, r1), (c0, c1) = window
        sub = directions[r0:r1, c0:c1]
        t = self.first_hit(center, sub.reshape(-1, 3))
        depth[r0:r1, c0:c1] = t.reshape(sub.shape[:2])
        return depth

    def _pixel_window(
        self, camera: Camera, step: int, shape: tuple[int, int]
    ) -> tuple[tuple[int, int], tuple[int, int]] | None:
        """Row and column index ranges (of the strided image) that can see the meshes."""
        assert self._mesh is not None
        lo, hi = np.asarray(self._mesh.bounds, dtype=np.float64)
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        uv, z = camera.project(corners)
        if not np.all(z > 1e-9):
            return (0, shape[0]), (0, shape[1])  # the box reaches behind the camera
        u_lo, v_lo = np.floor(uv.min(axis=0)) - 1.0
        u_hi, v_hi = np.ceil(uv.max(axis=0)) + 1.0
        c0 = int(np.clip(np.ceil(u_lo / step), 0, shape[1]))
        c1 = int(np.clip(np.floor(u_hi / step) + 1, 0, shape[1]))
        r0 = int(np.clip(np.ceil(v_lo / step), 0, shape[0]))
        r1 = int(np.clip(np.floor(v_hi / step) + 1, 0, shape[0]))
        if c0 >= c1 or r0 >= r1:
            return None
        return (r0, r1), (c0, c1)


def camera_rays_world(camera: Camera, step: int = 1) -> tuple[ArrayF64, ArrayF64]:
    """Origin and world-frame directions of the pixel-centre rays of ``camera``.

    The directions have unit z component in the camera frame, so a ray parameter is a
    z-depth.

    Args:
        camera: The camera.
        step: Pixel stride in u and v.

    Returns:
        The camera centre (3,) [m] and the directions (H', W', 3).
    """
    if not (isinstance(step, int | np.integer) and step >= 1):
        raise GeometryError(f"step must be a positive integer [px], got {step!r}")
    rays_camera = camera.pixel_rays(int(step))  # (H', W', 3)
    R_world_camera = camera.T_world_camera[:3, :3]
    return np.asarray(camera.center, dtype=np.float64), rays_camera @ R_world_camera.T


def floor_depth(camera: Camera, floor_z: float, step: int = 1) -> ArrayF32:
    """z-depth image [m] of the unbounded plane ``z = floor_z``; +inf where it is not hit.

    Args:
        camera: The camera.
        floor_z: Height of the floor plane in the world [m].
        step: Pixel stride in u and v.

    Returns:
        (H', W') float32 z-depth [m].
    """
    return _plane_depth(camera_rays_world(camera, step), floor_z)


def _plane_depth(rays: tuple[ArrayF64, ArrayF64], floor_z: float) -> ArrayF32:
    center, directions = rays
    dz = directions[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (float(floor_z) - center[2]) / dz
    t = np.where(np.isfinite(t) & (t > 0.0), t, np.inf)
    return t.astype(np.float32)


class StaticScene:
    """The static part of a cell (obstacles and the floor), ready to render many cameras.

    The Embree scene of the static meshes is built once; :meth:`render` adds the floor and,
    optionally, dynamic meshes (robot, people) traced in a second, per-call scene.

    Args:
        meshes: Static meshes in the world frame [m] (obstacles).
        floor_z: Height of the floor plane [m], or None for no floor.
    """

    def __init__(self, meshes: Sequence[trimesh.Trimesh], floor_z: float | None) -> None:
        if floor_z is not None and not np.isfinite(floor_z):
            raise GeometryError(f"floor_z must be finite [m] or None, got {floor_z!r}")
        self.floor_z = None if floor_z is None else float(floor_z)
        self._caster = MeshCaster(meshes)
        self._rays: weakref.WeakKeyDictionary[Camera, dict[int, tuple[ArrayF64, ArrayF64]]]
        self._rays = weakref.WeakKeyDictionary()

    @property
    def caster(self) -> MeshCaster:
        """The prepared caster of the static meshes."""
        return self._caster

    def rays(self, camera: Camera, step: int = 1) -> tuple[ArrayF64, ArrayF64]:
        """:func:`camera_rays_world` of ``camera``, cached for as long as the camera lives."""
        per_step = self._rays.setdefault(camera, {})
        if step not in per_step:
            per_step[step] = camera_rays_world(camera, step)
        return per_step[step]

    def render(
        self,
        camera: Camera,
        dynamic: Sequence[trimesh.Trimesh] | MeshCaster = (),
        step: int = 1,
    ) -> ArrayF32:
        """z-depth [m] of the first hit of floor, static meshes and ``dynamic`` meshes.

        Args:
            camera: The camera.
            dynamic: Further meshes (world frame), or a prepared :class:`MeshCaster` of
                them to reuse across cameras.
            step: Pixel stride in u and v.

        Returns:
            (H', W') float32 z-depth [m], +inf where nothing is hit.
        """
        rays = self.rays(camera, step)
        depth = self._caster.depth(camera, step, rays)
        if self.floor_z is not None:
            np.minimum(depth, _plane_depth(rays, self.floor_z), out=depth)
        caster = dynamic if isinstance(dynamic, MeshCaster) else MeshCaster(dynamic)
        if not caster.is_empty:
            np.minimum(depth, caster.depth(camera, step, rays), out=depth)
        return depth


def render_depth(
    camera: Camera,
    meshes: Sequence[trimesh.Trimesh],
    floor_z: float | None,
    step: int = 1,
) -> ArrayF32:
    """z-depth image [m] of ``meshes`` and the floor plane as seen by ``camera``.

    Each pixel-centre ray (pixel (u, v) centred at integer coordinates) reports the z-depth
    of its first hit; the floor is the unbounded plane ``z = floor_z`` (when not None).
    No clipping to the camera range.

    Args:
        camera: The camera.
        meshes: Triangle meshes in the world frame [m], concatenated into one scene.
        floor_z: Floor height [m], or None for no floor.
        step: Use every ``step``-th pixel in u and v.

    Returns:
        (ceil(H / step), ceil(W / step)) float32 z-depth [m], +inf where nothing is hit.
    """
    return StaticScene(meshes, floor_z).render(camera, step=step)


def render_reference(cell: Cell, step: int = 1) -> dict[str, ArrayF32]:
    """The reference depth ``B_i`` of every camera of ``cell``.

    The empty cell: the floor (the plane z = zone min z) and every static obstacle; no
    robot, no people. +inf where a reference ray hits nothing.

    Args:
        cell: The work cell.
        step: Pixel stride in u and v.

    Returns:
        Camera name -> (H', W') float32 z-depth [m].
    """
    scene = StaticScene([o.mesh for o in cell.obstacles], cell.zone.floor_z)
    return {cam.name: scene.render(cam, step=step) for cam in cell.cameras}
