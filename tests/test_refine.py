"""Refinement at the distance frontier (polyhull.engine.refine), with stand-in rules."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.cell import Cell
from polyhull.distance import DistanceResult
from polyhull.engine.dynamic_rules import box_vertices
from polyhull.engine.pieces import PieceSet
from polyhull.engine.refine import (
    BAND,
    FINE,
    MEMORY,
    MEMORY_FINE,
    OWN,
    SETTLED,
    RegionRules,
    _same_rows,
    distance_lower_bounds,
    refine_kept,
)
from polyhull.monitor import Monitor


def _boxes(rows: list[tuple[float, ...]]) -> PieceSet:
    """Axis-aligned test pieces: each row is (id, x0, y0, z0, x1, y1, z1); the id stands in
    for the camera-space box (column 0), the rest for the geometry."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 7)
    return PieceSet(a.copy(), box_vertices(a[:, 1:4], a[:, 4:7]))


@settings(max_examples=60)
@given(
    centre=st.tuples(*[st.floats(-2, 2)] * 3),
    size=st.tuples(*[st.floats(0.01, 1.0)] * 3),
    sphere=st.tuples(*[st.floats(-2, 2)] * 3, st.floats(0.0, 0.5)),
    seed=st.integers(0, 1000),
)
def test_lower_bound_never_exceeds_a_point_distance(centre, size, sphere, seed) -> None:
    lo = np.array(centre)
    v = box_vertices(lo[None], (lo + np.array(size))[None])
    s = np.array([sphere])
    bound = distance_lower_bounds(v, s)[0]
    w = np.random.default_rng(seed).dirichlet(np.ones(8), size=200)  # points of the hull
    pts = np.concatenate([w @ v[0], v[0]])
    true = np.maximum(np.linalg.norm(pts - s[0, :3], axis=1) - s[0, 3], 0.0).min()
    assert bound <= true + 1e-12


def test_same_rows() -> None:
    a = np.array([[0, 1, 2, 3, 4, 5.0, 6.0], [1, 1, 2, 3, 4, 5.0, 6.5]])
    b = np.array([[9, 9, 9, 9, 9, 9.0, 9.0], [0, 1, 2, 3, 4, 5.0, 6.0]])
    assert _same_rows(a, b).tolist() == [True, False]
    assert _same_rows(a, b[:0]).tolist() == [False, False]


def _rules(margin: float) -> RegionRules:
    top = 0.3  # a floor sheet 0.3 m thick

    def sheets(v: np.ndarray) -> np.ndarray:
        if len(v) == 0:
            return np.zeros((0, 8, 3))
        lo, hi = v.min(axis=1), v.max(axis=1)
        return box_vertices(np.column_stack([lo[:, :2] - margin, np.zeros(len(v))]), np.column_stack([hi[:, :2] + margin, np.full(len(v), top)]))

    return RegionRules(
        in_shells=lambda v: v[:, :, 2].max(axis=1) <= top,
        crossing=lambda v: (v[:, :, 2].min(axis=1) < top) & (v[:, :, 2].max(axis=1) >= top),
        sheets=sheets,
        margin=margin,
        too_thin=True,
    )


def _measure(robot_x: float):  # noqa: ANN202
    """Distance from the region's hexahedra to the plane x = robot_x (a robot far in +x)."""
    calls: list[int] = []

    def measure(vertices: np.ndarray, best: DistanceResult | None) -> DistanceResult:
        calls.append(len(vertices))
        d = math.inf if len(vertices) == 0 else float(robot_x - vertices[:, :, 0].max())
        if best is not None and best.distance < d:
            return best
        return DistanceResult(d, None, "link" if math.isfinite(d) else None)

    return measure, calls


def _passes(calls: list[int]) -> int:
    """The measurements of the region among ``measure``'s calls (a call without vertices
    seeks the parts refinement never changes: here the static region, which the stand-in
    has none of)."""
    return sum(1 for n in calls if n)


