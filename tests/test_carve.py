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
