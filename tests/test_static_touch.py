"""StaticModel.boxes_meet (a triangle grid and an exact box/triangle test) against
python-fcl's box-against-mesh collision with the static region, the oracle it replaced.

Boxes near the surface of the small cell's R3_static (on it, within 1e-6 of it, a few
centimetres off), far from it, and around its smallest component (a sliver of about 1 mm,
10 triangles) whole. Never "apart" where python-fcl finds the box meeting the surface,
and the same answer for every box farther than 1e-6 m from it.
"""

from __future__ import annotations

import fcl
import manifold3d as m3
import numpy as np
import pytest

from polyhull.engine.boxes import TriangleGrid, groups_meet_triangles
from polyhull.engine.static_model import StaticModel
from polyhull.monitor import Monitor

BAND = 1e-6
"""Distance [m] within which boxes_meet may say "meets" where python-fcl says apart."""


def _fcl_meets(static: StaticModel, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    out = np.zeros(len(lo), dtype=bool)
    for i in range(len(lo)):
        box = fcl.CollisionObject(fcl.Box(*(hi[i] - lo[i])), fcl.Transform(0.5 * (lo[i] + hi[i])))
        out[i] = fcl.collide(box, static.bvh, fcl.CollisionRequest(), fcl.CollisionResult()) > 0
    return out


def _surface_points(
    static: StaticModel, n: int, rng: np.random.Generator, flat: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) random points on R3_static's triangles and (n, 3) the triangles' outward unit
    normals; ``flat``: only on triangles facing along an axis (floor, walls, table tops)."""
    mesh = static.region.to_mesh64()
    v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    normal = np.cross(v[tris[:, 1]] - v[tris[:, 0]], v[tris[:, 2]] - v[tris[:, 0]])
    area = np.linalg.norm(normal, axis=1)
    keep = area > 1e-12
    normal[keep] /= area[keep, None]
    if flat:
        keep &= np.abs(normal).max(axis=1) > 1.0 - 1e-12
    pick = rng.choice(np.nonzero(keep)[0], size=n)
    w = rng.dirichlet(np.ones(3), size=n)
    return np.einsum("nk,nkd->nd", w, v[tris[pick]]), normal[pick]


def _boxes(static: StaticModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of every kind the dynamic rules ask about, and the kinds in between."""
    los, his = [], []
    # around surface points, offset by up to a few centimetres
    p, _ = _surface_points(static, 600, rng)
    half = rng.exponential(0.03, size=(600, 3)) + 1e-4
    centre = p + rng.normal(0.0, 0.03, size=(600, 3))
    los.append(centre - half)
    his.append(centre + half)
    # a face within 1e-6 of a surface point, along any axis on either side, or across it
    for flat in (False, True):
        p, normal = _surface_points(static, 300, rng, flat)
        rows = np.arange(300)
        if flat:  # outside a face that faces along an axis, across from the point
            axis = np.abs(normal).argmax(axis=1)
            side = np.sign(normal[rows, axis])
        else:
            axis = rng.integers(3, size=300)
            side = rng.choice([-1.0, 1.0], size=300)
        gap = rng.choice([0.0, 1e-9, 1e-7, 5e-7, -1e-7], size=300) * rng.uniform(0.5, 1.0, size=300)
        half = rng.uniform(0.001, 0.05, size=(300, 3))
        centre = p + rng.uniform(-1.0, 1.0, size=(300, 3)) * half
        centre[rows, axis] = p[rows, axis] + side * (gap + half[rows, axis])
        los.append(centre - half)
        his.append(centre + half)
    # anywhere in the cell (and beyond it), small and large
    bb = np.asarray(static.zone.bounding_box(), dtype=np.float64)
    corner = rng.uniform(bb[:3] - 0.3, bb[3:] + 0.3, size=(300, 3))
    los.append(corner)
    his.append(corner + rng.exponential(0.1, size=(300, 3)))
    return np.vstack(los), np.vstack(his)


@pytest.fixture(scope="module")
def static(small_monitor: Monitor) -> StaticModel:
    assert small_monitor.static.bvh is not None
    return small_monitor.static


def test_boxes_meet_as_fcl(static: StaticModel) -> None:
    rng = np.random.default_rng(3)
    lo, hi = _boxes(static, rng)
    got = static.boxes_meet(lo, hi, 0.0, np.arange(len(lo)), len(lo))
    fcl_yes = _fcl_meets(static, lo, hi)
    # grown by BAND / sqrt(3) on every side, a box reaches at most BAND farther: every box
    # farther than BAND from the surface (and some nearer) stays apart, and must be said so
    fcl_near = _fcl_meets(static, lo - BAND / np.sqrt(3.0), hi + BAND / np.sqrt(3.0))
    assert not np.any(fcl_yes & ~got), np.nonzero(fcl_yes & ~got)[0]
    far = ~fcl_near
    assert not np.any(got & far), np.nonzero(got & far)[0]
    band = fcl_near & ~fcl_yes
    # every kind was tested: meeting, apart, and within the band
    assert fcl_yes.sum() >= 300 and far.sum() >= 300 and band.sum() >= 20, (fcl_yes.sum(), far.sum(), band.sum())


def test_distance_grows_the_boxes(static: StaticModel) -> None:
    """Growing by ``distance`` is the same as asking about the grown boxes."""
    rng = np.random.default_rng(4)
    lo, hi = _boxes(static, rng)
    d = 0.05
    got = static.boxes_meet(lo, hi, d, np.arange(len(lo)), len(lo))
    fcl_yes = _fcl_meets(static, lo - d, hi + d)
    fcl_near = _fcl_meets(static, lo - d - BAND, hi + d + BAND)
    assert not np.any(fcl_yes & ~got)
    assert not np.any(got & ~fcl_near)
    assert 0 < got.sum() < len(got)


def test_a_box_around_a_whole_component_meets_it(static: StaticModel) -> None:
    """A box holding a whole small component (a 1 mm cube beside R3_static's triangles, no
    triangle crossing the box's faces) meets it; the same box moved off by its own size is
    apart. (R3_static of the small cell once had such a sliver of its own; it is one
    component since the sheets along a table's edges are kept wherever one face spares
    them.)"""
    mesh = static.region.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    top = verts.max(axis=0)
    cube = m3.Manifold.cube((1e-3, 1e-3, 1e-3)).translate(tuple(top + [-1.0, -1.0, 0.5])).to_mesh64()
    cv = np.asarray(cube.vert_properties, dtype=np.float64)[:, :3]
    grid = TriangleGrid.of(
        np.concatenate([verts, cv]), np.concatenate([tris, np.asarray(cube.tri_verts, dtype=np.int64) + len(verts)])
    )
    rng = np.random.default_rng(5)
    margin = rng.uniform(1e-5, 1e-3, size=(50, 6))
    lo = cv.min(axis=0) - margin[:, :3]
    hi = cv.max(axis=0) + margin[:, 3:]
    assert groups_meet_triangles(grid, lo, hi, np.arange(50), 50).all()
    shift = (hi - lo) * 1.5 * np.array([1.0, 0.0, 0.0])
    assert not groups_meet_triangles(grid, lo + shift, hi + shift, np.arange(50), 50).any()


def test_groups_meet_when_one_box_does(static: StaticModel) -> None:
    rng = np.random.default_rng(6)
    lo, hi = _boxes(static, rng)
    each = static.boxes_meet(lo, hi, 0.01, np.arange(len(lo)), len(lo))
    groups = rng.integers(0, 200, size=len(lo))
    got = static.boxes_meet(lo, hi, 0.01, groups, 200)
    expected = np.zeros(200, dtype=bool)
    np.logical_or.at(expected, groups, each)
    assert np.array_equal(got, expected)
    assert static.boxes_meet(lo, hi, 0.01).tolist() == [bool(each.any())]
    assert static.boxes_meet(np.zeros((0, 3)), np.zeros((0, 3)), 0.01, np.zeros(0, np.int64), 3).tolist() == [False] * 3
