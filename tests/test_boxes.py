"""Box queries (polyhull.engine.boxes) against brute force: box overlaps by sweep and prune,
and boxes against triangles (python-fcl's box-against-mesh collision as the oracle)."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import fcl
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from polyhull.engine.boxes import (
    ANY_PARALLEL_MIN,
    BRUTE_QUERIES,
    OverlapSweep,
    TriangleGrid,
    any_near_upright,
    any_overlap,
    group_bounds,
    groups_meet_triangles,
    overlap_groups,
)
from polyhull.errors import GeometryError


def _random_boxes(seed: int, n: int, spread: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0.0, spread, size=(n, 3))
    size = rng.exponential(0.15, size=(n, 3)) * rng.uniform(0.2, 3.0, size=(1, 3))  # anisotropic
    return lo, lo + size


def _meets(alo: np.ndarray, ahi: np.ndarray, blo: np.ndarray, bhi: np.ndarray) -> np.ndarray:
    return np.all((alo[:, None, :] <= bhi[None]) & (ahi[:, None, :] >= blo[None]), axis=2)


def _lattice_boxes(seed: int, n: int, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Boxes with corners on a coarse lattice: many exactly touching faces and equal
    coordinates (ties in every sort), some flat (zero extent along an axis)."""
    rng = np.random.default_rng(seed)
    lo = rng.integers(0, cells, size=(n, 3)).astype(np.float64) * 0.1
    return lo, lo + rng.integers(0, 3, size=(n, 3)) * 0.1


def _assert_same_groups(lo: np.ndarray, hi: np.ndarray) -> None:
    labels = overlap_groups(lo, hi)
    _, expected = connected_components(csr_matrix(_meets(lo, hi, lo, hi)), directed=False)
    # the same partition: labels map one-to-one
    pairs = set(zip(labels.tolist(), expected.tolist(), strict=True))
    assert len(pairs) == len(set(labels.tolist())) == len(set(expected.tolist()))
    # numbered 0..K-1 in the order of each group's first box
    _, first = np.unique(labels, return_index=True)
    assert np.array_equal(labels[np.sort(first)], np.arange(len(first)))


@settings(max_examples=40, deadline=None)  # the first example may compile
@given(seed=st.integers(0, 10_000), n=st.integers(1, 120), spread=st.floats(0.1, 3.0))
def test_groups_are_the_connected_components_of_overlap(seed: int, n: int, spread: float) -> None:
    _assert_same_groups(*_random_boxes(seed, n, spread))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 150), cells=st.integers(2, 12), flat=st.integers(-1, 2))
def test_touching_boxes_group_like_brute_force(seed: int, n: int, cells: int, flat: int) -> None:
    """Closed boxes: touching faces, edges and corners join groups, also on the sweep axis."""
    lo, hi = _lattice_boxes(seed, n, cells)
    if flat >= 0:  # all in one plane: the sweep axis is then another one
        lo[:, flat] = hi[:, flat] = 0.0
    _assert_same_groups(lo, hi)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000), n=st.integers(0, 150), parts=st.integers(1, 9), lattice=st.booleans(),
    inverted=st.integers(0, 5),
)
def test_a_sweep_in_parts_gives_the_groups_of_one_scan(seed: int, n: int, parts: int, lattice: bool, inverted: int) -> None:
    """The parts' forests, scanned in any order (as two threads do), join into the labels of
    one scan; the parts cover every entry (a box in every strip it meets) once, also with
    inverted boxes (lo > hi: in no strip when inverted along z)."""
    lo, hi = _lattice_boxes(seed, n, 6) if lattice else _random_boxes(seed, n, 1.0)
    k = min(inverted, n)
    lo[:k], hi[:k] = hi[:k] + 0.05, lo[:k].copy()
    sweep = OverlapSweep(lo, hi, parts)
    assert sweep.parts == parts and sweep.bounds[0] == 0 and sweep.bounds[-1] == sweep.entries >= n - k
    assert np.all(np.diff(sweep.bounds) >= 0)
    order = np.random.default_rng(seed).permutation(parts)
    forests = {int(p): sweep.scan(int(p)) for p in order}
    assert np.array_equal(sweep.labels([forests[p] for p in range(parts)]), overlap_groups(lo, hi))


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(50, 600), tall=st.integers(0, 20), infinite=st.booleans())
def test_a_body_over_a_sheet_groups_like_brute_force(seed: int, n: int, tall: int, infinite: bool) -> None:
    """Many small boxes in columns over a thin layer (a body standing in the floor's
    sheet: many strips), some boxes as tall as the whole body (in every strip), maybe one
    reaching to infinity along z (in the outer strips): the strips' groups are the
    connected components of overlap."""
    rng = np.random.default_rng(seed)
    lo = np.column_stack([rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.8, n)])
    hi = lo + rng.uniform(0.01, 0.08, size=(n, 3))
    sheet = rng.random(n) < 0.3
    lo[sheet, 2], hi[sheet, 2] = 0.0, 0.02
    k = min(tall, n)
    lo[:k, 2], hi[:k, 2] = 0.0, 1.9
    if infinite:
        hi[n - 1, 2] = np.inf
    _assert_same_groups(lo, hi)
    sweep = OverlapSweep(lo, hi, 3)
    assert sweep.entries > n  # tall boxes are in several strips
    assert np.array_equal(sweep.labels([sweep.scan(p) for p in range(3)]), overlap_groups(lo, hi))


