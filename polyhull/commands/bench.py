"""``polyhull bench``: the reference workload, timed per stage, with its accuracy checks.

Five parts, on one monitor (the static model is built once):

1. the reference workload: the cell, the robot moving, one walking person, default sensor
   effects; frames rendered before timing, ``warmup`` untimed cycles, then ``cycles`` timed
   ones: the cycle's median and p99 [ms] and every stage's median [ms]; and the new
   monitor's first two cycles [ms] (what a controller sees after starting it);
2. the person: over the walk, the true distance from the person's mesh to the robot's
   moving links against the reported distance (reported must never exceed true), and both
   against the distance of the exact depth hull's part that holds the person
   (:class:`ExactHullGap`: the gap no conservative region from these cameras can close);
3. tightness and misses on the last person cycle, by a Monte-Carlo point oracle: the exact
   depth hull C of the cycle's frames against the engine's region R2, and R2 against the
   exact hull with the static band (the engine's declared tolerance, :func:`banded_free`);
4. the empty cell: nobody present, the robot moving, every sensor effect on: its cycle time
   (as many cycles as the person's, back to back), the dynamic pieces kept, their volume
   outside the static hull C_static (:func:`dynamic_volume_outside_static`), and whether
   the distance departs from the static region's own distance;
5. with ``--peers N``: OctoMap on the frames of the last N timed cycles, side by side with
   the verdicts (:mod:`polyhull.peers`, the optional ``peers`` extra).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import re
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PolyhullError

__all__ = [
    "register",
    "run_bench",
    "ring_cameras",
    "rescale_camera",
    "parse_resolution",
    "exact_free",
    "banded_free",
    "exact_hull",
    "exact_hulls",
    "engine_r2",
    "padded_robot_shadow",
    "padded_robot_occlusion",
    "ExactHullGap",
    "dynamic_volume_outside_static",
]

DT = 0.1
"""Simulated time between cycles [s]."""

WALK_SPEED = 1.2
"""Walking speed of the person [m/s]: a walk toward the robot and back, repeated."""

MAX_CAMERAS = 16
RING_RADIUS = 2.9  # [m], around the zone centre
RING_HEIGHT = 3.3  # [m]
RING_TARGET_Z = 1.0  # [m], the cameras look at the zone centre at this height
MAX_SIDE = 4096  # [px]
MIN_SIDE = 16  # [px]
MAX_SAMPLES = 10_000_000


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``bench`` sub-command."""
    p = subparsers.add_parser(
        "bench",
        help="time the surveillance cycle on the reference workload and check its accuracy",
        description=(
            "Time the cycle (frames in, verdict out) on the reference workload: the paper's "
            "cell, four 640x480 depth cameras, the 6-axis robot in motion, one walking person, "
            "default sensor effects (frames are rendered before timing). Then check the "
            "distance against the person's true distance and against the exact depth hull's "
            "part that holds the person (2.5 cm grid, about 1 s per cycle), the tightness and "
            "misses of the region on the last cycle against the exact hull and the exact hull "
            "with the static band (Monte-Carlo point oracle), and the empty cell."
        ),
    )
    p.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    p.add_argument("--cycles", type=int, default=20, help="timed cycles (default 20)")
    p.add_argument("--warmup", type=int, default=2, help="untimed cycles first (default 2)")
    p.add_argument(
        "--empty-cycles", type=int, default=100, help="cycles of the empty cell (default 100; 0 skips)"
    )
    p.add_argument(
        "--tightness-samples",
        type=int,
        default=100_000,
        help="points sampled in the zone for the tightness and misses oracle (default 100000; 0 skips)",
    )
    p.add_argument(
        "--cameras",
        type=int,
        default=None,
        help=f"replace the cameras by a ring of N (1..{MAX_CAMERAS}) of the first camera's kind",
    )
    p.add_argument(
        "--resolution", default=None, metavar="WxH", help="rescale every camera's intrinsics to W x H px"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor effects and the samples (default 0)")
    p.add_argument(
        "--peers",
        type=int,
        nargs="?",
        const=3,
        default=0,
        metavar="N",
        help="also run OctoMap (fresh and incremental tree) on the last N timed cycles' frames and print "
        "the side-by-side table (N = 3 without a value; 5 to 10 s per cycle and tree; needs the 'peers' extra)",
    )
    p.add_argument("--peers-resolution", type=float, default=0.05, metavar="M", help="OctoMap voxel size [m] (default 0.05)")
    p.add_argument(
        "--peers-full-rays",
        action="store_true",
        help="OctoMap casts every point's own ray (as MoveIt does) instead of one per voxel (discretize, the faster)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object and nothing else")
    p.set_defaults(func=_run)


# -- the cameras ---------------------------------------------------------------------------
def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H) [px], or PolyhullError naming ``--resolution``."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if m is None:
        raise PolyhullError(f"--resolution must be WxH in pixels (e.g. 640x480), got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (MIN_SIDE <= w <= MAX_SIDE and MIN_SIDE <= h <= MAX_SIDE):
        raise PolyhullError(f"--resolution: width and height must be in {MIN_SIDE}..{MAX_SIDE} px, got {w}x{h}")
    return w, h


def rescale_camera(camera: Any, width: int, height: int) -> Any:
    """The camera with its intrinsics rescaled to ``width`` x ``height`` px (same field of view)."""
    from ..camera import Intrinsics

    k = camera.intrinsics
    sx, sy = width / k.width, height / k.height
    # pixel centres sit at integers: the image edge -0.5 maps to -0.5
    scaled = Intrinsics(width, height, k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5, (k.cy + 0.5) * sy - 0.5)
    return replace(camera, intrinsics=scaled)


def ring_cameras(cell: Any, n: int) -> tuple[Any, ...]:
    """``n`` cameras like the cell's first one, evenly on a circle of radius ``RING_RADIUS``
    around the zone centre at height ``RING_HEIGHT``, looking at the zone centre at
    ``RING_TARGET_Z`` (the first one in the zone's min-x, min-y direction)."""
    from ..camera import look_at_rotation

    base = cell.cameras[0]
    centre = np.asarray(cell.zone.min) + 0.5 * cell.zone.size
    target = np.array([centre[0], centre[1], RING_TARGET_Z])
    cams = []
    for i in range(n):
        a = -0.75 * np.pi + 2.0 * np.pi * i / n
        pos = np.array([centre[0] + RING_RADIUS * np.cos(a), centre[1] + RING_RADIUS * np.sin(a), RING_HEIGHT])
        T = np.eye(4)
        T[:3, :3] = look_at_rotation(pos, target)
        T[:3, 3] = pos
        cams.append(replace(base, name=f"ring{i}", T_world_camera=T))
    return tuple(cams)


# -- the oracles ---------------------------------------------------------------------------
def _pixels(camera: Any, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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

    from ..distance import points_in_hexahedra

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
    """The exact per-pixel free depth of SPEC section 2, ``min(D, B) - tau(D)`` [m]."""
    from ..regions import free_depth

    return free_depth(static_camera.camera, depth, static_camera.reference)


def banded_free(static_camera: Any, depth: np.ndarray) -> np.ndarray:
    """The exact free depth clamped to the camera's static free depth f_s [m]: the engine's
    declared tolerance (a reading in the static band [lower, upper] frees only up to f_s, the
    free depth of the least reading in the band)."""
    return np.minimum(exact_free(static_camera, depth), static_camera.free_static)


def _solid(cell: Any, points: np.ndarray) -> np.ndarray:
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
        u, v, z, inside = _pixels(cam, points)
        usable = inside & (z >= cam.near)
        depth = frames[cam.name].depth
        for count, free in zip(freed, frees, strict=True):
            count += usable & (z <= free(s, depth)[v, u])
    solid = _solid(monitor.cell, points)
    k = monitor.cell.reconstruction.k_of_n
    return [(count < k) & ~solid for count in freed], solid


def exact_hull(
    monitor: Any, frames: Mapping[str, Any], points: np.ndarray, free: FreeDepth = exact_free
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) whether each point lies in the exact depth hull C of the frames (outside the solid
    obstacles), and (P,) whether it lies in a solid obstacle.

    A point frees in a camera when in the image, ``z >= near`` and ``z <= f[v, u]`` with the
    per-pixel free depth ``f = free(static camera, depth)`` (default :func:`exact_free`, the
    exact one of SPEC section 2; :func:`banded_free` gives the exact hull with the static
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
            u, v, z, inside = _pixels(s.camera, points)
            shadow |= inside & r.covered[v, u] & (z >= r.shadow_start[v, u])
    return shadow


def padded_robot_occlusion(monitor: Any, points: np.ndarray, band: bool = False) -> np.ndarray:
    """(P,) whether each point lies in the padded robot's occlusion M of the monitor's last
    cycle by its definition (SPEC section 2, ``M = F_static minus F_static+robot``, k of n):
    at least k cameras free it in the empty cell, by the exact free depth of the reference
    ``B - tau(B)``, and fewer once the padded robot's covered pixels free only up to its
    shadow start. Stricter than :func:`padded_robot_shadow` (some camera's shadow), which
    excuses a point one camera cannot see though others see it.

    ``band``: the empty cell frees only up to the least free depth of a reading in each
    pixel's own static band (``StaticCamera.own_free``: the engine's declared band
    tolerance, 4.5 sigma, not an edge's widened band): M as the engine's static model
    defines it, for a point within one camera's noise sheet that only that camera sees
    once the robot is in the cell (the detection capability's object thinner than the
    sheet)."""
    k = monitor.cell.reconstruction.k_of_n
    counts = []
    for robot in (False, True):
        count = np.zeros(len(points), dtype=np.int64)
        for s in monitor.static.cameras:
            cam = s.camera
            f = np.asarray(s.own_free, dtype=np.float64) if band else exact_free(s, s.reference)
            r = monitor.last_images.raster.get(cam.name) if robot and monitor.last_images is not None else None
            if r is not None:
                f = np.where(r.covered, np.minimum(f, r.shadow_start), f)
            u, v, z, inside = _pixels(cam, points)
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
    exact-C points outside R2 and outside the padded robot's M, by its definition or with
    the static band (:func:`padded_robot_occlusion`; must be 0: the padding and the band
    are the engine's declared tolerances); ``misses_band`` are those only the band
    excuses; ``misses_unexcused`` counts them all without an excuse.
    """
    cell = monitor.cell
    lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    p = np.random.default_rng(seed).uniform(lo, hi, size=(samples, 3))
    (exact, banded), solid = exact_hulls(monitor, frames, p, (exact_free, banded_free))
    shadow = padded_robot_shadow(monitor, p)
    r2 = engine_r2(monitor, verdict, p, solid)
    out = p[exact & ~r2]
    m_exact, m_band = padded_robot_occlusion(monitor, out), padded_robot_occlusion(monitor, out, band=True)
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
        "misses": int((~m_exact & ~m_band).sum()),
        "misses_band": int((~m_exact & m_band).sum()),
        "misses_unexcused": int((exact & ~r2).sum()),
    }


def dynamic_volume_outside_static(monitor: Any, verdict: Any) -> float:
    """Volume [m^3] of a verdict's kept dynamic pieces outside the static hull C_static and
    the solids: what this cycle adds to the static region (exact, by manifold3d booleans;
    off the hot path, a few hundred ms). The sheet boxes under kept pieces are part of
    R2_static, inside C_static, and add nothing here."""
    from ..verdict import hexahedra_manifold

    geometry = verdict._geometry
    if geometry is None or len(geometry.kept_pieces) == 0:
        return 0.0
    s = monitor.static
    added = (hexahedra_manifold(geometry.kept_pieces) ^ monitor._zone) - s.hull - s.solids
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
    - outside the unpadded robot's occlusion M (SPEC section 2: ``M = F_static \ F_static+robot``):
      it is not the case that at least k cameras free it in the empty cell (free depth of
      the reference) while fewer than k free it with the robot at q (free depth of the
      noise-free depth of the static scene plus the robot, ``Simulator.render_exact(q)``,
      so a point at or behind ``robot depth - tau(robot depth)`` on a pixel the robot
      covers is not freed there);
    - outside the solid obstacles;
    - outside the floor's noise sheet (the static model's floor sheet: below its top),
      except within ``plausibility.floor_shell_margin`` horizontally of the person's
      bounding box (a person keeps their feet).

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
    a margin around the person's box; a part reaching beyond the grid's sides is cut there
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
        p0, p1 = person.bounds
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


# -- the workloads -------------------------------------------------------------------------
def _stats(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {"median": math.nan, "min": math.nan, "max": math.nan}
    return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def _progress(total: int, desc: str, enabled: bool) -> Any:
    from tqdm import tqdm

    # to stderr, and only on a terminal (disable=None), so --json keeps stdout clean
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=None if enabled else True, leave=False)


def _walk(cell: Any) -> Any:
    """Person mesh at time t [s]: from a zone corner to 1 m in front of the robot and back,
    at ``WALK_SPEED``, repeated."""
    from .demo import person_path

    zmin, zmax = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    robot_xy = np.asarray(cell.robot.base[:2])
    length = max(float(np.linalg.norm(robot_xy - (zmin[:2] + 0.35))) - 1.0, 0.1)
    period = 2.0 * length / WALK_SPEED
    walk = person_path(zmin, zmax, robot_xy, period)
    return lambda t: walk(t % period)  # type: ignore[operator]


def run_bench(
    cell_path: Path | None = None,
    cycles: int = 20,
    warmup: int = 2,
    empty_cycles: int = 100,
    tightness_samples: int = 100_000,
    cameras: int | None = None,
    resolution: tuple[int, int] | None = None,
    seed: int = 0,
    progress: bool = False,
    peers: int = 0,
    peers_options: Any = None,
) -> dict[str, Any]:
    """Run the benchmark and its checks; return the figures (see the module docstring).

    Raises:
        PolyhullError: a bad argument (named after its flag) or a cell without a robot.
    """
    from ..cell import mesh_to_manifold
    from ..cellfile import default_cell_path, load_cell
    from ..errors import CellError
    from ..monitor import Monitor
    from ..simulator import SensorEffects, Simulator
    from .demo import robot_motion

    path = cell_path or default_cell_path()
    cell = load_cell(path)
    spec = cell.robot
    if spec is None:
        raise PolyhullError(f"{path}: the benchmark needs a cell with a [robot]")
    if not cell.cameras:
        raise PolyhullError(f"{path}: the benchmark needs a cell with cameras")
    try:
        if cameras is not None:
            cell = replace(cell, cameras=ring_cameras(cell, cameras))
    except CellError as exc:
        raise PolyhullError(f"--cameras: {exc}") from exc
    if resolution is not None:
        cell = replace(cell, cameras=tuple(rescale_camera(c, *resolution) for c in cell.cameras))

    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    robot, distance_model = monitor.robot, monitor._distance_model
    assert robot is not None and distance_model is not None  # the cell has a robot
    q0 = np.asarray(spec.q, dtype=np.float64)
    person_at = _walk(cell)
    n = warmup + cycles

    # 1. the reference workload: frames first, then the cycles
    inputs = []
    with _progress(n, "rendering", progress) as bar:
        for k in range(n):
            t = k * DT
            q = robot_motion(q0, robot.lower, robot.upper, t)
            person = person_at(t)
            inputs.append((sim.render(q, targets=[person], seed=seed + k, stamp=t), q, t, person))
            bar.update()
    stages: dict[str, list[float]] = {}
    first: list[float] = []  # the new monitor's first two cycles (the warm-up's effect)
    verdicts = []
    comparison = None  # OctoMap on the last ``peers`` timed cycles, alternating with the monitor
    if peers > 0:
        from ..peers import PeerComparison

        comparison = PeerComparison(
            monitor, lambda frames, points: exact_hull(monitor, frames, points),
            options=peers_options, samples=tightness_samples or 100_000, seed=seed,
        )
    with _progress(n, "cycles", progress) as bar:
        for k, (frames, q, t, person) in enumerate(inputs):
            v = monitor.step(frames, q, stamp=t)
            if comparison is not None and k >= n - min(peers, cycles):
                bar.set_postfix_str("and OctoMap")
                comparison.add(frames, q, person, v)
            # as a controller does, no verdict's regions are kept but the last one's (a
            # kept verdict keeps its cycle's images, and the monitor allocates new ones)
            if k < 2:
                first.append(v.timings["total"])
            if k >= warmup:
                for stage, ms in v.timings.items():
                    stages.setdefault(stage, []).append(ms)
            verdicts.append(v if k == n - 1 else replace(v, _geometry=None))
            del v
            bar.update()
    total = np.asarray(stages.pop("total"))

    # 2. the person: true distance (person mesh to the moving links) against the reported one
    gaps, trues, above = [], [], 0
    for (_, q, _, person), v in zip(inputs, verdicts, strict=True):
        true = distance_model.distance(
            robot.link_transforms(q), region=mesh_to_manifold(person, "person")
        ).distance
        if math.isfinite(true) and math.isfinite(v.min_distance):
            gaps.append(true - v.min_distance)
        above += int(v.min_distance > true + 1e-6)
        trues.append(true)
    person_faults = sorted({f for v in verdicts for f in v.faults})

    # 2b. the exact hull's own gap: its part that holds the person, against the links
    started = time.perf_counter()
    moving = set(distance_model.link_names)
    oracle = ExactHullGap(monitor, {n: m for n, m in robot.link_geometry().items() if n in moving}, seed=seed)
    exact_gaps, engine_losses, clipped = [], [], 0
    with _progress(len(inputs), "exact hull gap", progress) as bar:
        for (frames, q, _, person), v, true in zip(inputs, verdicts, trues, strict=True):
            d, cut = oracle.measure(frames, sim.render_exact(q), robot.link_transforms(q), person)
            clipped += int(cut)
            if math.isfinite(d) and math.isfinite(true):
                exact_gaps.append(true - d)
            if math.isfinite(d) and math.isfinite(v.min_distance):
                engine_losses.append(d - v.min_distance)
            bar.update()
    exact_seconds = time.perf_counter() - started

    # 3. tightness and misses on the last person cycle (before the monitor moves on)
    tightness = None
    if tightness_samples > 0 and verdicts[-1]._geometry is not None:
        tightness = tightness_and_misses(monitor, inputs[-1][0], verdicts[-1], tightness_samples, seed)
    del inputs

    # 4. the empty cell: the robot moving, every sensor effect on
    empty: dict[str, Any] | None = None
    if empty_cycles > 0:
        effects = SensorEffects(uint16=True)

        def empty_frames(k: int) -> tuple[Any, np.ndarray, float]:
            t = k * DT
            q = robot_motion(q0, robot.lower, robot.upper, t)
            return sim.render(q, seed=seed + 10_000 + k, stamp=t, effects=effects), q, t

        # its cost first: the first cycles back to back, frames rendered before (as the
        # person's cycles: the checks below run manifold booleans between cycles)
        timed = min(empty_cycles, warmup + cycles)
        with _progress(timed, "empty cell, timed", progress) as bar:
            frames_q_t = []
            for k in range(timed):
                frames_q_t.append(empty_frames(k))
                bar.update()
        monitor.reset()
        empty_ms = []
        for k, (frames, q, t) in enumerate(frames_q_t):
            v = monitor.step(frames, q, stamp=t)
            if k >= min(warmup, timed - 1):
                empty_ms.append(v.timings["total"])
        del frames_q_t, v
        monitor.reset()
        kept: list[int] = []
        added: list[float] = []
        dists: list[float] = []
        scales: list[float] = []
        faults: set[str] = set()
        off = 0
        with _progress(empty_cycles, "empty cell", progress) as bar:
            for k in range(empty_cycles):
                frames, q, t = empty_frames(k)
                v = monitor.step(frames, q, stamp=t)
                static = distance_model.distance(
                    robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains
                ).distance
                kept.append(v.counts.get("kept_pieces", 0))
                added.append(dynamic_volume_outside_static(monitor, v))
                off += int(not (v.min_distance == static or abs(v.min_distance - static) <= 0.01))
                dists.append(v.min_distance)
                scales.append(v.speed_scale)
                faults.update(v.faults)
                bar.update()
        empty = {
            "cycles": empty_cycles,
            "cycle_ms": {
                "median": float(np.median(empty_ms)),
                "p99": float(np.percentile(empty_ms, 99)),
                "max": float(np.max(empty_ms)),
                "cycles": len(empty_ms),
            },
            "kept_pieces": _stats(kept),
            "cycles_with_kept_pieces": int(np.count_nonzero(kept)),
            "dynamic_volume_outside_static_l": _stats([1e3 * a for a in added]),
            "min_volume_l": 1e3 * monitor.cell.plausibility.min_volume,
            "cycles_dynamic_volume_over_min_volume": int(
                sum(a > monitor.cell.plausibility.min_volume for a in added)
            ),
            "cycles_distance_off_static": off,
            "distance_m": _stats(dists),
            "speed_scale": _stats(scales),
            "faults": sorted(faults),
        }

    cams = cell.cameras
    return {
        "workload": {
            "cell": str(path),
            "cameras": len(cams),
            "camera_layout": "ring" if cameras is not None else "cell",
            "resolution": [cams[0].intrinsics.width, cams[0].intrinsics.height],
            "cycles": cycles,
            "warmup": warmup,
            "dt_s": DT,
            "seed": seed,
            "targets": f"one person walking at {WALK_SPEED} m/s toward the robot and back",
            "robot": "6-axis arm in motion",
            "sensor_effects": "default (noise, dropouts, out of range, flying pixels)",
            "empty_cell_sensor_effects": "all (default and uint16 millimetres)",
        },
        "cycle_ms": {"median": float(np.median(total)), "p99": float(np.percentile(total, 99)), "max": float(total.max())},
        "first_cycles_ms": first,
        "stages_ms_median": {s: float(np.median(v)) for s, v in stages.items()},
        "stages_cycles": {s: len(v) for s, v in stages.items()},
        "person": {
            "cycles": len(verdicts),
            "true_minus_reported_m": {k: v for k, v in _stats(gaps).items() if k != "min"},
            "cycles_reported_above_true": above,
            "exact_hull_gap_m": {k: v for k, v in _stats(exact_gaps).items() if k != "min"},
            "engine_minus_exact_m": {k: v for k, v in _stats(engine_losses).items() if k != "min"},
            "exact_hull_cycles": len(exact_gaps),
            "exact_hull_cycles_clipped": clipped,
            "exact_hull_grid_m": GAP_GRID,
            "exact_hull_seconds": exact_seconds,
            "distance_m": _stats([v.min_distance for v in verdicts]),
            "speed_scale": _stats([v.speed_scale for v in verdicts]),
            "faults": person_faults,
        },
        "tightness": tightness,
        "empty_cell": empty,
        "peers": None if comparison is None else comparison.result(),
    }


# -- the command ---------------------------------------------------------------------------
def _finite(obj: Any) -> Any:
    """JSON-safe copy: non-finite floats become None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _check(args: argparse.Namespace) -> tuple[int, int] | None:
    if args.cycles < 1:
        raise PolyhullError(f"--cycles must be >= 1, got {args.cycles}")
    if args.warmup < 0:
        raise PolyhullError(f"--warmup must be >= 0, got {args.warmup}")
    if args.empty_cycles < 0:
        raise PolyhullError(f"--empty-cycles must be >= 0, got {args.empty_cycles}")
    if not 0 <= args.tightness_samples <= MAX_SAMPLES:
        raise PolyhullError(f"--tightness-samples must be in 0..{MAX_SAMPLES}, got {args.tightness_samples}")
    if args.cameras is not None and not 1 <= args.cameras <= MAX_CAMERAS:
        raise PolyhullError(f"--cameras must be in 1..{MAX_CAMERAS}, got {args.cameras}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")
    if args.peers < 0:
        raise PolyhullError(f"--peers must be >= 0 cycles, got {args.peers}")
    return None if args.resolution is None else parse_resolution(args.resolution)


def _fmt(x: float | None, spec: str = ".3f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _run(args: argparse.Namespace) -> int:
    resolution = _check(args)
    peers_options = None
    if args.peers:
        from ..peers import OctomapOptions, require_octomap

        require_octomap()  # before any work: a missing extra is one line
        peers_options = OctomapOptions(resolution=args.peers_resolution, discretize=not args.peers_full_rays)
    # anything the engine prints goes to stderr: with --json, stdout holds the object only
    with contextlib.redirect_stdout(sys.stderr):
        result = run_bench(
            args.cell, args.cycles, args.warmup, args.empty_cycles, args.tightness_samples,
            args.cameras, resolution, args.seed, progress=True, peers=args.peers, peers_options=peers_options,
        )
    if args.json:
        print(json.dumps(_finite(result), indent=2))
        return 0
    w, c = result["workload"], result["cycle_ms"]
    print(f"polyhull bench: {w['cameras']} cameras {w['resolution'][0]}x{w['resolution'][1]}, "
          f"{w['cycles']} cycles after {w['warmup']} warm-up")
    print(f"{'stage':<16}{'median [ms]':>12}")
    for stage, ms in result["stages_ms_median"].items():
        ran = result["stages_cycles"][stage]
        note = "" if ran == w["cycles"] else f"   (ran in {ran} of {w['cycles']} cycles)"
        print(f"{stage:<16}{ms:12.1f}{note}")
    print(f"{'cycle median':<16}{c['median']:12.1f}")
    print(f"{'cycle p99':<16}{c['p99']:12.1f}")
    print("a new monitor's first cycles: " + ", ".join(f"{ms:.1f}" for ms in result["first_cycles_ms"]) + " ms")
    p = result["person"]
    g = p["true_minus_reported_m"]
    print(f"person: {p['cycles']} cycles, true - reported distance median {_fmt(g['median'])} m, "
          f"max {_fmt(g['max'])} m; reported above true in {p['cycles_reported_above_true']} cycles; "
          f"speed scale median {_fmt(p['speed_scale']['median'], '.2f')}, min {_fmt(p['speed_scale']['min'], '.2f')}")
    x, e = p["exact_hull_gap_m"], p["engine_minus_exact_m"]
    print(f"exact hull around the person ({p['exact_hull_grid_m'] * 100:.1f} cm grid, {p['exact_hull_cycles']} cycles, "
          f"{p['exact_hull_seconds']:.1f} s): true distance - its distance median {_fmt(x['median'])} m, max "
          f"{_fmt(x['max'])} m (the least gap a conservative region from these cameras can have; an estimate)")
    print(f"engine against that exact hull: its distance - reported median {_fmt(e['median'])} m, "
          f"max {_fmt(e['max'])} m (what the engine loses to the exact hull)")
    if p["faults"]:
        print(f"  faults: {'; '.join(p['faults'])}")
    t = result["tightness"]
    if t is not None:
        print(f"tightness (last person cycle, {t['samples']} samples): exact C ~{t['volume_exact_hull_m3']:.3f} m^3, "
              f"engine R2 ~{t['volume_engine_r2_m3']:.3f} m^3, excess {_fmt(t['excess_percent'], '+.1f')} % "
              f"({_fmt(t['excess_outside_robot_shadow_percent'], '+.1f')} % against C outside the robot shadow)")
        print(f"R2 against the exact hull with the static band: {t['volume_engine_r2_m3']:.1f} vs "
              f"{t['volume_exact_banded_m3']:.1f} m^3 ({_fmt(t['excess_over_banded_percent'], '+.0f')} %)")
        print(f"misses: {t['misses']} (outside R2 and the padded robot's M), {t['misses_band']} in M only with the "
              f"static band, unexcused {t['misses_unexcused']}")
    e = result["empty_cell"]
    if e is not None:
        c = e["cycle_ms"]
        print(f"empty cell: cycle median {c['median']:.1f} ms, p99 {c['p99']:.1f} ms ({c['cycles']} cycles back to back)")
        print(f"empty cell: {e['cycles']} cycles, kept pieces median {e['kept_pieces']['median']:.0f}, "
              f"max {e['kept_pieces']['max']:.0f} ({e['cycles_with_kept_pieces']} cycles with any); distance "
              f"off the static region's by > 1 cm in {e['cycles_distance_off_static']} cycles; distance median "
              f"{_fmt(e['distance_m']['median'])} m, min {_fmt(e['distance_m']['min'])} m; speed scale median "
              f"{_fmt(e['speed_scale']['median'], '.2f')}, min {_fmt(e['speed_scale']['min'], '.2f')}")
        a = e["dynamic_volume_outside_static_l"]
        print(f"empty cell: dynamic volume outside C_static median {_fmt(a['median'], '.1f')} l, max "
              f"{_fmt(a['max'], '.1f')} l; over the too-small threshold ({e['min_volume_l']:g} l) in "
              f"{e['cycles_dynamic_volume_over_min_volume']} of {e['cycles']} cycles")
        if e["faults"]:
            print(f"  faults: {'; '.join(e['faults'])}")
    if result["peers"] is not None:
        from ..peers import format_table

        print(format_table(result["peers"]))
    return 0
