"""Independent oracles of the engine's sets, by point classification (the bench's checks
and the tests'): which points lie in the exact depth hull C (README, "What it computes"), in the
padded robot's shadow and occlusion M, in the engine's R2; the tightness and misses of a
verdict's region; the dynamic part's volume outside the static hull; and the distance of
the exact hull's part that holds a person (:class:`ExactHullGap`).

None of them reads the engine's pieces or images to decide what the engine should have
found: they project points into the cameras and compare with the frames, the references
and the robot's exact depth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

__all__ = [
    "FreeDepth",
    "ExactHullGap",
    "banded_free",
    "dynamic_volume_outside_static",
    "engine_r2",
    "exact_free",
    "exact_hull",
    "exact_hulls",
    "flying_edge_free",
    "in_solids",
    "legs_footprint",
    "padded_robot_occlusion",
    "padded_robot_shadow",
    "pixels_of",
    "tightness_and_misses",
]


def pixels_of(camera: Any, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (u, v) of each point (nearest pixel centre), its z-depth, and whether it is in
    the image in front of the camera."""
    uv, z = camera.project(points)
    H, W = camera.shape
    with np.errstate(invalid="ignore"):
        px = np.floor(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0) + 0.5).astype(np.int64)
    inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
    u = np.where(inside, px[:, 0], 0)
    v = np.where(inside, px[:, 1], 0)
    return u, v, z, inside


