"""merge_adjacent (polyhull.engine.pieces): pieces of one camera adjacent along u, v or depth
with equal other extents merged back into one; the same set, in fewer pieces."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.pieces import merge_adjacent


def _split(rng: np.random.Generator, box: list[float], depth: int, out: list[list[float]]) -> None:
    """Split a piece in halves along a random axis, recursively (as the carve does)."""
    c, u0, u1, v0, v1, z0, z1 = box
    if depth == 0 or rng.random() < 0.25:
        out.append(box)
        return
    axis = rng.integers(3)
    if axis == 0 and u1 > u0:
        m = (u0 + u1) // 2
        halves = [[c, u0, m, v0, v1, z0, z1], [c, m + 1, u1, v0, v1, z0, z1]]
    elif axis == 1 and v1 > v0:
        m = (v0 + v1) // 2
        halves = [[c, u0, u1, v0, m, z0, z1], [c, u0, u1, m + 1, v1, z0, z1]]
    else:
        zm = 0.5 * (z0 + z1)
        halves = [[c, u0, u1, v0, v1, z0, zm], [c, u0, u1, v0, v1, zm, z1]]
    for h in halves:
        _split(rng, h, depth - 1, out)


def _inside(boxes: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(P,) whether each image-space point (camera, u, v, z) lies in some box."""
    c, u, v, z = (pts[:, k, None] for k in range(4))
    b = boxes[None]
    return np.any(
        (c == b[..., 0]) & (u >= b[..., 1]) & (u <= b[..., 2]) & (v >= b[..., 3]) & (v <= b[..., 4])
        & (z >= b[..., 5]) & (z <= b[..., 6]),
        axis=1,
    )


@settings(max_examples=60)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 0.9))
def test_merged_pieces_are_the_same_set_in_fewer_pieces(seed: int, drop: float) -> None:
    rng = np.random.default_rng(seed)
    pieces: list[list[float]] = []
    for c in range(2):
        for u0 in (0, 16):
            _split(rng, [c, u0, u0 + 15, 0, 15, 1.0, 5.0], 7, pieces)
    boxes = np.array(pieces)
    boxes = boxes[rng.random(len(boxes)) >= drop]  # some pieces dropped (seen free)
    merged = merge_adjacent(boxes)
    assert len(merged) <= len(boxes)
    # the same set: pixel centres, pixel edges' neighbours and depths at the pieces' own
    # bounds (where a merge could leave a gap or add a sliver) and in between
    zs = np.unique(np.concatenate([boxes[:, 5], boxes[:, 6], rng.uniform(1.0, 5.0, 50)]))
    n = 4000
    pts = np.column_stack(
        [rng.integers(0, 2, n), rng.integers(-1, 33, n), rng.integers(-1, 17, n), rng.choice(zs, n)]
    ).astype(float)
    np.testing.assert_array_equal(_inside(merged, pts), _inside(boxes, pts))


def test_split_halves_and_quarters_merge_back_whole() -> None:
    whole = [0, 0, 7, 0, 7, 1.0, 3.0]
    quarters = np.array(
        [[0, 0, 3, 0, 7, 1.0, 2.0], [0, 0, 3, 0, 7, 2.0, 3.0], [0, 4, 7, 0, 3, 1.0, 3.0], [0, 4, 7, 4, 7, 1.0, 3.0]]
    )
    np.testing.assert_array_equal(merge_adjacent(quarters), [whole])
    # another camera's, or a different depth range, is never merged in
    other = np.array([[0, 0, 3, 0, 7, 1.0, 3.0], [1, 4, 7, 0, 7, 1.0, 3.0], [0, 4, 7, 0, 7, 1.0, 2.5]])
    assert len(merge_adjacent(other)) == 3
    assert merge_adjacent(np.zeros((0, 7))).shape == (0, 7)
