"""The sheet boxes under pieces that stand on a surface (dynamic_rules.sheets_under)
against the rule written plainly with numpy, and against point sampling."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.cellfile import load_cell
from polyhull.distance import points_in_hexahedra
from polyhull.engine.dynamic_rules import (
    SHEET_ROWS,
    DynamicContext,
    _crossing_pairs,
    box_vertices,
    hidden_legs,
    sheets_under,
)
from polyhull.engine.static_model import SHEET_PITCH, Sheet, _to_world

SHEETS = (
    Sheet("floor", axis=2, sign=1, level=0.0, lo=(-2.0, -2.0), hi=(2.0, 2.0), height=0.2),
    Sheet("table +z", axis=2, sign=1, level=0.7, lo=(0.5, 0.5), hi=(1.3, 1.1), height=0.1),
    Sheet("table +x", axis=0, sign=1, level=1.3, lo=(0.5, 0.0), hi=(1.1, 0.7), height=0.1),
)


def _context(heights: tuple[np.ndarray, ...], sheets: tuple[Sheet, ...] = SHEETS) -> DynamicContext:
    cell = load_cell("fixtures/cells/small_cell.toml")
    return DynamicContext.of(cell, sheets, None, heights[: len(sheets)])  # type: ignore[arg-type]  # no touch grid needed


def _local_boxes(boxes: np.ndarray, sheet: Sheet) -> np.ndarray:
    """(B, 6) the boxes' bounds in the sheet's local frame (x, y on the face, z up from it)."""
    L = np.linalg.inv(_to_world(sheet.to_local())[:, :3])
    W = _to_world(sheet.to_local())
    local = (boxes - W[:, 3]) @ L.T
    return np.concatenate([local.min(axis=1), local.max(axis=1)], axis=1)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 40))
def test_sheet_boxes_hold_every_footprints_disc_and_no_more(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    # height maps smaller than some sheets' grids (the sheet's height beyond them)
    heights = tuple(rng.uniform(0.02, sh.height, size=(rng.integers(1, 30), rng.integers(1, 30))) for sh in SHEETS)
    ctx = _context(heights)
    # boxes standing on the floor or the table (crossing their sheets' tops), some apart
    lo = np.column_stack([rng.uniform(-2.2, 1.8, n), rng.uniform(-2.2, 1.8, n), rng.uniform(-0.1, 0.9, n)])
    hi = lo + rng.uniform(0.02, 0.6, size=(n, 3))
    vertices = box_vertices(lo, hi)
    got = sheets_under(vertices, ctx)
    margin = ctx.params.floor_shell_margin
    # no box reaches farther than the margin and a row's width from the footprints of its
    # sheet, nor above the highest height-map cell under it (the sheet's height beyond it):
    # the horizontal sheets alone (a vertical face's boxes keep the floor's under them too)
    flat = _context(heights, SHEETS[:2])
    pairs, bounds = _crossing_pairs(vertices, flat)
    for k, sh in enumerate(SHEETS[:2]):
        (x0, y0), (x1, y1) = sh.local_box()
        mine = pairs[:, 1] == k
        local = _local_boxes(sheets_under(vertices, flat), sh)
        on = (
            (np.abs(local[:, 2]) < 1e-9)
            & (local[:, 0] >= x0 - 1e-9) & (local[:, 3] <= x1 + 1e-9)
            & (local[:, 1] >= y0 - 1e-9) & (local[:, 4] <= y1 + 1e-9)
            & (local[:, 5] <= sh.height + 1e-9)
        )
        if not mine.any():
            continue
        b = bounds[mine]
        f0, f1 = b[:, :2], b[:, 3:5]
        for box in local[on]:
            corners = np.array([[box[0], box[1]], [box[3], box[1]], [box[0], box[4]], [box[3], box[4]]])
            gap = np.hypot(*np.maximum(np.maximum(f0[None] - corners[:, None], corners[:, None] - f1[None]), 0.0).transpose(2, 0, 1))
            # the box is convex: its farthest point from the nearest footprint is a corner
            # within the margin and a row's width of some footprint (the disc, rounded by rows)
            near = gap.min(axis=1)
            assert near.max() <= margin + SHEET_PITCH / SHEET_ROWS + 1e-9, (box, near)
            hmap = heights[k]
            i = np.arange(int(np.floor((box[0] - x0) / SHEET_PITCH + 1e-9)), int(np.ceil((box[3] - x0) / SHEET_PITCH - 1e-9)))
            j = int(np.floor((box[1] - y0) / SHEET_PITCH + 1e-9))
            cells = [hmap[ii, j] if ii < hmap.shape[0] and j < hmap.shape[1] else sh.height for ii in i]
            assert box[5] <= max(cells) + 1e-9
    # every point within the margin of a crossing piece's footprint (a disc around it),
    # under the height map, is covered
    pairs, bounds = _crossing_pairs(vertices, ctx)
    margin = ctx.params.floor_shell_margin
    for (_, k), b in zip(pairs, bounds, strict=True):
        sh = SHEETS[k]
        (x0, y0), (x1, y1) = sh.local_box()
        a = np.maximum(b[:2] - margin, (x0, y0))
        c = np.minimum(b[3:5] + margin, (x1, y1))
        if not np.all(c > a):
            continue
        p = rng.uniform(a, c, size=(40, 2))
        gap = np.hypot(*np.maximum(np.maximum(b[:2] - p, p - b[3:5]), 0.0).T)
        p = p[gap <= margin]
        i = np.floor((p - (x0, y0)) / SHEET_PITCH).astype(int)
        hmap = heights[k]
        inside_map = (i[:, 0] < hmap.shape[0]) & (i[:, 1] < hmap.shape[1])
        h = np.where(inside_map, hmap[np.minimum(i[:, 0], hmap.shape[0] - 1), np.minimum(i[:, 1], hmap.shape[1] - 1)], sh.height)
        local = np.column_stack([p, rng.uniform(0.0, 1.0, len(p)) * h * (1 - 1e-9)])
        W = _to_world(sh.to_local())
        world = local @ W[:, :3].T + W[:, 3]
        assert points_in_hexahedra(world, got).all()
    # a lone post on the floor keeps a disc of the floor's sheet, not a square: the
    # sheet's corners diagonal from it, beyond the margin and a row's width, are free
    post = box_vertices(np.array([[0.0, 0.0, 0.0]]), np.array([[0.05, 0.05, 1.0]]))
    boxes = sheets_under(post, ctx)
    r = margin + SHEET_PITCH / SHEET_ROWS + 1e-6
    d = r / np.sqrt(2.0)
    corners = np.array([[0.05 + d, 0.05 + d, 0.01], [-d, -d, 0.01], [0.05 + d, -d, 0.01], [-d, 0.05 + d, 0.01]])
    sides = np.array([[0.05 + 0.99 * margin, 0.02, 0.01], [0.02, -0.99 * margin, 0.01]])
    assert not points_in_hexahedra(corners, boxes).any()
    assert points_in_hexahedra(sides, boxes).all()


def test_a_body_at_a_table_side_keeps_the_side_sheet_down_to_the_floor() -> None:
    """A person standing at a table: their legs lie in the table side's noise sheet
    (closer to it than the sheet is thick, so unseen) and only their body above the table
    is a dynamic piece. The piece reaches into the side's sheet from above the face's upper
    edge without crossing the sheet's top face: the sheet is kept down to the floor, and
    the floor's sheet under it (the feet). A body crossing the side sheet's top face (seen
    in front of the sheet) also keeps the sheet down to the floor (legs in the sheet under
    it), and its own legs, seen, keep the floor's sheet."""
    ctx = _context(tuple(np.full((1, 1), sh.height) for sh in SHEETS))
    torso = box_vertices(np.array([[1.32, 0.7, 0.6]]), np.array([[1.38, 0.9, 1.0]]))
    legs = np.array([[1.35, 0.8, 0.05], [1.35, 0.55, 0.25]])  # in the side's sheet, low
    feet = np.array([[1.55, 0.8, 0.05]])  # in front of the side's sheet, in the floor's
    boxes = sheets_under(torso, ctx)
    assert points_in_hexahedra(legs, boxes).all()
    assert points_in_hexahedra(feet, boxes).all()
    crossing = box_vertices(np.array([[1.32, 0.7, 0.6]]), np.array([[1.6, 0.9, 1.0]]))
    boxes = sheets_under(crossing, ctx)
    assert points_in_hexahedra(legs, boxes).all()
    assert not points_in_hexahedra(feet, boxes).any()
    # a body wholly inside the side's sheet (closer to the side than the sheet is thick)
    # keeps it down to the floor too, but not the floor's sheet
    inside = box_vertices(np.array([[1.32, 0.7, 0.3]]), np.array([[1.38, 0.9, 0.5]]))
    boxes = sheets_under(inside, ctx)
    assert points_in_hexahedra(legs[:1], boxes).all() and not points_in_hexahedra(feet, boxes).any()
    # on the floor, a piece inside the sheet (flatter than it) keeps nothing
    flat = box_vertices(np.array([[-1.0, -1.0, 0.02]]), np.array([[-0.8, -0.8, 0.1]]))
    assert len(sheets_under(flat, ctx)) == 0