def test_a_false_crossing_loses_its_sheet_and_the_feet_it_kept() -> None:
    # A: a coarse piece whose top seems to cross the sheet's top; carved again, only its
    # part inside the sheet stays. B: a piece inside the sheet, kept only within the
    # margin of A. C: far from the robot, untouched.
    kept = _boxes(
        [
            (1, 1.0, 0.0, 0.20, 1.1, 0.1, 0.35),  # A
            (2, 1.2, 0.0, 0.00, 1.3, 0.1, 0.20),  # B
            (3, -3.0, 0.0, 0.0, -2.9, 0.1, 1.8),  # C: a person standing far away
        ]
    )
    children = {1: [(4, 1.0, 0.0, 0.20, 1.1, 0.1, 0.28)]}
    seen: list[float] = []

    def recarve(boxes: np.ndarray, memory: bool, offset: float, alpha: float, size_min: float) -> PieceSet:
        seen.extend(boxes[:, 0].tolist())
        rows = [r for b in boxes for r in children.get(int(b[0]), [tuple(b)])]
        return _boxes(rows)

    measure, calls = _measure(robot_x=1.6)
    spheres = np.array([[1.8, 0.05, 0.2, 0.2]])
    flags = np.array([OWN, OWN, OWN], dtype=np.int8)
    inside = _rules(0.3).in_shells(kept.vertices)
    out = refine_kept(kept, flags, inside, _rules(0.3), spheres, 0.25, recarve, measure)

    # A (which seems to cross the sheet) and B (inside it, near the frontier) are carved
    # again; C, beyond the reach of the frontier, is not
    assert sorted(seen) == [1.0, 2.0]
    assert out.rounds == 1
    ids = sorted(out.pieces.boxes[:, 0].tolist())
    assert ids == [3.0]  # A's child and B are inside the sheet with nothing standing near
    assert sorted(out.cut.boxes[:, 0].tolist()) == [2.0, 4.0]
    # the sheet under C only: nothing near the robot any more
    assert out.sheets.shape[0] == 1 and out.sheets[0, :, 0].max() < 0.0
    region = np.concatenate([out.pieces.vertices, out.sheets])
    assert out.distance.distance == measure(region, None).distance
    assert out.distance.distance > 1.6 - 1.3  # farther than B was


def test_a_memory_piece_is_carved_down_to_fine_in_one_round() -> None:
    # M: a coarse piece of the shadow memory (0.4 m) that seems to cross the sheet's top;
    # only carved down to FINE does it show that nothing of it stands out of the sheet
    # (a quarter of its size, 0.1 m, still seems to). B: a piece inside the sheet, kept
    # only within the margin of M. O: an own piece of M's size that crosses the sheet.
    kept = _boxes(
        [
            (1, 1.0, 0.0, 0.0, 1.4, 0.4, 0.35),  # M
            (2, 1.45, 0.0, 0.0, 1.5, 0.1, 0.20),  # B
            (3, 0.25, 0.0, 0.0, 0.65, 0.4, 0.35),  # O: behind M, within the frontier's reach
        ]
    )
    minima: dict[int, float] = {}

    def recarve(boxes: np.ndarray, flags: int, offset: float, alpha: float, size_min: float) -> PieceSet:
        rows = []
        for b in boxes:
            minima[int(b[0])] = size_min
            if int(b[0]) == 1 and size_min <= FINE:
                rows.append((4, 1.0, 0.0, 0.0, 1.4, 0.4, 0.28))  # all inside the sheet
            else:
                rows.append(tuple(b))
        return _boxes(rows)

    measure, _ = _measure(robot_x=1.8)
    flags = np.array([MEMORY, OWN, OWN], dtype=np.int8)
    rules = _rules(0.3)
    out = refine_kept(kept, flags, rules.in_shells(kept.vertices), rules, np.array([[2.0, 0.05, 0.2, 0.2]]), 0.25, recarve, measure)
    assert out.rounds == 1
    assert minima[1] == FINE  # the memory's piece: FINE at once
    assert math.isclose(minima[3], 0.25 * 0.4)  # an own piece: a quarter of its size
    # M's child is inside the sheet and B was kept only by M: both go in this round
    assert sorted(out.cut.boxes[:, 0].tolist()) == [2.0, 4.0]
    assert math.isclose(out.distance.distance, 1.8 - (0.65 + 0.3))  # O's sheet, with the margin


def test_only_the_nearest_memory_pieces_go_to_fine_at_once() -> None:
    # MEMORY_FINE + 6 memory pieces crossing the sheet's top at the frontier, each a little
    # farther from the robot than the last (a colour camera's memory holds thousands at the
    # robot): the nearest MEMORY_FINE are carved down to FINE, the others to a quarter
    n = MEMORY_FINE + 6
    rows = [(i, 1.0 - 0.002 * i, 0.0, 0.0, 1.1 - 0.002 * i, 0.1, 0.35) for i in range(n)]
    kept = _boxes(rows)
    minima: dict[int, float] = {}

    def recarve(boxes: np.ndarray, flags: int, offset: float, alpha: float, size_min: float) -> PieceSet:
        for b in boxes:
            minima[int(b[0])] = size_min
        return _boxes([tuple(b) for b in boxes])

    measure, _ = _measure(robot_x=1.5)
    rules = _rules(0.3)
    flags = np.full(n, MEMORY, dtype=np.int8)
    refine_kept(kept, flags, rules.in_shells(kept.vertices), rules, np.array([[1.7, 0.05, 0.2, 0.2]]), 0.25, recarve, measure)
    assert sorted(minima) == list(range(n))  # every piece was carved again
    assert [minima[i] for i in range(MEMORY_FINE)] == [FINE] * MEMORY_FINE
    assert all(math.isclose(minima[i], 0.25 * 0.35) for i in range(MEMORY_FINE, n))


