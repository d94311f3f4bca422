"""Fusion of camera regions: the depth hull C and the k-of-n rule."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest

from polyhull.fusion import depth_hull, free_union


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(tuple(float(h - l) for l, h in zip(lo, hi, strict=True))).translate(lo)  # noqa: E741


ZONE = _box((0, 0, 0), (3, 3, 2.5))
# Three overlapping "free regions".
F1 = _box((0, 0, 0), (2, 2, 2))
F2 = _box((1, 1, 0), (3, 3, 2))
F3 = _box((0.5, 0, 1), (2.5, 3, 2.5))


def test_zero_cameras_hull_is_zone() -> None:
    assert depth_hull(ZONE, []).volume() == pytest.approx(ZONE.volume(), rel=1e-12)
    assert depth_hull(ZONE, [m3.Manifold()]).volume() == pytest.approx(ZONE.volume(), rel=1e-12)
    assert depth_hull(ZONE, [], k=2).volume() == pytest.approx(ZONE.volume(), rel=1e-12)


def test_union_hull_volume_by_inclusion_exclusion() -> None:
    # |F1 u F2| = 8 + 8 - |[1,2]^2 x [0,2]| = 16 - 2 = 14
    assert free_union([F1, F2]).volume() == pytest.approx(14.0, rel=1e-12)
    assert depth_hull(ZONE, [F1, F2]).volume() == pytest.approx(22.5 - 14.0, rel=1e-12)


def test_k_of_n_two_of_three() -> None:
    # F_2 = (F1 n F2) u (F1 n F3) u (F2 n F3)
    f12 = F1 ^ F2
    f13 = F1 ^ F3
    f23 = F2 ^ F3
    expected = (f12 + f13 + f23).volume()
    assert free_union([F1, F2, F3], k=2).volume() == pytest.approx(expected, rel=1e-12)
    assert free_union([F1, F2, F3], k=3).volume() == pytest.approx((f12 ^ F3).volume(), rel=1e-12)
    assert free_union([F1, F2], k=3).is_empty()
    with pytest.raises(ValueError, match="k must be >= 1"):
        free_union([F1], k=0)


@pytest.mark.parametrize("regions", [[F1, F2], [F1, F2, F3], [F1, F3]])
def test_k2_hull_contains_k1_hull_and_lies_in_zone(regions: list[m3.Manifold]) -> None:
    c1 = depth_hull(ZONE, regions, k=1)
    c2 = depth_hull(ZONE, regions, k=2)
    assert c2.volume() >= c1.volume() - 1e-9
    # C1 subset of C2: C1 \ C2 is empty (up to round-off).
    assert (c1 - c2).volume() <= 1e-9
    for c in (c1, c2):
        assert (c - ZONE).volume() <= 1e-9
        assert c.status() == m3.Error.NoError


def test_real_camera_regions_fusion(small_monitor, small_sim) -> None:  # noqa: ANN001
    """On the small cell: C inside Z, each C(i) contains C, k=2 hull contains the k=1 hull."""
    frames = small_sim.render(stamp=0.0, seed=3)
    regions = small_monitor.camera_regions(frames)
    zone = small_monitor.cell.zone.manifold()
    frees = [zone - c for c in regions.values()]
    c1 = depth_hull(zone, frees, k=1)
    c2 = depth_hull(zone, frees, k=2)
    assert (c1 - zone).volume() <= 1e-9
    for c in regions.values():
        assert (c1 - c).volume() <= 1e-6
    assert (c1 - c2).volume() <= 1e-6
    assert c2.volume() > c1.volume()  # two cameras with different views: strictly larger
    # Intersection of the per-camera regions is the hull.
    inter = m3.Manifold.batch_boolean(list(regions.values()), m3.OpType.Intersect)
    assert np.isclose(inter.volume(), c1.volume(), rtol=1e-6)