def test_groups_of_no_box_and_of_one_box() -> None:
    assert overlap_groups(np.zeros((0, 3)), np.zeros((0, 3))).tolist() == []
    assert overlap_groups(np.zeros((1, 3)), np.ones((1, 3))).tolist() == [0]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 80), m=st.integers(0, 80))
def test_any_overlap_is_brute_force(seed: int, n: int, m: int) -> None:
    qlo, qhi = _random_boxes(seed, n, 2.0)
    blo, bhi = _random_boxes(seed + 1, m, 2.0)
    expected = _meets(qlo, qhi, blo, bhi).any(axis=1) if m else np.zeros(n, dtype=bool)
    assert np.array_equal(any_overlap(qlo, qhi, blo, bhi), expected)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(ANY_PARALLEL_MIN, ANY_PARALLEL_MIN + 300))
def test_any_overlap_on_two_threads_is_the_same(seed: int, n: int) -> None:
    """Many queries, split over two threads: the same answers, in the queries' order."""
    qlo, qhi = _random_boxes(seed, n, 2.0)
    blo, bhi = _random_boxes(seed + 1, 60, 2.0)
    with ThreadPoolExecutor(2) as pool:
        assert np.array_equal(any_overlap(qlo, qhi, blo, bhi, pool), _meets(qlo, qhi, blo, bhi).any(axis=1))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 200), m=st.integers(0, 120), reach=st.floats(0.0, 0.6))
def test_any_overlap_within_reach_is_brute_force(seed: int, n: int, m: int, reach: float) -> None:
    """With ``reach``: the Euclidean gap between the boxes is at most ``reach`` (a ball,
    not a cube: boxes diagonal to each other within the cube's reach do not count)."""
    qlo, qhi = _random_boxes(seed, n, 3.0)
    blo, bhi = _random_boxes(seed + 1, m, 3.0)
    gap = np.linalg.norm(np.maximum(np.maximum(blo[None] - qhi[:, None], qlo[:, None] - bhi[None]), 0.0), axis=2)
    expected = (gap <= reach).any(axis=1) if m else np.zeros(n, dtype=bool)
    # pairs within a rounding error of the limit may go either way
    doubt = (np.abs(gap - reach) < 1e-9).any(axis=1) if m else np.zeros(n, dtype=bool)
    got = any_overlap(qlo, qhi, blo, bhi, reach=reach)
    assert np.array_equal(got[~doubt], expected[~doubt])


def test_a_box_with_a_non_finite_coordinate_may_meet_any_query() -> None:
    """A query or a box with a NaN or infinite coordinate: nothing is known of it, so it is
    taken to meet (the rules then keep more)."""
    lo, hi = np.zeros((3, 3)), np.ones((3, 3))
    far = np.full((1, 3), 10.0)
    bad = lo.copy()
    bad[1, 2] = np.nan
    got = any_overlap(bad, hi, far, far + 1.0)
    assert got.tolist() == [False, True, False]
    nan_box = far.copy()
    nan_box[0, 0] = np.nan
    assert any_overlap(lo, hi, nan_box, far + 1.0).all()
    assert any_near_upright(lo, hi, np.concatenate([far, nan_box]), np.concatenate([far, far]) + 1.0, 0.3).all()


