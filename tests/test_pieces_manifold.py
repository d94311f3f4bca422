"""pieces_manifold (polyhull.verdict): the union of pieces built per camera in image space
and mapped to the world is the union of the pieces' world hexahedra."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_camera
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.pieces import CameraStack, piece_vertices
from polyhull.verdict import hexahedra_manifold, pieces_manifold

CAMERAS = CameraStack.of(
    [
        make_camera(width=64, height=48, position=(2.0, 0.3, 3.0), target=(0.0, 0.0, 0.5)),
        make_camera(width=64, height=48, position=(-1.5, 1.8, 2.5), target=(0.0, 0.0, 0.5)),
    ]
)


def _boxes(rng: np.random.Generator, n: int, cameras: int) -> np.ndarray:
    """``n`` random pieces (N, 7) of the first ``cameras`` cameras, overlapping at times."""
    c = rng.integers(0, cameras, n).astype(float)
    u0 = rng.integers(0, 56, n)
    v0 = rng.integers(0, 40, n)
    u1 = u0 + rng.integers(0, 8, n)
    v1 = v0 + rng.integers(0, 8, n)
    z0 = rng.uniform(1.0, 4.0, n)
    z1 = z0 + rng.uniform(0.05, 1.0, n)
    return np.column_stack([c, u0, u1, v0, v1, z0, z1]).astype(np.float64)


def _frustum_volume(b: np.ndarray) -> float:
    """Exact volume [m^3] of image-space boxes (disjoint): du dv (z1^3 - z0^3) / (3 fx fy)."""
    fx, fy = CAMERAS.intr[b[:, 0].astype(int), 0], CAMERAS.intr[b[:, 0].astype(int), 1]
    return float(((b[:, 2] - b[:, 1] + 1) * (b[:, 4] - b[:, 3] + 1) * (b[:, 6] ** 3 - b[:, 5] ** 3) / (3 * fx * fy)).sum())


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), cameras=st.integers(1, 2))
def test_the_union_is_the_union_of_the_world_hexahedra(seed: int, n: int, cameras: int) -> None:
    boxes = _boxes(np.random.default_rng(seed), n, cameras)
    got = pieces_manifold(boxes, CAMERAS)
    want = hexahedra_manifold(piece_vertices(boxes, CAMERAS))
    scale = want.volume()
    assert scale > 0
    assert got.volume() == pytest.approx(scale, rel=1e-6)
    assert (got - want).volume() <= 1e-6 * scale and (want - got).volume() <= 1e-6 * scale


def test_disjoint_pieces_of_one_camera_keep_their_exact_volume() -> None:
    """A camera's pieces meet face to face (a grid of tiles, split in depth): the union's
    volume is the sum of the frustums' exact volumes, and one piece's is its own."""
    rows = []
    for u in range(0, 40, 4):
        for v in range(0, 32, 4):
            z = 1.5 + 0.1 * ((u + v) % 7)
            rows += [[0, u, u + 3, v, v + 3, z, z + 0.4], [0, u, u + 3, v, v + 3, z + 0.4, z + 1.1]]
    boxes = np.array(rows, dtype=np.float64)
    assert pieces_manifold(boxes, CAMERAS).volume() == pytest.approx(_frustum_volume(boxes), rel=1e-9)
    assert pieces_manifold(boxes[:1], CAMERAS).volume() == pytest.approx(_frustum_volume(boxes[:1]), rel=1e-12)
    assert pieces_manifold(np.zeros((0, 7)), CAMERAS).is_empty()
