"""Shared fixtures of the reconstruction engine tests: the small cell, its simulator and monitor.

The monitor and simulator are session-scoped (a Monitor takes ~0.5 s to build); tests that
step a monitor must call ``monitor.reset()`` first, which the ``fresh_monitor`` fixture does.

Hypothesis runs derandomized (the same examples on every machine and run), so a red test
is reproducible and CI cannot turn red on a newly drawn example; ``HYPOTHESIS_PROFILE=explore``
draws fresh examples to search for new counterexamples.
"""

from __future__ import annotations

import os
from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
from hypothesis import settings
from scipy.spatial import cKDTree

from polyhull.camera import Camera, Intrinsics, look_at_rotation
from polyhull.cell import Cell
from polyhull.cellfile import load_cell
from polyhull.monitor import Monitor
from polyhull.simulator import Simulator

# no deadline: a test's first example may compile the numba kernels it calls (a cold cache
# on a fresh machine takes seconds), and timing is the benchmark's business, not the tests'
settings.register_profile("ci", derandomize=True, deadline=None)
settings.register_profile("explore", derandomize=False, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
SMALL_CELL = FIXTURES / "cells" / "small_cell.toml"


@pytest.fixture(scope="session")
def small_cell() -> Cell:
    """The two-camera small cell of ``fixtures/cells/small_cell.toml``."""
    return load_cell(SMALL_CELL)


@pytest.fixture(scope="session")
def small_sim(small_cell: Cell) -> Simulator:
    """A simulator of the small cell (default sensor effects)."""
    return Simulator(small_cell)


@pytest.fixture(scope="session")
def small_monitor(small_cell: Cell, small_sim: Simulator) -> Monitor:
    """A monitor of the small cell, with the simulator's reference depth."""
    return Monitor(small_cell, references=small_sim.reference())


@pytest.fixture(scope="module")
def paper() -> tuple[Monitor, Simulator]:
    """A monitor of the default (paper) cell and its simulator, one per test module."""
    from polyhull.cellfile import default_cell_path

    cell = load_cell(default_cell_path())
    sim = Simulator(cell)
    return Monitor(cell, references=sim.reference()), sim


@pytest.fixture()
def fresh_monitor(small_monitor: Monitor) -> Monitor:
    """The session monitor with its faults and history cleared."""
    small_monitor.reset()
    return small_monitor


def make_camera(
    width: int = 64,
    height: int = 48,
    kind: str = "depth",
    position: tuple[float, float, float] = (0.3, 0.2, 3.0),
    target: tuple[float, float, float] = (0.0, 0.0, 0.0),
    near: float = 0.3,
    far: float = 6.0,
    noise: float = 0.003,
) -> Camera:
    """A small test camera looking from ``position`` at ``target`` [m]."""
    f = 0.8 * width
    k = Intrinsics(width=width, height=height, fx=f, fy=f * 1.05, cx=(width - 1) / 2, cy=(height - 1) / 2)
    T = np.eye(4)
    T[:3, :3] = look_at_rotation(np.array(position, float), np.array(target, float))
    T[:3, 3] = position
    return Camera(name="test", kind=kind, intrinsics=k, T_world_camera=T, near=near, far=far, noise=noise)  # type: ignore[arg-type]


def manifold_contains(
    region: m3.Manifold, points: np.ndarray, half: float = 1e-6, chunk: int = 800
) -> np.ndarray:
    """Which points (N, 3) lie inside a manifold (within ``half`` [m] of it).

    One boolean: the region intersected with a tiny cube around every point, then the
    pieces of the result mapped back to their points. Independent of ray casting (trimesh's
    ``contains`` misreports points for boolean results with many coplanar faces).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inside = np.zeros(len(points), dtype=bool)
    if region.is_empty() or len(points) == 0:
        return inside
    bb = np.asarray(region.bounding_box(), dtype=np.float64)
    cand = np.nonzero(np.all((points >= bb[:3] - half) & (points <= bb[3:] + half), axis=1))[0]
    cube = m3.Manifold.cube((2 * half,) * 3, True)
    for start in range(0, len(cand), chunk):  # decompose() grows superlinearly: chunk
        idx = cand[start : start + chunk]
        cubes = m3.Manifold.compose([cube.translate(tuple(points[i])) for i in idx])
        pieces = (region ^ cubes).decompose()
        if not pieces:
            continue
        centers = np.array(
            [np.asarray(p.bounding_box(), dtype=np.float64).reshape(2, 3).mean(axis=0) for p in pieces]
        )
        _, nearest = cKDTree(points[idx]).query(centers)
        inside[idx[nearest]] = True
    return inside


def exactly_possibly_occupied(monitor: Monitor, frames: dict, points: np.ndarray) -> np.ndarray:  # type: ignore[type-arg]
    """The exact per-pixel oracle: a point is possibly occupied unless k cameras (the cell's
    k-of-n rule) see it in front of the exact free depth ``min(D, B) - tau(D)`` of the
    pixel it projects to."""
    from polyhull.regions import free_depth

    freed = np.zeros(len(points), dtype=np.int64)
    for s in monitor.statics:
        cam = s.camera
        f = free_depth(cam, np.asarray(frames[cam.name].depth, dtype=np.float64), s.reference)
        uv, z = cam.project(points)
        H, W = cam.shape
        with np.errstate(invalid="ignore"):
            in_view = (z >= cam.near) & (z <= cam.far) & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5)
            in_view &= (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
        ui = np.clip(np.floor(np.nan_to_num(uv[:, 0]) + 0.5).astype(int), 0, W - 1)
        vi = np.clip(np.floor(np.nan_to_num(uv[:, 1]) + 0.5).astype(int), 0, H - 1)
        freed += in_view & (z <= f[vi, ui])
    return freed < monitor.cell.reconstruction.k_of_n


def in_robot_occlusion(monitor: Monitor, points: np.ndarray) -> np.ndarray:
    """(P,) whether points lie in the padded robot's occlusion M of the monitor's last cycle
    by its definition (``M = F_static minus F_static+robot``, k of n): at
    least k cameras free them in the empty cell, fewer with the robot
    (:func:`polyhull.oracles.padded_robot_occlusion`). Stricter than "in some
    camera's robot shadow", which excuses a point one camera cannot see though another
    sees it."""
    from polyhull.oracles import padded_robot_occlusion

    return padded_robot_occlusion(monitor, points)


def in_declared_occlusion(monitor: Monitor, frames: dict, points: np.ndarray) -> np.ndarray:  # type: ignore[type-arg]
    """(P,) :func:`in_robot_occlusion`, or in M with the engine's declared tolerances (the
    bench's excuses, :func:`polyhull.oracles.tightness_and_misses`): the empty cell freeing
    up to each pixel's own static band, and a static edge's flying readings of ``frames``
    taken for the static scene (:func:`polyhull.oracles.flying_edge_free`)."""
    from polyhull.oracles import padded_robot_occlusion

    return (
        in_robot_occlusion(monitor, points)
        | padded_robot_occlusion(monitor, points, band=True)
        | padded_robot_occlusion(monitor, points, band=True, frames=frames)
    )


def zone_and_person_points(cell: Cell, person: object, rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """(<= 2n, 3) points for the miss oracle: n uniform in the zone, n in the person's
    bounding box grown by 0.5 m, those outside the zone dropped."""
    lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    b = person.bounds  # type: ignore[attr-defined]
    points = np.concatenate([rng.uniform(lo, hi, size=(n, 3)), rng.uniform(b[0] - 0.5, b[1] + 0.5, size=(n, 3))])
    return points[np.all((points >= lo) & (points <= hi), axis=1)]


def outside_r2(monitor: Monitor, frames: dict, verdict: object, points: np.ndarray) -> tuple[int, np.ndarray]:  # type: ignore[type-arg]
    """How many ``points`` the exact per-pixel free depth leaves possibly occupied, and those
    of them outside the verdict's R2 (C_static with the cell's k, or a dynamic piece), the
    solids and the padded robot's M by its definition: each a miss unless a declared
    tolerance holds it (:func:`in_declared_occlusion`)."""
    from polyhull.distance import points_in_hexahedra
    from polyhull.oracles import in_solids

    cell = monitor.cell
    occupied = exactly_possibly_occupied(monitor, frames, points)
    in_r2 = monitor.static.hull_contains(points, cell.reconstruction.k_of_n)
    in_r2 |= points_in_hexahedra(points, verdict._geometry.pieces)  # type: ignore[attr-defined]
    out = points[occupied & ~in_r2 & ~in_solids(cell, points)]
    return int(occupied.sum()), out[~in_robot_occlusion(monitor, out)]


def in_robot_span(monitor: Monitor, points: np.ndarray) -> np.ndarray:
    """(P,) whether points lie, in every camera whose robot raster covers their pixel,
    between the padded robot's front and back depths there (the padded robot itself, or a
    gap between its pieces along the ray: the memory holds neither), and some camera
    covers them."""
    some = np.zeros(len(points), dtype=bool)
    every = np.ones(len(points), dtype=bool)
    assert monitor.last_images is not None
    for s in monitor.statics:
        cam = s.camera
        r = monitor.last_images.raster.get(cam.name)
        if r is None:
            continue
        from polyhull.oracles import pixels_of

        ui, vi, z, ok = pixels_of(cam, points)
        cov = ok & r.covered[vi, ui]
        some |= cov
        every &= ~cov | ((z >= r.front[vi, ui]) & (z <= r.back[vi, ui]))
    return some & every


def pixel_points(camera: Camera, v: np.ndarray, u: np.ndarray, z0: np.ndarray, z1: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) world points drawn uniformly in the footprints of pixels (v, u), between
    z-depths ``z0`` and ``z1``."""
    n = len(v)
    pv, pu = v + rng.uniform(-0.5, 0.5, n), u + rng.uniform(-0.5, 0.5, n)
    z = z0 + rng.uniform(0, 1, n) * (z1 - z0)
    k = camera.intrinsics
    return camera.camera_to_world(np.column_stack([(pu - k.cx) / k.fx * z, (pv - k.cy) / k.fy * z, z]))