def _in_pieces(points: np.ndarray, pieces: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies in some convex hexahedron of ``pieces`` (N, 8, 3)."""
    from scipy.spatial import cKDTree

    from .distance import points_in_hexahedra

    out = np.zeros(len(points), dtype=bool)
    if len(points) == 0 or len(pieces) == 0:
        return out
    centres = 0.5 * (pieces.min(axis=1) + pieces.max(axis=1))
    radii = np.linalg.norm(pieces - centres[:, None, :], axis=2).max(axis=1)
    near = cKDTree(points).query_ball_point(centres, radii)  # candidate points of each piece
    for i, idx in enumerate(near):
        if idx:
            out[idx] |= points_in_hexahedra(points[idx], pieces[i : i + 1])
    return out


FreeDepth = Callable[[Any, np.ndarray], np.ndarray]
"""Per-camera free depth: ``(static camera, measured depth (H, W) [m]) -> (H, W) free depth [m]``
(``static camera`` is one of ``monitor.static.cameras``)."""


def exact_free(static_camera: Any, depth: np.ndarray) -> np.ndarray:
    """The exact per-pixel free depth ``min(D, B) - tau(D)`` [m]
    (:func:`polyhull.regions.free_depth`)."""
    from .regions import free_depth

    return free_depth(static_camera.camera, depth, static_camera.reference)


def banded_free(static_camera: Any, depth: np.ndarray) -> np.ndarray:
    """The exact free depth clamped to the camera's static free depth f_s [m]: the engine's
    declared tolerance (a reading in the static band [lower, upper] frees only up to f_s, the
    free depth of the least reading in the band)."""
    return np.minimum(exact_free(static_camera, depth), static_camera.free_static)


def in_solids(cell: Any, points: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies in a solid obstacle (their boxes)."""
    solid = np.zeros(len(points), dtype=bool)
    for o in cell.solid_obstacles:  # boxes
        b = o.mesh.bounds
        solid |= np.all((points >= b[0]) & (points <= b[1]), axis=1)
    return solid


def exact_hulls(
    monitor: Any, frames: Mapping[str, Any], points: np.ndarray, frees: Sequence[FreeDepth]
) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`exact_hull` for several free-depth functions at once (the points are
    projected once per camera): one (P,) mask per function, and (P,) in a solid obstacle."""
    freed = [np.zeros(len(points), dtype=np.int64) for _ in frees]
    for s in monitor.static.cameras:
        cam = s.camera
        u, v, z, inside = pixels_of(cam, points)
        usable = inside & (z >= cam.near)
        depth = frames[cam.name].depth
        for count, free in zip(freed, frees, strict=True):
            count += usable & (z <= free(s, depth)[v, u])
    solid = in_solids(monitor.cell, points)
    k = monitor.cell.reconstruction.k_of_n
    return [(count < k) & ~solid for count in freed], solid


def exact_hull(
    monitor: Any, frames: Mapping[str, Any], points: np.ndarray, free: FreeDepth = exact_free
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) whether each point lies in the exact depth hull C of the frames (outside the solid
    obstacles), and (P,) whether it lies in a solid obstacle.

    A point frees in a camera when in the image, ``z >= near`` and ``z <= f[v, u]`` with the
    per-pixel free depth ``f = free(static camera, depth)`` (default :func:`exact_free`, the
    exact one, ``min(D, B) - tau(D)``; :func:`banded_free` gives the exact hull with the static
    band); it is in C when fewer than k cameras free it.
    """
    (hull,), solid = exact_hulls(monitor, frames, points, (free,))
    return hull, solid


def padded_robot_shadow(monitor: Any, points: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies in the padded robot's declared shadow of the monitor's
    last cycle: for some camera, on a pixel the padded robot covers, at or behind
    ``shadow_start`` (the engine's declared robot-occlusion tolerance)."""
    shadow = np.zeros(len(points), dtype=bool)
    for s in monitor.static.cameras:
        r = monitor.last_images.raster.get(s.camera.name)
        if r is not None:
            u, v, z, inside = pixels_of(s.camera, points)
            shadow |= inside & r.covered[v, u] & (z >= r.shadow_start[v, u])
    return shadow


def flying_edge_free(static_camera: Any, depth: np.ndarray) -> np.ndarray:
    """(H, W) the free depth [m] of the readings a depth camera's static edge takes for
    flying pixels, +inf elsewhere: the engine's declared flying-pixel tolerance.

    At a static edge pixel (``StaticCamera.edge``, its band widened to its 3 x 3
    neighbourhood's) a valid reading inside the widened band but in front of the pixel's
    own band, with no valid reading outside its band at a non-edge pixel within
    ``WEDGE_REACH`` px (nothing else seen there), is a mixed reading of the edge's two
    surfaces: the engine counts the space behind it as the static scene's, so where the
    robot hides that space from every other camera it is M. This mask is what the oracle
    needs to say so; it reads the frame and the static model's bands, not the engine's
    images, and it counts more readings as "something seen" than the engine does (it
    ignores the robot), so it excuses no more than the engine declares."""
    from scipy.ndimage import maximum_filter

    from .engine.pixels import WEDGE_REACH

    cam = static_camera.camera
    out = np.full(cam.shape, np.inf)
    edge = np.asarray(static_camera.edge, dtype=bool)
    if cam.kind != "depth" or not edge.any():
        return out
    D = np.asarray(depth, dtype=np.float64)
    lower = np.asarray(static_camera.lower, dtype=np.float64)
    upper = np.asarray(static_camera.upper, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(D) & (D >= cam.near) & (D <= cam.far)
        in_band = valid & (D >= lower) & (D <= upper)
    seen = valid & ~in_band & ~edge
    seen = maximum_filter(seen, size=2 * WEDGE_REACH + 1, mode="constant", cval=False)
    f = exact_free(static_camera, D)
    flying = edge & in_band & (f < np.asarray(static_camera.own_free, dtype=np.float64)) & ~seen
    out[flying] = f[flying]
    return out


def padded_robot_occlusion(
    monitor: Any, points: np.ndarray, band: bool = False, frames: Mapping[str, Any] | None = None
) -> np.ndarray:
    """(P,) whether each point lies in the padded robot's occlusion M of the monitor's last
    cycle by its definition (``M = F_static minus F_static+robot``, k of n):
    at least k cameras free it in the empty cell, by the exact free depth of the reference
    ``B - tau(B)``, and fewer once the padded robot's covered pixels free only up to its
    shadow start. Stricter than :func:`padded_robot_shadow` (some camera's shadow), which
    excuses a point one camera cannot see though others see it.

    ``band``: the empty cell frees only up to the least free depth of a reading in each
    pixel's own static band (``StaticCamera.own_free``: the engine's declared band
    tolerance, 4.5 sigma, not an edge's widened band): M as the engine's static model
    defines it, for a point within one camera's noise sheet that only that camera sees
    once the robot is in the cell (the detection capability's object thinner than the
    sheet).

    ``frames``: the cycle's frames (a camera without one has no flying readings); in both
    cells a static edge's flying readings (:func:`flying_edge_free`) free only up to their
    own free depth, as the static scene's (the engine's declared flying-pixel tolerance: a
    sliver behind an edge reading that only cameras the robot now hides from saw free)."""
    k = monitor.cell.reconstruction.k_of_n
    base = []
    for s in monitor.static.cameras:
        f = np.asarray(s.own_free, dtype=np.float64) if band else exact_free(s, s.reference)
        frame = None if frames is None else frames.get(s.camera.name)
        if frame is not None:
            f = np.minimum(f, flying_edge_free(s, frame.depth))
        base.append(f)
    counts = []
    for robot in (False, True):
        count = np.zeros(len(points), dtype=np.int64)
        for s, f in zip(monitor.static.cameras, base, strict=True):
            cam = s.camera
            r = monitor.last_images.raster.get(cam.name) if robot and monitor.last_images is not None else None
            if r is not None:
                f = np.where(r.covered, np.minimum(f, r.shadow_start), f)
            u, v, z, inside = pixels_of(cam, points)
            count += inside & (z >= cam.near) & (z <= f[v, u])
        counts.append(count)
    return (counts[0] >= k) & (counts[1] < k)


def engine_r2(monitor: Any, verdict: Any, points: np.ndarray, solid: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies in the engine's R2 of ``verdict`` (the monitor's last
    cycle): C_static (the static model's point oracle) outside the solid obstacles
    (``solid``, (P,)), or inside one of the cycle's dynamic pieces (before the plausibility
    rules)."""
    k = monitor.cell.reconstruction.k_of_n
    return (monitor.static.hull_contains(points, k) & ~solid) | _in_pieces(points, verdict._geometry.pieces)


def tightness_and_misses(monitor: Any, frames: dict, verdict: Any, samples: int, seed: int) -> dict[str, Any]:  # type: ignore[type-arg]
    """Monte-Carlo comparison of the exact depth hull C with the engine's R2 (last cycle).

    - exact C: :func:`exact_hull`;
    - banded exact C: :func:`exact_hull` with :func:`banded_free`, the best the engine may
      reach within its declared static-band tolerance (a superset of exact C);
    - engine R2: :func:`engine_r2`;
    - padded robot shadow: :func:`padded_robot_shadow`; the padded robot's occlusion M:
      :func:`padded_robot_occlusion`.

    Both volumes leave out the solid obstacles (nobody can be inside them). ``misses`` are
    exact-C points outside R2 and outside the padded robot's M, by its definition, with the
    static band, or with the band and a static edge's flying readings
    (:func:`padded_robot_occlusion`; must be 0: the padding, the band and the flying
    readings are the engine's declared tolerances); ``misses_band`` are those only the band
    excuses, ``misses_flying`` those only the band with a static edge's flying readings
    (:func:`flying_edge_free`) excuses; ``misses_unexcused`` counts them all without an
    excuse.
    """
    cell = monitor.cell
    lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    p = np.random.default_rng(seed).uniform(lo, hi, size=(samples, 3))
    (exact, banded), solid = exact_hulls(monitor, frames, p, (exact_free, banded_free))
    shadow = padded_robot_shadow(monitor, p)
    r2 = engine_r2(monitor, verdict, p, solid)
    out = p[exact & ~r2]
    m_exact, m_band = padded_robot_occlusion(monitor, out), padded_robot_occlusion(monitor, out, band=True)
    m_flying = padded_robot_occlusion(monitor, out, band=True, frames=frames)
    zone = cell.zone.volume
    v_exact = zone * float(exact.mean())
    v_r2 = zone * float(r2.mean())
    v_exact_out = zone * float((exact & ~shadow).mean())
    v_banded = zone * float(banded.mean())
    return {
        "samples": samples,
        "volume_zone_m3": zone,
        "volume_exact_hull_m3": v_exact,
        "volume_engine_r2_m3": v_r2,
        "excess_percent": 100.0 * (v_r2 / v_exact - 1.0) if v_exact > 0 else math.inf,
        "volume_exact_hull_outside_robot_shadow_m3": v_exact_out,
        "excess_outside_robot_shadow_percent": 100.0 * (v_r2 / v_exact_out - 1.0) if v_exact_out > 0 else math.inf,
        "volume_exact_banded_m3": v_banded,
        "excess_over_banded_percent": 100.0 * (v_r2 / v_banded - 1.0) if v_banded > 0 else math.inf,
        "misses": int((~m_exact & ~m_band & ~m_flying).sum()),
        "misses_band": int((~m_exact & m_band).sum()),
        "misses_flying": int((~m_exact & ~m_band & m_flying).sum()),
        "misses_unexcused": int((exact & ~r2).sum()),
    }


def dynamic_volume_outside_static(monitor: Any, verdict: Any) -> float:
    """Volume [m^3] of a verdict's kept dynamic pieces outside the static hull C_static and
    the solids: what this cycle adds to the static region (exact, by manifold3d booleans;
    off the hot path, a few hundred ms). The sheet boxes under kept pieces are part of
    R2_static, inside C_static, and add nothing here."""
    from .verdict import pieces_manifold

    geometry = verdict._geometry
    if geometry is None or len(geometry.kept_pieces) == 0:
        return 0.0
    s = monitor.static
    added = (pieces_manifold(geometry.kept_boxes, geometry.stack) ^ monitor._zone) - s.hull - s.solids
    return float(added.volume())


GAP_GRID = 0.025
"""Grid step [m] of the exact hull's person component (:class:`ExactHullGap`)."""

GAP_REACH = 1.5
"""How far [m] the grid reaches beyond the person's bounding box in x and y."""

GAP_LINK_EDGE = 0.01
"""Longest edge [m] of the subdivided link meshes whose vertices pre-select the grid points
nearest to the links (every point of a link's surface is within this of a vertex)."""

GAP_PERSON_SAMPLES = 2000
"""Candidate points of the rejection sampling of the person's interior."""

GAP_FEW = 256
"""Border points (those nearest the links' bounding spheres) that bound the distance first."""


def legs_footprint(person: Any, height: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (2,) each: the x, y bounds of the person mesh's section at ``height`` [m]
    (the legs where they cross the floor sheet's top), or of the whole mesh where it has
    no section there (wholly above or below). The engine keeps the floor's sheet within
    ``floor_shell_margin`` of what its region has crossing that height, which holds the
    legs' section: the oracle's feet region, within the margin of the section itself, is
    the least the engine's can be."""
    import trimesh

    lines = trimesh.intersections.mesh_plane(person, [0.0, 0.0, 1.0], [0.0, 0.0, float(height)])
    if len(lines) == 0:
        return np.asarray(person.bounds[0][:2], dtype=float), np.asarray(person.bounds[1][:2], dtype=float)
    pts = np.asarray(lines, dtype=float).reshape(-1, 3)
    return pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)


def _sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """A sphere (centre, radius [m]) around the points: centred on their bounding box."""
    v = np.asarray(vertices, dtype=np.float64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return centre, float(np.linalg.norm(v - centre, axis=1).max())


class ExactHullGap:
    r"""Distance from the robot's moving links to the exact depth hull's part that holds the
    person: the best any conservative region built from these frames can report.

    Per cycle, on a grid of step ``grid`` (cell centres of a lattice anchored at the zone's
    minimum corner) over the person's bounding box grown by ``reach`` in x and y (clipped to
    the zone) and over the zone's whole height, a grid point is kept when it lies in

    - the exact depth hull C: fewer than k cameras free it with the exact per-pixel free
      depth of the measured frames (:func:`exact_free`, as :func:`exact_hull`);
    - outside the unpadded robot's occlusion M (by definition ``M = F_static \ F_static+robot``):
      it is not the case that at least k cameras free it in the empty cell (free depth of
      the reference) while fewer than k free it with the robot at q (free depth of the
      noise-free depth of the static scene plus the robot, ``Simulator.render_exact(q)``,
      so a point at or behind ``robot depth - tau(robot depth)`` on a pixel the robot
      covers is not freed there);
    - outside the solid obstacles;
    - outside the floor's noise sheet (the static model's floor sheet: below its top),
      except within ``plausibility.floor_shell_margin`` horizontally of the bounds of the
      person's section at the sheet's top (:func:`legs_footprint`: a person keeps their
      feet).

    The kept points are labelled into 26-connected components (``scipy.ndimage.label``);
    the components that hold the person's interior (``trimesh.sample.volume_mesh``) are the
    person's part. Its distance to the links: 0 when a grid point of the part lies inside a
    link (tested in each link's bounding box); else the nearest grid point lies on the
    part's border, and the border points that can be nearest are pre-selected with a k-d
    tree against the vertices of the link meshes subdivided to edges of at most
    ``GAP_LINK_EDGE`` (every surface point lies within that of a vertex), then measured
    exactly to the link meshes (``trimesh.proximity``). The figure is the exact distance of
    the grid points, not of the continuous set.

    It is an estimate, not a proof: the hull is sampled at ``grid`` (a part thinner than a
    grid step can be missed or split, and the distance is off by up to half a grid cell's
    diagonal, about 0.022 m at 0.025 m); the floor sheet rule is approximated by a height and
    a margin around the legs' section's bounds; a part reaching beyond the grid's sides is cut there
    (it may only make the distance larger; ``clipped`` says when it happened).
    """

    def __init__(
        self, monitor: Any, link_geometry: Mapping[str, Any], grid: float = GAP_GRID, reach: float = GAP_REACH, seed: int = 0
    ) -> None:
        """Args:
            monitor: The monitor (its cell and static cameras).
            link_geometry: Watertight collision mesh per moving link, in the link frame.
            grid: Grid step [m].
            reach: Grid reach beyond the person's bounding box in x and y [m].
            seed: Seed of the person's interior samples.
        """
        import trimesh
        from scipy.spatial import cKDTree

        self._cell = monitor.cell
        self._cameras = monitor.static.cameras
        self._grid = float(grid)
        self._reach = float(reach)
        self._rng = np.random.default_rng(seed)
        floor = [sh for sh in monitor.static.sheets if sh.name == "floor"]
        self.floor_top = floor[0].level + floor[0].height if floor else -math.inf
        # the empty cell's free depth, per camera (the reference measured without noise)
        self._free_empty = [self._padded(exact_free(s, s.reference)) for s in self._cameras]
        self._links = {n: m for n, m in link_geometry.items() if len(m.faces)}
        self._trees = {
            n: cKDTree(trimesh.remesh.subdivide_to_size(m.vertices, m.faces, GAP_LINK_EDGE, max_iter=20)[0])
            for n, m in self._links.items()
        }
        self._spheres = {n: _sphere(m.vertices) for n, m in self._links.items()}
        self._queries = {n: trimesh.proximity.ProximityQuery(m) for n, m in self._links.items()}

    @staticmethod
    def _padded(free: np.ndarray) -> np.ndarray:
        """Flat float32 free depth with a last entry -inf: the index of pixels not seen."""
        return np.append(np.asarray(free, dtype=np.float32).ravel(), np.float32(-np.inf))

    def _axes(self, person: Any) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
        """The grid's axes (x, y, z centres [m]) and its first lattice index (3,)."""
        zmin, zmax = np.asarray(self._cell.zone.min), np.asarray(self._cell.zone.max)
        grow = np.array([self._reach, self._reach, 0.0])
        lo = np.maximum(person.bounds[0] - grow, zmin)
        hi = np.minimum(person.bounds[1] + grow, zmax)
        lo[2], hi[2] = zmin[2], zmax[2]
        last = np.floor((zmax - zmin) / self._grid - 1e-9).astype(np.int64)  # last cell in the zone
        i0 = np.clip(np.floor((lo - zmin) / self._grid).astype(np.int64), 0, last)
        i1 = np.clip(np.ceil((hi - zmin) / self._grid).astype(np.int64) - 1, i0, last)
        axes = tuple(zmin[a] + (np.arange(i0[a], i1[a] + 1) + 0.5) * self._grid for a in range(3))
        return axes, i0

    def _project(self, camera: Any, axes: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Flat pixel index (the last index where not seen: outside the image or nearer than
        ``near``) and z-depth [m] of every grid point, (nx, ny, nz) each, float32; the grid's
        camera coordinates are sums of per-axis terms (no (N, 3) array)."""
        T = camera.T_camera_world
        gx, gy, gz = (a.astype(np.float32) for a in axes)

        def coordinate(c: int) -> np.ndarray:
            r, t = T[c, :3].astype(np.float32), np.float32(T[c, 3])
            return (r[0] * gx)[:, None, None] + (r[1] * gy)[None, :, None] + (r[2] * gz + t)[None, None, :]

        k = camera.intrinsics
        H, W = camera.shape
        z = coordinate(2)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.floor(np.float32(k.fx) * coordinate(0) / z + np.float32(k.cx + 0.5))
            v = np.floor(np.float32(k.fy) * coordinate(1) / z + np.float32(k.cy + 0.5))
        seen = (z >= camera.near) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        # v * W + u < 2**24 is exact in float32 (images up to MAX_SIDE x MAX_SIDE px)
        index = np.where(seen, v * np.float32(W) + u, np.float32(H * W)).astype(np.int32)
        return index, z

    def kept(
        self, frames: Mapping[str, Any], robot_depth: Mapping[str, np.ndarray], person: Any
    ) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
        """The grid around ``person`` and which of its points are kept (the class docstring):
        the axes (x, y, z cell centres [m]), the grid's first lattice index (3,) and the
        (nx, ny, nz) mask. Arguments as :meth:`measure`."""
        cell = self._cell
        k = cell.reconstruction.k_of_n
        axes, i0 = self._axes(person)
        shape = tuple(len(a) for a in axes)
        freed = np.zeros(shape, dtype=np.int16)
        empty = np.zeros(shape, dtype=np.int16)
        with_robot = np.zeros(shape, dtype=np.int16)
        for s, free_empty in zip(self._cameras, self._free_empty, strict=True):
            index, z = self._project(s.camera, axes)
            freed += z <= self._padded(exact_free(s, frames[s.camera.name].depth))[index]
            empty += z <= free_empty[index]
            with_robot += z <= self._padded(exact_free(s, robot_depth[s.camera.name]))[index]
        keep = (freed < k) & ((empty < k) | (with_robot >= k))
        gx, gy, gz = axes
        for o in cell.solid_obstacles:  # boxes
            b0, b1 = o.mesh.bounds
            keep &= ~(
                ((gx >= b0[0]) & (gx <= b1[0]))[:, None, None]
                & ((gy >= b0[1]) & (gy <= b1[1]))[None, :, None]
                & ((gz >= b0[2]) & (gz <= b1[2]))[None, None, :]
            )
        p0, p1 = legs_footprint(person, self.floor_top)
        dx = np.maximum(np.maximum(p0[0] - gx, gx - p1[0]), 0.0)
        dy = np.maximum(np.maximum(p0[1] - gy, gy - p1[1]), 0.0)
        feet = dx[:, None] ** 2 + dy[None, :] ** 2 <= cell.plausibility.floor_shell_margin**2
        keep &= ~(~feet[:, :, None] & (gz < self.floor_top)[None, None, :])
        return axes, i0, keep

    def measure(
        self,
        frames: Mapping[str, Any],
        robot_depth: Mapping[str, np.ndarray],
        T_world_links: Mapping[str, np.ndarray],
        person: Any,
    ) -> tuple[float, bool]:
        """(distance [m] of the exact hull's person part to the links, whether the part
        reaches a side of the grid inside the zone); the distance is NaN when no grid point
        of the person's interior is kept (nothing holds the person).

        Args:
            frames: The cycle's depth frames (camera name -> DepthFrame).
            robot_depth: Noise-free depth (H, W) [m] of the static scene and the robot at
                the cycle's q per camera (``Simulator.render_exact(q)``).
            T_world_links: T_world_link (4, 4) of the moving links at q.
            person: The person's watertight mesh (world frame).
        """
        import trimesh
        from scipy import ndimage

        cell = self._cell
        axes, i0, keep = self.kept(frames, robot_depth, person)
        shape = keep.shape
        labels, count = ndimage.label(keep, structure=np.ones((3, 3, 3), dtype=bool))
        zmin = np.asarray(cell.zone.min)
        inner = trimesh.sample.volume_mesh(person, GAP_PERSON_SAMPLES, seed=self._rng)
        idx = np.floor((inner - zmin) / self._grid).astype(np.int64) - i0
        idx = idx[np.all((idx >= 0) & (idx < shape), axis=1)]
        held = np.unique(labels[tuple(idx.T)])
        held = held[held > 0]
        if held.size == 0:
            return math.nan, False
        lut = np.zeros(count + 1, dtype=bool)
        lut[held] = True
        part = lut[labels]
        last = np.floor((np.asarray(cell.zone.max) - zmin) / self._grid - 1e-9).astype(np.int64)
        clipped = bool(
            (i0[0] > 0 and part[0].any()) or (i0[0] + shape[0] - 1 < last[0] and part[-1].any())
            or (i0[1] > 0 and part[:, 0].any()) or (i0[1] + shape[1] - 1 < last[1] and part[:, -1].any())
        )

        def points(mask: np.ndarray) -> np.ndarray:
            return np.column_stack([a[i] for a, i in zip(axes, np.nonzero(mask), strict=True)])

        # a point of the part inside a link: distance 0; else the nearest lies on its border
        world = {n: T for n, T in T_world_links.items() if n in self._links}
        for name, T in world.items():
            corners = trimesh.bounds.corners(self._links[name].bounds) @ T[:3, :3].T + T[:3, 3]
            a = np.clip(np.floor((corners.min(axis=0) - zmin) / self._grid).astype(np.int64) - i0, 0, shape)
            b = np.clip(np.ceil((corners.max(axis=0) - zmin) / self._grid).astype(np.int64) - i0 + 1, 0, shape)
            box = np.zeros(shape, dtype=bool)
            box[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = True
            inside = points(part & box)
            if len(inside) and self._links[name].contains((inside - T[:3, 3]) @ T[:3, :3]).any():
                return 0.0, clipped
        border = points(part & ~ndimage.binary_erosion(part, structure=np.ones((3, 3, 3), dtype=bool)))
        local = {n: (border - T[:3, 3]) @ T[:3, :3] for n, T in world.items()}  # world -> link frame
        # a lower bound of each border point's distance: to the links' bounding spheres
        bound = np.min([np.linalg.norm(local[n] - self._spheres[n][0], axis=1) - self._spheres[n][1] for n in world], axis=0)
        # an upper bound of the least vertex distance d_v: the few points of least bound
        few = np.argsort(bound)[:GAP_FEW]
        upper = min(float(self._trees[n].query(local[n][few])[0].min()) for n in world)
        # the nearest point p* has bound <= d(p*) <= d_v <= upper, and a vertex within
        # d(p*) + GAP_LINK_EDGE <= d_v + GAP_LINK_EDGE
        maybe = np.flatnonzero(bound <= upper)
        d_vertex = np.min([self._trees[n].query(local[n][maybe])[0] for n in world], axis=0)
        near = maybe[d_vertex <= d_vertex.min() + GAP_LINK_EDGE]
        best = math.inf
        for name in world:
            signed = self._queries[name].signed_distance(local[name][near])  # > 0 inside
            best = min(best, float(np.maximum(-signed, 0.0).min()))
        return best, clipped