def test_unchanged_pieces_settle_and_a_real_crossing_keeps_its_sheet() -> None:
    kept = _boxes([(1, 1.0, 0.0, 0.0, 1.1, 0.1, 1.7)])  # a leg: no camera frees any of it

    def recarve(boxes: np.ndarray, memory: bool, offset: float, alpha: float, size_min: float) -> PieceSet:
        return _boxes([tuple(b) for b in boxes])

    measure, _ = _measure(robot_x=1.6)
    out = refine_kept(
        kept, np.array([OWN], np.int8), np.array([False]), _rules(0.3), np.array([[1.8, 0.05, 0.5, 0.2]]), 0.25, recarve, measure
    )
    assert out.rounds == 1
    assert len(out.pieces) == 1 and len(out.cut) == 0
    assert len(out.sheets) == 1  # the leg keeps the sheet under it, with the margin
    assert math.isclose(out.distance.distance, 1.6 - 1.4)


def test_settled_flag_value() -> None:
    assert SETTLED & OWN == 0


def test_same_rows_against_a_set() -> None:
    """Which rows of one box array are rows of another: the compiled search against a set
    of tuples (ties, -0.0, repeated rows, empty arrays)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.engine.refine import _same_rows

    @settings(max_examples=60, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.integers(0, 40), st.integers(0, 40))
    def check(seed: int, n: int, m: int) -> None:
        rng = np.random.default_rng(seed)
        b = rng.integers(0, 3, size=(m, 7)).astype(float)
        a = rng.integers(0, 3, size=(n, 7)).astype(float)
        if m and n:
            a[: n // 2] = b[rng.integers(0, m, n // 2)]  # some shared rows
            a[a == 0.0] = -0.0
        rows = {tuple(r) for r in b}
        np.testing.assert_array_equal(_same_rows(a, b), np.array([tuple(r) in rows for r in a], dtype=bool).reshape(-1))

    check()


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 300), st.integers(1, 7))
def test_lexicographic_order_is_numpys(seed: int, n: int, k: int) -> None:
    """The compiled merge sort of ``_same_rows`` orders rows as ``np.lexsort`` of the
    columns (the first column the primary key), ties kept in their order: on rows with
    many ties, of any count (not only powers of two)."""
    from polyhull.engine.refine import _lex_order

    b = np.random.default_rng(seed).integers(0, 3, size=(n, k)).astype(float)
    np.testing.assert_array_equal(_lex_order(b), np.lexsort(b.T[::-1]))


@pytest.mark.parametrize("hint", [0.3, 0.1, 5.0])
def test_a_hinted_frontier_skips_the_first_measurement_and_changes_nothing_else(hint: float) -> None:
    """With the last cycle's frontier as a hint, the unrefined region is not measured
    first (one python-fcl pass less a cycle), unless a piece may lie more than ``BAND``
    nearer than the hint (the region came closer than expected): then it is, as without
    a hint. Either way the same pieces are carved, cut and kept, and the distance is the
    returned region's."""
    kept = _boxes(
        [
            (1, 1.0, 0.0, 0.20, 1.1, 0.1, 0.35),
            (2, 1.2, 0.0, 0.00, 1.3, 0.1, 0.20),
            (3, -3.0, 0.0, 0.0, -2.9, 0.1, 1.8),
        ]
    )
    children = {1: [(4, 1.0, 0.0, 0.20, 1.1, 0.1, 0.28)]}

    def recarve(boxes: np.ndarray, memory: bool, offset: float, alpha: float, size_min: float) -> PieceSet:
        return _boxes([r for b in boxes for r in children.get(int(b[0]), [tuple(b)])])

    spheres = np.array([[1.8, 0.05, 0.2, 0.2]])
    flags = np.array([OWN, OWN, OWN], dtype=np.int8)
    inside = _rules(0.3).in_shells(kept.vertices)
    runs = []
    for front_hint in (None, hint):
        measure, calls = _measure(robot_x=1.6)
        out = refine_kept(kept, flags, inside, _rules(0.3), spheres, 0.25, recarve, measure, front_hint=front_hint)
        region = np.concatenate([out.pieces.vertices, out.sheets])
        assert out.distance.distance == measure(region, None).distance
        runs.append((sorted(out.pieces.boxes[:, 0].tolist()), sorted(out.cut.boxes[:, 0].tolist()), out.distance.distance, _passes(calls) - 1))
    (ids, cut, d, n), (h_ids, h_cut, h_d, h_n) = runs
    assert (h_ids, h_cut, h_d) == (ids, cut, d)
    hinted = float(distance_lower_bounds(kept.vertices, spheres).min()) >= hint - BAND
    assert hinted == (hint < 1.0)
    assert h_n == (n - 1 if hinted else n)


