"""pieces_manifold (polyhull.verdict): the union of pieces built per camera in image space
and mapped to the world is the union of the pieces' world hexahedra."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_camera, manifold_contains
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.distance import points_in_hexahedra
from polyhull.engine.pieces import CameraStack, piece_vertices
from polyhull.verdict import pieces_manifold

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
def test_the_union_holds_exactly_the_points_of_the_world_hexahedra(seed: int, n: int, cameras: int) -> None:
    """Points classified by the pieces' half-spaces (``points_in_hexahedra``) against the
    union's manifold: half in the pieces (moved up to about 5 cm), half in their bounding
    box. (Not the symmetric difference with the world hexahedra's union: the two meshes
    share surfaces triangulated differently, and manifold3d's difference of such meshes
    leaves slivers of up to 1e-3 m^3 where both hold exactly the same points.)"""
    rng = np.random.default_rng(seed)
    boxes = _boxes(rng, n, cameras)
    vertices = piece_vertices(boxes, CAMERAS)
    got = pieces_manifold(boxes, CAMERAS)
    weights = rng.dirichlet(np.ones(8), size=1500)
    inside = np.einsum("nk,nkj->nj", weights, vertices[rng.integers(0, n, 1500)])
    lo, hi = vertices.min(axis=(0, 1)), vertices.max(axis=(0, 1))
    points = np.concatenate([inside + rng.normal(0.0, 0.03, inside.shape), rng.uniform(lo, hi, size=(1500, 3))])
    want = points_in_hexahedra(points, vertices)
    assert want.sum() > 300 and (~want).sum() > 300
    np.testing.assert_array_equal(manifold_contains(got, points, half=1e-9), want)
    # and no more volume than the pieces have (overlaps count once)
    assert got.volume() <= _frustum_volume(boxes) * (1 + 1e-9)


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
