"""The padded robot's raster against a ray-casting oracle, and its reused buffers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from polyhull.cell import Cell
from polyhull.commands.bench import rescale_camera
from polyhull.engine.robot_raster import PaddedPieces, RasterBuffers, rasterize_robot
from polyhull.robot import Robot

SUB = 3  # rays per side of a pixel's grown square (its corners and centre)


@pytest.fixture(scope="module")
def setup(small_cell: Cell) -> tuple[Robot, PaddedPieces, list]:  # type: ignore[type-arg]
    robot = Robot.from_spec(small_cell.robot)  # type: ignore[arg-type]
    padded = PaddedPieces.build(robot.link_convex_pieces(), small_cell.robot.padding)  # type: ignore[union-attr]
    cams = [rescale_camera(c, 64, 48) for c in small_cell.cameras]
    return robot, padded, cams


def _oracle(camera, pieces_world: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Per pixel: hit by a ray through its square grown by one pixel (SUB x SUB rays),
    and the least entry / greatest exit z-depth of those rays through the convex pieces."""
    H, W = camera.shape
    k = camera.intrinsics
    off = np.linspace(-1.5, 1.5, SUB)
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    du, dv = np.meshgrid(off, off)
    u = (uu[:, :, None] + du.ravel()[None, None, :]).ravel()
    v = (vv[:, :, None] + dv.ravel()[None, None, :]).ravel()
    d_cam = np.column_stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)])  # z = 1
    R = camera.T_world_camera[:3, :3]
    o = camera.T_world_camera[:3, 3]
    d = d_cam @ R.T
    front = np.full(len(u), np.inf)
    back = np.full(len(u), -np.inf)
    for verts in pieces_world:
        uv, z = camera.project(verts)
        if (z <= 1e-3).any():
            sel = np.arange(len(u))
        else:  # only the rays through the piece's projected bounding box can meet it
            lo, hi = uv.min(axis=0) - 1e-6, uv.max(axis=0) + 1e-6
            sel = np.nonzero((u >= lo[0]) & (u <= hi[0]) & (v >= lo[1]) & (v <= hi[1]))[0]
        eq = np.unique(ConvexHull(verts).equations.round(12), axis=0)  # n . x + c <= 0 inside
        nd = d[sel] @ eq[:, :3].T
        no = eq[:, :3] @ o + eq[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -no[None, :] / nd
        t_in = np.where(nd < 0, t, -np.inf).max(axis=1)
        t_out = np.where(nd > 0, t, np.inf).min(axis=1)
        outside_parallel = ((nd == 0) & (no[None, :] > 0)).any(axis=1)
        hit = (t_in <= t_out) & (t_out > 0) & ~outside_parallel
        front[sel] = np.where(hit, np.minimum(front[sel], np.maximum(t_in, 0.0)), front[sel])
        back[sel] = np.where(hit, np.maximum(back[sel], t_out), back[sel])
    shape = (H, W, SUB * SUB)
    return np.isfinite(front).reshape(shape).any(axis=2), front.reshape(shape).min(axis=2), back.reshape(shape).max(axis=2)


@settings(max_examples=6, deadline=None)
@given(st.lists(st.floats(-2.5, 2.5), min_size=6, max_size=6))
def test_raster_bounds_the_padded_robot(setup, q) -> None:  # noqa: ANN001
    """Every ray through a pixel's grown square that meets a padded piece marks the pixel
    covered, with front <= its entry depth and back >= its exit depth (z-depth)."""
    robot, padded, cams = setup
    q = np.clip(np.asarray(q), robot.lower, robot.upper)
    world = padded.world(robot.link_transforms(q))
    for cam in cams:
        r = rasterize_robot(cam, world, padded)
        hit, front, back = _oracle(cam, world)
        assert not (hit & ~r.covered).any()
        near = np.maximum(front, cam.near)
        assert (r.front[hit] <= near[hit] * (1 + 1e-6)).all()
        assert (r.back[hit] >= back[hit] * (1 - 1e-6)).all()
        assert (r.shadow_start[hit] <= r.front[hit]).all()
        if r.rect is not None:
            # the covered pixels' bounding rectangle, and their least back depth
            rows, cols = np.nonzero(r.covered.any(axis=1))[0], np.nonzero(r.covered.any(axis=0))[0]
            assert r.rect == (cols[0], cols[-1], rows[0], rows[-1])
            assert r.back_min == float(r.back[r.covered].min())
        else:
            assert not r.covered.any()
            assert r.back_min == np.inf


def test_reused_buffers_equal_fresh_images(setup) -> None:  # noqa: ANN001
    """With reused images (reset only where the last raster wrote), each raster equals a
    fresh one."""
    robot, padded, cams = setup
    cam = cams[0]
    buffers = RasterBuffers(cam.shape)
    rng = np.random.default_rng(3)
    lo = np.maximum(robot.lower, -2.5)
    hi = np.minimum(robot.upper, 2.5)
    for _ in range(6):
        world = padded.world(robot.link_transforms(rng.uniform(lo, hi)))
        got = rasterize_robot(cam, world, padded, buffers)
        fresh = rasterize_robot(cam, world, padded)
        for name in ("covered", "front", "back", "shadow_start"):
            np.testing.assert_array_equal(getattr(got, name), getattr(fresh, name))
        assert got.rect == fresh.rect
    assert not buffers.zbuf[np.isfinite(buffers.zbuf)].size  # the depth buffers are reset


def test_a_failed_raster_leaves_no_stale_depth(setup, monkeypatch: pytest.MonkeyPatch) -> None:  # noqa: ANN001
    """A raster that fails halfway resets the shared buffers: the next one equals a fresh one."""
    import polyhull.engine.robot_raster as rr

    robot, padded, cams = setup
    cam = cams[0]
    buffers = RasterBuffers(cam.shape)
    world = padded.world(robot.link_transforms(np.zeros(len(robot.lower))))
    rasterize_robot(cam, world, padded, buffers)

    def failing(pix, tris, W, H, near, zbuf, zback, rect):  # noqa: ANN001, ANN202
        zbuf[:5, :5] = 0.01  # a near depth left behind
        raise RuntimeError("kernel failed")

    with monkeypatch.context() as m:
        m.setattr(rr, "_raster", failing)
        with pytest.raises(RuntimeError):
            rasterize_robot(cam, world, padded, buffers)
    q = np.clip(np.full(len(robot.lower), 0.4), robot.lower, robot.upper)
    world = padded.world(robot.link_transforms(q))
    got = rasterize_robot(cam, world, padded, buffers)
    fresh = rasterize_robot(cam, world, padded)
    for name in ("covered", "front", "back", "shadow_start"):
        np.testing.assert_array_equal(getattr(got, name), getattr(fresh, name))