def test_legs_the_robot_hides_keep_the_floors_sheet_under_them() -> None:
    """A body whose shins the robot hides (a component touching M that reaches no sheet's
    top): under its low pieces, within the margin, the columns holding a point of M (here a
    stand-in for the cycle's images: a shin-sized 8 cm square of M from 0.1 to 0.5 m high)
    become leg boxes from the floor up to M's lowest tested point, and the floor's sheet
    kept under them holds the feet within the margin of the shin; a body touching M away
    from any such column adds nothing, and a body seen only from higher up (the robot
    hiding it to the hips) stands on the same legs."""
    base = _context(tuple(np.full((1, 1), sh.height) for sh in SHEETS))
    margin = base.params.floor_shell_margin
    shin = np.array([0.46, 0.54, 0.36, 0.44])  # x0, x1, y0, y1

    def m_columns(xy: np.ndarray, heights: np.ndarray) -> np.ndarray:
        inside = (xy[:, 0] >= shin[0]) & (xy[:, 0] <= shin[1]) & (xy[:, 1] >= shin[2]) & (xy[:, 1] <= shin[3])
        in_m = (heights >= 0.1) & (heights <= 0.5)
        return np.where(inside, heights[np.argmax(in_m)], np.inf)

    ctx = replace(base, m_columns=m_columns)
    lo, hi = np.array([[0.4, 0.3, 0.5]]), np.array([[0.8, 0.6, 1.5]])  # the body, seen from 0.5 m up
    legs = hidden_legs(lo, hi, np.array([True]), ctx)
    assert len(legs) >= 1
    assert points_in_hexahedra(np.array([[0.5, 0.4, 0.05], [0.5, 0.4, 0.3]]), legs).all()
    boxes = sheets_under(legs, ctx, horizontal=True)
    feet = np.array([[0.5 + 0.9 * margin, 0.4, 0.05], [0.5, 0.4 + 0.9 * margin, 0.15]])
    assert points_in_hexahedra(feet, boxes).all()
    # beyond the margin (and the sheet grid's cell) of the shin, and above the sheet
    far = np.array([[0.54 + margin + 2 * SHEET_PITCH, 0.4, 0.05], [0.5, 0.4, 0.3]])
    assert not points_in_hexahedra(far, boxes).any()
    away = hidden_legs(lo + 1.5, hi + 1.5, np.array([True]), ctx)  # no M under it
    assert len(away) == 0
    high = hidden_legs(lo + np.array([0.0, 0.0, 0.6]), hi + 0.6, np.array([True]), ctx)  # seen from 1.1 m up
    assert points_in_hexahedra(np.array([[0.5, 0.4, 0.05], [0.5, 0.4, 0.3]]), high).all()
    assert len(hidden_legs(lo, hi, np.array([False]), ctx)) == 0  # not touching M


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 40))
def test_leg_columns_are_the_union_of_the_footprints(seed: int, n: int) -> None:
    """The grid cells under the hidden legs' pieces (``_footprint_columns``) are exactly
    those some touching box's footprint covers (``floor(lo / g) <= cell < ceil(hi / g)``
    after clipping to the zone), each once: checked against the cells listed box by box,
    on boxes that reach past the zone, lie on grid lines or are not touching."""
    from polyhull.engine.dynamic_rules import LEG_GRID, _footprint_columns

    rng = np.random.default_rng(seed)
    zlo, zhi, g = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.5, 2.0]), LEG_GRID
    lo = rng.uniform(-1.3, 1.3, (n, 3))
    snap = rng.random((n, 3)) < 0.3  # on grid lines
    lo[snap] = np.round(lo[snap] / g) * g
    hi = lo + rng.uniform(0.0, 0.3, (n, 3)) * (rng.random((n, 1)) < 0.9)
    touching = rng.random(n) < 0.7
    want = set()
    for a, b in zip(lo[touching], hi[touching], strict=True):
        c0 = np.floor((np.clip(a[:2], zlo[:2], zhi[:2]) - zlo[:2]) / g).astype(int)
        c1 = np.ceil((np.clip(b[:2], zlo[:2], zhi[:2]) - zlo[:2]) / g).astype(int)
        want |= {(x, y) for x in range(c0[0], c1[0]) for y in range(c0[1], c1[1])}
    xy = _footprint_columns(lo, hi, touching, zlo, zhi, g)
    got = [tuple(np.round((p - zlo[:2]) / g - 0.5).astype(int)) for p in xy]
    assert len(got) == len(set(got))  # each cell once
    assert set(got) == want
    np.testing.assert_allclose(xy, [zlo[:2] + (np.array(c) + 0.5) * g for c in got] if got else np.zeros((0, 2)))
