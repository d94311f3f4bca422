"""Carving dynamic pieces (polyhull.engine.pieces.carve): termination and keeping."""

from __future__ import annotations

import numpy as np

from polyhull.cellfile import load_cell
from polyhull.engine.pieces import (
    CameraStack,
    CarveParams,
    ImageStack,
    PyramidStack,
    carve,
    piece_vertices,
)


def _setup(free_other: float):  # noqa: ANN202
    cell = load_cell("fixtures/cells/small_cell.toml")
    stack = CameraStack.of(cell.cameras)
    free = ImageStack(stack, fill=free_other)
    end = ImageStack(stack, fill=6.0)
    free.image(0)[:] = 0.3  # camera 0's own segments start near it
    active = np.ones(len(cell.cameras), dtype=bool)
    return cell, stack, free, end, active


def test_a_budget_below_a_pixel_footprint_terminates() -> None:
    # One pixel column of camera 0, 2 m to 5.5 m deep: at 5.5 m its footprint is larger
    # than the budget, so only the depth can be split; half of it is seen free by camera 1
    # (whose free depth is 3.5 m everywhere), so every half stays undecided for a while.
    cell, stack, free, end, active = _setup(3.5)
    init = np.array([[0.0, 100, 100, 80, 80, 2.0, 5.5]])
    zlo, zhi = np.asarray(cell.zone.min, float), np.asarray(cell.zone.max, float)
    params = CarveParams(alpha=0.0, size_min=1e-4, size_max=1e-4)
    pieces, overflow = carve(init, stack, active, PyramidStack.build(free, active), free, end, np.zeros((0, 4)), zlo, zhi, 1, params)
    assert not overflow
    assert 0 < len(pieces) < 10_000
    # what is kept stays inside the initial segment
    assert np.all(pieces.boxes[:, 5] >= 2.0 - 1e-9) and np.all(pieces.boxes[:, 6] <= 5.5 + 1e-9)


def test_nothing_free_keeps_the_piece_whole() -> None:
    cell, stack, free, end, active = _setup(0.0)  # camera 1 frees nothing
    init = np.array([[0.0, 90, 110, 70, 90, 2.0, 5.5]])
    zlo, zhi = np.asarray(cell.zone.min, float), np.asarray(cell.zone.max, float)
    pieces, _ = carve(init, stack, active, PyramidStack.build(free, active), free, end, np.zeros((0, 4)), zlo, zhi, 1, CarveParams())
    assert len(pieces) == 1
    assert np.allclose(pieces.vertices, piece_vertices(init, stack))


def test_pyramid_range_bounds_every_box() -> None:
    """The pyramids' range query (level 0 read from the free image itself) gives, over any
    pixel box, a min no larger and a max no smaller than the box's own (exact on boxes
    under 8 px a side), for every camera of a stack of images of different sizes; asked
    about a piece's depths [zlo, zhi], it may stop early, and its answers (covered:
    ``zhi < min``, maybe freed: ``zlo < max``) are those of the whole range."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.engine.pieces import _range

    cell = load_cell("fixtures/cells/small_cell.toml")
    stack = CameraStack.of(cell.cameras)
    free = ImageStack(stack, fill=None)
    rng = np.random.default_rng(0)
    for i in range(len(cell.cameras)):
        # bands of rows at their own depths (a band's rows differ from the next band's), so
        # that the rows read before an early stop bound the whole box's range loosely
        H, W = free.shape(i)
        band = rng.uniform(0.3, 6.0, size=(H + 15) // 16).repeat(16)[:H, None]
        free.image(i)[:] = (band + rng.uniform(0.0, 0.2, size=(H, W))).astype(np.float32)
    pyr = PyramidStack.build(free, np.ones(len(cell.cameras), dtype=bool))

    @settings(max_examples=300, deadline=None)
    @given(
        st.integers(0, len(cell.cameras) - 1), st.floats(0, 1), st.floats(0, 1), st.floats(0, 1), st.floats(0, 1),
        st.floats(0.0, 7.0), st.floats(0.0, 2.0),
    )
    def check(i: int, a: float, b: float, c: float, d: float, z0: float, dz: float) -> None:
        H, W = free.shape(i)
        u0, u1 = sorted((int(a * (W - 1)), int(b * (W - 1))))
        v0, v1 = sorted((int(c * (H - 1)), int(d * (H - 1))))
        args = (pyr.mins, pyr.maxs, pyr.image, pyr.offsets[i], pyr.shapes[i], pyr.levels[i], u0, u1, v0, v1)
        lo, hi = _range(*args, np.inf, -np.inf)  # an empty depth range: never stops early
        box = free.image(i)[v0 : v1 + 1, u0 : u1 + 1]
        assert lo <= box.min() and hi >= box.max()
        if u1 - u0 < 8 and v1 - v0 < 8:
            assert lo == box.min() and hi == box.max()
        zlo, zhi = z0, z0 + dz
        lo_z, hi_z = _range(*args, zlo, zhi)
        assert (zhi < lo_z) == (zhi < lo) and (zlo < hi_z) == (zlo < hi)

    check()


def test_carving_on_two_threads_gives_the_same_pieces() -> None:
    """Carving split over a pool's two threads keeps the same set of pieces as one call."""
    from concurrent.futures import ThreadPoolExecutor

    cell, stack, free, end, active = _setup(3.5)
    rng = np.random.default_rng(1)
    img = free.image(1)
    img[:] = rng.uniform(2.0, 5.0, size=img.shape).astype(np.float32)  # camera 1 frees in patches
    u0 = rng.integers(0, 150, size=200).astype(float)
    v0 = rng.integers(0, 110, size=200).astype(float)
    init = np.column_stack([np.zeros(200), u0, u0 + 7, v0, v0 + 7, np.full(200, 1.0), np.full(200, 5.5)])
    zlo, zhi = np.asarray(cell.zone.min, float), np.asarray(cell.zone.max, float)
    pyr = PyramidStack.build(free, active)
    params = CarveParams(alpha=0.1, size_min=0.05, size_max=0.3)
    one, _ = carve(init, stack, active, pyr, free, end, np.array([[0.0, 0.0, 1.0, 0.3]]), zlo, zhi, 1, params)
    with ThreadPoolExecutor(2) as pool:
        two, _ = carve(init, stack, active, pyr, free, end, np.array([[0.0, 0.0, 1.0, 0.3]]), zlo, zhi, 1, params, pool=pool)
    assert len(one) > len(init)  # carving split pieces
    key = lambda b: sorted(map(tuple, b))  # noqa: E731
    assert key(one.boxes) == key(two.boxes)
    order = np.lexsort(two.boxes.T[::-1])
    np.testing.assert_array_equal(two.vertices[order], piece_vertices(two.boxes[order], stack))