def test_the_box_the_last_query_met_counts_only_if_it_meets_the_next() -> None:
    """Consecutive queries that alternate between meeting one box and missing it only
    along z, or only by the ball's reach along a diagonal (the box the last hit found is
    tried first): each answer is the brute-force one."""
    blo, bhi = np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 1.0]])
    qlo = np.array([
        [0.2, 0.2, 0.5],  # inside
        [0.2, 0.2, 1.5],  # above by 0.4, same x, y
        [0.2, 0.2, 0.9],  # inside again
        [1.25, 1.25, 0.5],  # 0.25 m off along x and y: 0.354 m away, within the cube's 0.3
        [1.2, 0.2, 0.5],  # 0.2 m off along x
        [0.2, 0.2, -0.6],  # below by 0.5
    ])
    qhi = qlo + 0.1
    reach = 0.3
    gaps = np.maximum(np.maximum(blo[None] - qhi[:, None], qlo[:, None] - bhi[None]), 0.0)
    ball = (np.linalg.norm(gaps, axis=2) <= reach).any(axis=1)
    upright = ((np.linalg.norm(gaps[..., :2], axis=2) <= reach) & (gaps[..., 2] <= reach)).any(axis=1)
    assert ball.tolist() == [True, False, True, False, True, False]
    # the six queries alone (tested against every box) and repeated (binned, the last
    # hit tried first)
    for times in (1, 1 + BRUTE_QUERIES // len(qlo)):
        ql, qh = np.tile(qlo, (times, 1)), np.tile(qhi, (times, 1))
        assert any_overlap(ql, qh, blo, bhi, reach=reach).tolist() == ball.tolist() * times
        assert any_near_upright(ql, qh, blo, bhi, reach).tolist() == upright.tolist() * times
        assert any_overlap(ql, qh, blo, bhi).tolist() == [True, False, True, False, False, False] * times


def test_any_overlap_reach_is_a_ball() -> None:
    """Two unit boxes apart by 0.3 m along each axis: 0.52 m apart (not 0.3)."""
    lo, hi = np.zeros((1, 3)), np.ones((1, 3))
    assert not any_overlap(lo, hi, lo + 1.3, hi + 1.3, reach=0.5)[0]
    assert any_overlap(lo, hi, lo + 1.3, hi + 1.3, reach=0.53)[0]
    assert any_overlap(lo, hi, lo + np.array([1.3, 0.0, 0.0]), hi + np.array([1.3, 0.0, 0.0]), reach=0.31)[0]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 200), m=st.integers(0, 120), margin=st.floats(0.0, 0.6))
def test_any_near_upright_is_a_cylinder(seed: int, n: int, m: int, margin: float) -> None:
    """Within ``margin`` horizontally (the Euclidean gap in x, y) and along z (the gap in z):
    each box grown by an upright cylinder, brute force."""
    qlo, qhi = _random_boxes(seed, n, 3.0)
    blo, bhi = _random_boxes(seed + 1, m, 3.0)
    gaps = np.maximum(np.maximum(blo[None] - qhi[:, None], qlo[:, None] - bhi[None]), 0.0)
    horizontal = np.linalg.norm(gaps[..., :2], axis=2)
    expected = ((horizontal <= margin) & (gaps[..., 2] <= margin)).any(axis=1) if m else np.zeros(n, dtype=bool)
    doubt = ((np.abs(horizontal - margin) < 1e-9) | (np.abs(gaps[..., 2] - margin) < 1e-9)).any(axis=1) if m else np.zeros(n, dtype=bool)
    got = any_near_upright(qlo, qhi, blo, bhi, margin)
    assert np.array_equal(got[~doubt], expected[~doubt])
    # a foot 0.25 m from the leg diagonally is within 0.3 m; the square's corner is not
    lo, hi = np.zeros((1, 3)), np.full((1, 3), 0.1)
    diagonal = np.array([0.25, 0.25, 0.0]) / np.sqrt(2.0)
    assert any_near_upright(lo + 0.1 + diagonal, hi + 0.1 + diagonal, lo, hi, 0.3)[0]
    corner = np.array([0.29, 0.29, 0.0])
    assert not any_near_upright(lo + 0.1 + corner, hi + 0.1 + corner, lo, hi, 0.3)[0]
    assert any_near_upright(lo + np.array([0.0, 0.0, 0.39]), hi + np.array([0.0, 0.0, 0.39]), lo, hi, 0.3)[0]


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 300),
    m=st.integers(1, 3000),
    layout=st.sampled_from(["flat", "columns", "scattered"]),
    reach=st.floats(0.0, 0.3),
)
def test_any_near_upright_on_a_fine_grid_is_brute_force(seed: int, n: int, m: int, layout: str, reach: float) -> None:
    """Thousands of small boxes over 4 m: the grid's cubes are as small as the boxes until
    ``GRID_CELLS`` of them would not cover the queries' reach, then coarser. The boxes lie
    flat at one height (a sheet: one layer of cubes), stand in columns (a body over the
    floor's sheet, the case the cubes are for) or are scattered; the queries reach beyond
    them (the outer cells reach to infinity). Brute force, with the ball's and the
    cylinder's reach."""
    rng = np.random.default_rng(seed)
    blo = rng.uniform(0.0, 4.0, size=(m, 3))
    size = rng.uniform(0.005, 0.05, size=(m, 3))
    if layout == "flat":
        blo[:, 2] = 0.1
        size[:, 2] = 0.0
    elif layout == "columns":
        blo[:, :2] = np.round(blo[:, :2] * 2.0) / 2.0 + rng.uniform(0.0, 0.02, size=(m, 2))
    bhi = blo + size
    qlo = rng.uniform(-0.5, 4.5, size=(n, 3))
    qhi = qlo + rng.uniform(0.0, 0.08, size=(n, 3))
    gaps = np.maximum(np.maximum(blo[None] - qhi[:, None], qlo[:, None] - bhi[None]), 0.0)
    ball = np.linalg.norm(gaps, axis=2)
    horizontal = np.linalg.norm(gaps[..., :2], axis=2)
    doubt = (np.abs(ball - reach) < 1e-9).any(axis=1)
    assert np.array_equal(any_overlap(qlo, qhi, blo, bhi, reach=reach)[~doubt], (ball <= reach).any(axis=1)[~doubt])
    doubt = ((np.abs(horizontal - reach) < 1e-9) | (np.abs(gaps[..., 2] - reach) < 1e-9)).any(axis=1)
    expected = ((horizontal <= reach) & (gaps[..., 2] <= reach)).any(axis=1)
    assert np.array_equal(any_near_upright(qlo, qhi, blo, bhi, reach)[~doubt], expected[~doubt])


