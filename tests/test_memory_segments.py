"""The shadow memory's segments hold every box's own segment (a superset, per cell)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.pixels import memory_segments


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([1, 4, 8]))
def test_memory_segments_hold_each_box_segment(seed: int, cell: int) -> None:
    rng = np.random.default_rng(seed)
    H, W = (int(x) for x in rng.integers(4, 40, size=2))
    covered = rng.random((H, W)) < 0.6
    back = np.where(covered, rng.uniform(1.0, 2.0, (H, W)), -np.inf).astype(np.float32)
    free = rng.uniform(0.5, 3.0, (H, W)).astype(np.float32)
    fs = (free + rng.uniform(0.0, 3.0, (H, W))).astype(np.float32)
    B = int(rng.integers(0, 12))
    u0 = rng.integers(-3, W, B)
    v0 = rng.integers(-3, H, B)
    rects = np.column_stack([u0, u0 + rng.integers(0, 10, B), v0, v0 + rng.integers(0, 10, B)])
    z0 = rng.uniform(0.5, 4.0, B)
    zr = np.column_stack([z0, z0 + rng.uniform(0.0, 2.0, B)])
    f, e = memory_segments(covered, back, free, fs, rects, zr, cell=cell)
    has = f < e
    assert not (has & ~covered).any()
    for b in range(B):
        a0, a1 = max(rects[b, 0], 0), min(rects[b, 1], W - 1)
        c0, c1 = max(rects[b, 2], 0), min(rects[b, 3], H - 1)
        for v in range(c0, c1 + 1):
            for u in range(a0, a1 + 1):
                if not covered[v, u]:
                    continue
                start = max(float(free[v, u]), float(back[v, u]), zr[b, 0])
                stop = min(float(fs[v, u]), zr[b, 1])
                if start < stop:
                    assert f[v, u] <= start and e[v, u] >= stop
    if cell == 1:
        # per pixel, nothing beyond the boxes' rectangles
        inside = np.zeros((H, W), dtype=bool)
        for b in range(B):
            inside[max(rects[b, 2], 0) : rects[b, 3] + 1, max(rects[b, 0], 0) : rects[b, 1] + 1] = True
        assert not (has & ~inside).any()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_box_rects_equal_projected_corners(seed: int) -> None:
    """box_rects gives, for the boxes in front of the camera that reach beyond a depth and
    meet a window, the window-clipped pixel rectangle and z range of their 8 corners'
    projections (Camera.project written out)."""
    from conftest import make_camera

    from polyhull.engine.pixels import box_rects

    rng = np.random.default_rng(seed)
    cam = make_camera(width=64, height=48)
    B = int(rng.integers(0, 30))
    centre = cam.camera_to_world(np.column_stack([rng.uniform(-2, 2, B), rng.uniform(-2, 2, B), rng.uniform(-0.5, 4, B)]))
    lo = centre - rng.uniform(0.0, 0.5, (B, 3))
    hi = centre + rng.uniform(0.0, 0.5, (B, 3))
    window = (int(rng.integers(0, 30)), int(rng.integers(30, 64)), int(rng.integers(0, 20)), int(rng.integers(20, 48)))
    z_beyond = float(rng.uniform(0.5, 3.0))
    k = cam.intrinsics
    rects, zr = box_rects(lo, hi, cam.T_camera_world, (k.fx, k.fy, k.cx, k.cy), z_beyond, window)
    corners = np.stack([np.where(np.array([m & 1, m & 2, m & 4]) > 0, hi, lo) for m in range(8)], axis=1)
    uv, z = cam.project(corners.reshape(-1, 3))
    uv, z = uv.reshape(-1, 8, 2), z.reshape(-1, 8)
    ok = (z.max(axis=1) > z_beyond) & (z.min(axis=1) > 1e-6)
    with np.errstate(invalid="ignore"):
        r = np.floor(np.stack([uv[..., 0].min(1), uv[..., 0].max(1), uv[..., 1].min(1), uv[..., 1].max(1)], 1) + 0.5)
    ok &= (r[:, 1] >= window[0]) & (r[:, 0] <= window[1]) & (r[:, 3] >= window[2]) & (r[:, 2] <= window[3])
    want = np.column_stack(
        [np.maximum(r[ok, 0], window[0]), np.minimum(r[ok, 1], window[1]), np.maximum(r[ok, 2], window[2]), np.minimum(r[ok, 3], window[3])]
    )
    np.testing.assert_array_equal(rects, want.astype(np.int64))
    np.testing.assert_allclose(zr, np.column_stack([z[ok].min(1), z[ok].max(1)]), rtol=0, atol=1e-12)
