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