def _fcl_meets(vertices: np.ndarray, triangles: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) python-fcl: whether each solid box [lo, hi] collides with the triangles."""
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(triangles))
    model.addSubModel(vertices, triangles)
    model.endModel()
    mesh = fcl.CollisionObject(model, fcl.Transform())
    out = np.zeros(len(lo), dtype=bool)
    for i in range(len(lo)):
        box = fcl.CollisionObject(fcl.Box(*(hi[i] - lo[i])), fcl.Transform(0.5 * (lo[i] + hi[i])))
        out[i] = fcl.collide(box, mesh, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), degenerate=st.booleans())
def test_boxes_meet_triangles_as_fcl(seed: int, degenerate: bool) -> None:
    """Random triangles (some long, crossing many cells; some collinear) against random
    boxes: the same answer as python-fcl, except within a 1e-6 band where either may be
    said (a box touching the surface, which the caller grows for)."""
    rng = np.random.default_rng(seed)
    n_tri = 30
    centres = rng.uniform(0.0, 2.0, size=(n_tri, 1, 3))
    scale = rng.choice([0.02, 0.2, 1.5], size=(n_tri, 1, 1))
    corners = centres + rng.normal(0.0, 1.0, size=(n_tri, 3, 3)) * scale
    if degenerate:  # a third of them collinear: the third corner between the other two
        corners[::3, 2] = 0.3 * corners[::3, 0] + 0.7 * corners[::3, 1]
    vertices = corners.reshape(-1, 3)
    triangles = np.arange(3 * n_tri).reshape(-1, 3)
    grid = TriangleGrid.of(vertices, triangles, pitch=0.1)
    lo = rng.uniform(-0.5, 2.5, size=(200, 3))
    hi = lo + rng.exponential(0.15, size=(200, 3))
    got = groups_meet_triangles(grid, lo, hi, np.arange(200), 200)
    fcl_yes = _fcl_meets(vertices, triangles, lo, hi)
    fcl_near = _fcl_meets(vertices, triangles, lo - 1e-6, hi + 1e-6)
    assert not np.any(fcl_yes & ~fcl_near)
    sure = fcl_yes | ~fcl_near
    assert np.array_equal(got[sure], fcl_yes[sure])
    assert 0 < fcl_yes.sum() < len(lo)  # both answers were tested


def test_boxes_meet_triangles_touching_and_holding() -> None:
    """A box that only touches a triangle (at a vertex, along an edge, on a face) meets it,
    and so does a box that holds it whole; a box a hair away does not."""
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    grid = TriangleGrid.of(v, np.array([[0, 1, 2]]))
    lo = np.array(
        [
            [1.0, -0.5, -0.5],  # the vertex (1, 0, 0) on its face
            [0.5, 0.5, -0.5],  # the hypotenuse edge through its corner (0.5, 0.5)
            [0.1, 0.1, 0.0],  # the face, from above
            [-1.0, -1.0, -1.0],  # the whole triangle inside
            [1.0 + 1e-7, -0.5, -0.5],  # beyond the vertex
            [0.2, 0.2, 1e-7],  # above the face
        ]
    )
    hi = lo + np.array([[1.0, 1.0, 1.0]] * 3 + [[3.0, 3.0, 3.0]] + [[1.0, 1.0, 1.0]] * 2)
    got = groups_meet_triangles(grid, lo, hi, np.arange(6), 6)
    assert got.tolist() == [True, True, True, True, False, False]
    # python-fcl finds the same, except the touch along the edge (rounding puts it apart)
    assert _fcl_meets(v, np.array([[0, 1, 2]]), lo, hi).tolist() == [True, False, True, True, False, False]
    # groups: a group meets when one of its boxes does
    assert groups_meet_triangles(grid, lo, hi, np.array([0, 1, 1, 1, 2, 2]), 3).tolist() == [True, True, False]


def test_triangle_grid_rejects_bad_meshes() -> None:
    with pytest.raises(GeometryError, match="triangle grid"):
        TriangleGrid.of(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(GeometryError, match="non-finite"):
        TriangleGrid.of(np.array([[0.0, 0.0, np.nan], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([[0, 1, 2]]))
    with pytest.raises(GeometryError, match="vertex indices"):
        TriangleGrid.of(np.eye(3), np.array([[0, 1, 3]]))


def test_a_box_with_a_non_finite_coordinate_may_meet() -> None:
    """Nothing is known of such a box: it is taken to meet (the rules then keep its piece)."""
    grid = TriangleGrid.of(np.eye(3), np.array([[0, 1, 2]]))
    lo = np.array([[5.0, 5.0, np.nan], [5.0, 5.0, 5.0], [-np.inf, 5.0, 5.0]])
    hi = np.array([[6.0, 6.0, 6.0], [6.0, 6.0, np.inf], [6.0, 6.0, 6.0]])
    assert groups_meet_triangles(grid, lo, hi, np.arange(3), 3).tolist() == [True, True, True]


def test_bad_shapes_and_groups_are_refused() -> None:
    """The compiled loops do not check their bounds: the wrappers do, with a clear error."""
    with pytest.raises(GeometryError, match=r"overlap_groups: expected lo and hi of shape \(N, 3\)"):
        overlap_groups(np.zeros((4, 3)), np.ones((3, 3)))
    grid = TriangleGrid.of(np.eye(3), np.array([[0, 1, 2]]))
    lo, hi = np.zeros((2, 3)), np.ones((2, 3))
    with pytest.raises(GeometryError, match=r"groups must lie in 0\.\.1"):
        groups_meet_triangles(grid, lo, hi, np.array([0, 2]), 2)
    with pytest.raises(GeometryError, match="expected lo, hi"):
        groups_meet_triangles(grid, lo, hi, np.array([0]), 2)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 60), st.integers(0, 16))
def test_near_balls_equals_numpy(seed: int, n: int, b: int) -> None:
    """The dynamic rules' "near the robot" test (a box's ball within eps of a robot ball),
    compiled, against the same formula in numpy."""
    from polyhull.engine.dynamic_rules import _near_balls

    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1, 1, (n, 3))
    hi = lo + rng.uniform(0, 0.5, (n, 3))
    balls = np.column_stack([rng.uniform(-1, 1, (b, 3)), rng.uniform(0, 0.3, b)])
    c, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=1)
    gap = np.linalg.norm(c[:, None, :] - balls[None, :, :3], axis=2) - balls[None, :, 3] - r[:, None]
    want = (gap <= 0.05).any(axis=1) if b else np.zeros(n, dtype=bool)
    np.testing.assert_array_equal(_near_balls(lo, hi, balls, 0.05), want)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 60), K=st.integers(1, 8))
def test_group_bounds_equal_ufunc_at(seed: int, n: int, K: int) -> None:
    """Each group's bounds are the min / max of its boxes' (as numpy's ufunc.at gives);
    an empty group keeps +inf / -inf."""
    rng = np.random.default_rng(seed)
    lo = rng.normal(size=(n, 3))
    hi = lo + rng.uniform(0, 1, size=(n, 3))
    labels = rng.integers(0, K, size=n)
    clo, chi = group_bounds(labels, lo, hi, K)
    elo, ehi = np.full((K, 3), np.inf), np.full((K, 3), -np.inf)
    np.minimum.at(elo, labels, lo)
    np.maximum.at(ehi, labels, hi)
    np.testing.assert_array_equal(clo, elo)
    np.testing.assert_array_equal(chi, ehi)