def in_raster_shadows(cameras, rasters, i: int, points: np.ndarray) -> list[tuple[int, np.ndarray]]:  # type: ignore[no-untyped-def]
    """Per camera j other than ``i``: (j, the indices of ``points`` that its robot raster
    puts in the padded robot's shadow: a covered pixel, at or behind the shadow's start)."""
    out = []
    for j, r in enumerate(rasters):
        if j == i:
            continue
        uv, zj = cameras[j].project(points)
        px = np.floor(uv + 0.5).astype(np.int64)
        H, W = cameras[j].shape
        inside = (zj > 0) & (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
        idx = np.nonzero(inside)[0]
        shadowed = r.covered[px[idx, 1], px[idx, 0]] & (zj[idx] >= r.shadow_start[px[idx, 1], px[idx, 0]])
        out.append((j, idx[shadowed]))
    return out


def robot_shadow_poses(monitor: Monitor, rng: np.random.Generator, n: int = 6):  # type: ignore[no-untyped-def]
    """The padded robot at the cell's joint state, then at ``n - 1`` random ones: per pose,
    its pieces' image boxes in every camera (``robot_boxes``) and every camera's raster."""
    from polyhull.engine.edge_wedges import robot_boxes
    from polyhull.engine.robot_raster import rasterize_robot

    robot, padded = monitor.robot, monitor._padded
    assert robot is not None and padded is not None
    cams = monitor.cell.cameras
    for trial in range(n):
        q = robot.lower + rng.random(len(robot.lower)) * (robot.upper - robot.lower)
        if trial == 0:
            q = np.asarray(monitor.cell.robot.q, dtype=np.float64)  # type: ignore[union-attr]
        world = padded.world(robot.link_transforms(q))
        yield robot_boxes(cams, world), [rasterize_robot(c, world, padded) for c in cams]


def lost_points(monitor: Monitor, frames: dict, verdict, points: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def, type-arg]
    """The ``points`` (in Z) of a target the verdict loses: outside R3 (the static region
    and the kept dynamic pieces) and not excused (in M by its definition, in a solid, or
    not possibly occupied by the exact free depth of ``frames``)."""
    from polyhull.distance import points_in_hexahedra
    from polyhull.oracles import in_solids

    in_r3 = manifold_contains(monitor.static.region, points) | points_in_hexahedra(points, verdict._geometry.kept)
    excused = (
        in_robot_occlusion(monitor, points)
        | in_solids(monitor.cell, points)
        | ~exactly_possibly_occupied(monitor, frames, points)
    )
    return points[~(in_r3 | excused)]  # type: ignore[no-any-return]