def test_the_hint_counts_only_the_links_the_distance_is_measured_to() -> None:
    """A ball of a link fixed to the world (the robot's base, which the distance is not
    measured to) near a piece does not refuse the hint: with ``hint_spheres`` (the measured
    links' balls) the first measurement is skipped, and the pieces carved, cut and kept
    and the distance are those of the run without a hint."""
    kept = _boxes(
        [
            (1, 1.0, 0.0, 0.20, 1.1, 0.1, 0.35),
            (2, 1.2, 0.0, 0.00, 1.3, 0.1, 0.20),
            (3, -3.0, 0.0, 0.0, -2.9, 0.1, 1.8),
        ]
    )

    def recarve(boxes: np.ndarray, memory: bool, offset: float, alpha: float, size_min: float) -> PieceSet:
        return _boxes([tuple(b) for b in boxes])

    link = np.array([[1.8, 0.05, 0.2, 0.2]])
    base = np.array([[-2.95, 0.05, 0.5, 0.3]])  # over piece 3: its lower bound is 0
    spheres = np.concatenate([link, base])
    flags = np.array([OWN, OWN, OWN], dtype=np.int8)
    inside = _rules(0.3).in_shells(kept.vertices)
    hint = 0.5
    assert float(distance_lower_bounds(kept.vertices, spheres).min()) < hint - BAND  # refused by the base
    assert float(distance_lower_bounds(kept.vertices, link).min()) >= hint - BAND
    runs = []
    for kwargs in ({}, {"front_hint": hint}, {"front_hint": hint, "hint_spheres": link}):
        measure, calls = _measure(robot_x=1.6)
        out = refine_kept(kept, flags, inside, _rules(0.3), spheres, 0.25, recarve, measure, **kwargs)
        runs.append((sorted(out.pieces.boxes[:, 0].tolist()), sorted(out.cut.boxes[:, 0].tolist()), out.distance.distance, _passes(calls)))
    (ids, cut, d, n), (r_ids, r_cut, r_d, r_n), (h_ids, h_cut, h_d, h_n) = runs
    assert (r_ids, r_cut, r_d, r_n) == (ids, cut, d, n)  # the base's ball refuses the hint
    assert (h_ids, h_cut, h_d) == (ids, cut, d)
    assert h_n == n - 1


def _measure_with(robot_x: float, static: float, extra: np.ndarray | None = None):  # noqa: ANN202
    """:func:`_measure` of a region that also holds a static part ``static`` [m] from the
    robot (added to every result, as the monitor's ``measure`` adds the static region's),
    and ``extra()`` boxes."""
    inner, calls = _measure(robot_x)

    def measure(vertices: np.ndarray, best: DistanceResult | None) -> DistanceResult:
        res = inner(vertices, best)
        return DistanceResult(static, None, "static") if static < res.distance else res

    return measure, calls, (lambda: np.zeros((0, 8, 3)) if extra is None else extra)


def _scene() -> tuple[PieceSet, np.ndarray, np.ndarray]:
    """The scene of the false crossing: unrefined, A's sheet (the margin around it) is 0.2 m
    from the robot (the plane x = 1.6), B 0.3 m; refined, only C stays, 4.5 m from it, with
    its sheet 0.3 m nearer."""
    kept = _boxes(
        [
            (1, 1.0, 0.0, 0.20, 1.1, 0.1, 0.35),  # A: seems to cross the sheet's top
            (2, 1.2, 0.0, 0.00, 1.3, 0.1, 0.20),  # B: inside the sheet, kept only by A
            (3, -3.0, 0.0, 0.0, -2.9, 0.1, 1.8),  # C: a person standing far away
        ]
    )
    return kept, np.array([OWN, OWN, OWN], dtype=np.int8), _rules(0.3).in_shells(kept.vertices)


