"""The static touch grid answers "within d of the region?" with a superset, in every direction.

The grid used to dilate the surface voxels with a 6-connected cross (an L1 ball), which
missed voxels diagonal to the region although points in them can touch it; the
Euclidean distance transform marks them.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.static_model import TouchGrid


@settings(max_examples=30, deadline=None)
@given(
    corner=st.tuples(*[st.floats(0.2, 0.8)] * 3),
    size=st.tuples(*[st.floats(0.05, 0.6)] * 3),
    distance=st.sampled_from([0.0, 0.02, 0.05, 0.1]),
    seed=st.integers(0, 2**16),
)
def test_points_within_distance_are_marked(corner, size, distance, seed) -> None:  # noqa: ANN001
    lo_box, sz = np.asarray(corner), np.asarray(size)
    region = m3.Manifold.cube(tuple(sz)).translate(tuple(lo_box))
    grid = TouchGrid.within(region, np.zeros(3) - 0.2, np.full(3, 1.8), pitch=0.05, distance=distance)
    rng = np.random.default_rng(seed)
    # points at distance <= d from the box, in every direction (corners included)
    p = rng.uniform(lo_box - distance - 0.01, lo_box + sz + distance + 0.01, size=(4000, 3))
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo_box - p, p - (lo_box + sz))), axis=1)
    p = p[gap <= distance]
    assert grid.any_in(p, p).all()


def test_far_boxes_are_not_marked() -> None:
    region = m3.Manifold.cube((0.2, 0.2, 0.2)).translate((0.4, 0.4, 0.4))
    grid = TouchGrid.within(region, np.zeros(3), np.ones(3) * 1.5, pitch=0.05, distance=0.05)
    far = np.array([[1.2, 1.2, 1.2], [0.0, 0.0, 0.0]])
    assert not grid.any_in(far, far).any()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_box_queries_equal_the_voxels_they_meet(seed: int) -> None:
    """A box query says "marked" exactly when a marked voxel meets the box (clipped to the
    grid): the summed-volume table against the voxels themselves, boxes of every size and
    place (inside, across and outside the grid)."""
    rng = np.random.default_rng(seed)
    # larger than a coarse block on every axis, sparse: boxes in unmarked blocks too
    occ = rng.uniform(size=(21, 17, 19)) < 0.004
    table = np.zeros(tuple(np.asarray(occ.shape) + 1), dtype=np.int32)
    table[1:, 1:, 1:] = occ.astype(np.int32).cumsum(0).cumsum(1).cumsum(2)
    grid = TouchGrid(np.array([0.1, -0.2, 0.3]), 0.1, table)
    lo = rng.uniform(-0.5, 2.5, size=(600, 3))
    hi = lo + rng.uniform(0.0, 0.6, size=(600, 3)) * (rng.uniform(size=(600, 1)) < 0.8)
    got = grid.any_in(lo, hi)
    a = np.clip(np.floor((lo - grid.origin) / grid.pitch).astype(np.int64), 0, np.array(occ.shape))
    b = np.clip(np.floor((hi - grid.origin) / grid.pitch).astype(np.int64) + 1, 0, np.array(occ.shape))
    want = np.array([occ[a[i, 0] : b[i, 0], a[i, 1] : b[i, 1], a[i, 2] : b[i, 2]].any() for i in range(len(lo))])
    np.testing.assert_array_equal(got, want)