def _recarve(seen: list[float]):  # noqa: ANN202
    children = {1: [(4, 1.0, 0.0, 0.20, 1.1, 0.1, 0.28)]}  # A's part inside the sheet

    def recarve(boxes: np.ndarray, flags: int, offset: float, alpha: float, size_min: float) -> PieceSet:
        seen.extend(boxes[:, 0].tolist())
        return _boxes([r for b in boxes for r in children.get(int(b[0]), [tuple(b)])])

    return recarve


@pytest.mark.parametrize("static", [0.1, 0.25, 1.0, math.inf])
@pytest.mark.parametrize("hint", [None, 0.0, 1.0])
def test_refinement_is_left_out_only_when_it_cannot_change_the_distance(static: float, hint: float | None) -> None:
    """The static region (a part of the region that refinement never changes) nearer than
    every piece, or as near as the nearest: refinement is left out (no piece carved, the
    pieces returned as they are) and the distance is the static region's, which is also
    the refined region's. Farther than a piece that refinement removes: the pieces are
    refined as without a static region, and the distance is the nearer of the static
    region and the refined pieces."""
    kept, flags, inside = _scene()
    spheres = np.array([[1.8, 0.05, 0.2, 0.2]])
    seen: list[float] = []
    measure, _, extra = _measure_with(1.6, static)
    out = refine_kept(kept, flags, inside, _rules(0.3), spheres, 0.25, _recarve(seen), measure, front_hint=hint, extra=extra)
    # the same scene refined in full, without the static region
    plain, _ = _measure(1.6)
    full = refine_kept(kept, flags, inside, _rules(0.3), spheres, 0.25, _recarve([]), plain)
    assert full.rounds == 1 and full.distance.distance > 1.0  # refinement removes A and B
    assert out.distance.distance == min(static, full.distance.distance)
    if static < 1.6 - 1.4:  # nearer than A's sheet, the nearest part of the pieces
        assert (out.rounds, seen) == (0, [])
        assert sorted(out.pieces.boxes[:, 0].tolist()) == [1.0, 2.0, 3.0] and len(out.cut) == 0
        assert out.distance.link == "static"
    else:
        assert out.rounds == 1 and sorted(seen) == [1.0, 2.0]
        assert sorted(out.pieces.boxes[:, 0].tolist()) == [3.0]


def test_the_sheet_under_hidden_legs_decides_and_refinement_is_left_out() -> None:
    """``extra()`` boxes (the sheet under legs the robot may hide) nearer than every piece:
    refinement is left out, the distance is theirs and they are returned with the sheets."""
    kept, flags, inside = _scene()
    legs = box_vertices(np.array([[1.35, 0.0, 0.0]]), np.array([[1.45, 0.1, 0.1]]))  # 0.15 m from the robot
    seen: list[float] = []
    measure, _, extra = _measure_with(1.6, math.inf, legs)
    out = refine_kept(kept, flags, inside, _rules(0.3), np.array([[1.8, 0.05, 0.2, 0.2]]), 0.25, _recarve(seen), measure, extra=extra)
    assert (out.rounds, seen) == (0, [])
    assert math.isclose(out.distance.distance, 1.6 - 1.45)
    assert any(np.array_equal(s, legs[0]) for s in out.sheets)


def test_the_monitor_reports_the_refined_distance_when_refinement_is_left_out(small_cell: Cell, fresh_monitor: Monitor) -> None:
    """Over the small cell's recorded walk (its static region comes within centimetres of
    the arm, and the person walks up to it), the distances are those of a monitor that
    always refines, in every cycle, and refinement is left out in some cycles and not in
    others."""
    from polyhull.frames import load_frames

    files = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "frames").glob("small_walk_*.npz"))
    loaded = [load_frames(f) for f in files]
    runs = []
    try:
        for always in (False, True):
            fresh_monitor._always_refine = always  # (the warm-up's mode: always refined)
            fresh_monitor.reset()
            runs.append([fresh_monitor.step(f.frames, f.q, stamp=f.stamp) for f in loaded])
    finally:
        fresh_monitor._always_refine = False
    left_out = [v.counts["refine_rounds"] == 0 and v.counts["kept_pieces"] > 0 for v in runs[0]]
    assert any(left_out) and not all(left_out)
    assert all(v.counts["refine_rounds"] == 1 for v, out in zip(runs[1], left_out, strict=True) if out)
    assert [v.min_distance for v in runs[0]] == [v.min_distance for v in runs[1]]
    assert [v.closest_link for v in runs[0]] == [v.closest_link for v in runs[1]]
