"""Fusion: the k-of-n rule of the static hull, and the engine's zero-miss point oracle."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
from conftest import exactly_possibly_occupied, in_robot_occlusion, manifold_contains
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from polyhull.distance import points_in_hexahedra
from polyhull.fusion import free_union
from polyhull.person import make_person, sample_points_inside
from polyhull.simulator import SensorEffects


def depth_hull(zone: m3.Manifold, regions: list[m3.Manifold], k: int = 1) -> m3.Manifold:
    """C = Z minus the k-of-n union (how the static model fuses its cameras)."""
    return zone - free_union(regions, k)


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(tuple(float(h - l) for l, h in zip(lo, hi, strict=True))).translate(lo)  # noqa: E741


# Boxes as corner pairs, built per test (manifolds kept in module globals would outlive
# the interpreter's last garbage collection).
_ZONE = ((0, 0, 0), (3, 3, 2.5))
# Three overlapping "free regions".
_F = {
    "F1": ((0, 0, 0), (2, 2, 2)),
    "F2": ((1, 1, 0), (3, 3, 2)),
    "F3": ((0.5, 0, 1), (2.5, 3, 2.5)),
}


@pytest.fixture
def boxes() -> dict[str, m3.Manifold]:
    """The zone and the three free regions."""
    out = {name: _box(*corners) for name, corners in _F.items()}
    out["ZONE"] = _box(*_ZONE)
    return out


def test_zero_cameras_hull_is_zone(boxes: dict[str, m3.Manifold]) -> None:
    ZONE = boxes["ZONE"]
    assert depth_hull(ZONE, []).volume() == pytest.approx(ZONE.volume(), rel=1e-12)
    assert depth_hull(ZONE, [m3.Manifold()]).volume() == pytest.approx(ZONE.volume(), rel=1e-12)
    assert depth_hull(ZONE, [], k=2).volume() == pytest.approx(ZONE.volume(), rel=1e-12)


def test_union_hull_volume_by_inclusion_exclusion(boxes: dict[str, m3.Manifold]) -> None:
    ZONE, F1, F2 = boxes["ZONE"], boxes["F1"], boxes["F2"]
    # |F1 u F2| = 8 + 8 - |[1,2]^2 x [0,2]| = 16 - 2 = 14
    assert free_union([F1, F2]).volume() == pytest.approx(14.0, rel=1e-12)
    assert depth_hull(ZONE, [F1, F2]).volume() == pytest.approx(22.5 - 14.0, rel=1e-12)


def test_k_of_n_two_of_three(boxes: dict[str, m3.Manifold]) -> None:
    F1, F2, F3 = boxes["F1"], boxes["F2"], boxes["F3"]
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


@pytest.mark.parametrize("names", [["F1", "F2"], ["F1", "F2", "F3"], ["F1", "F3"]])
def test_k2_hull_contains_k1_hull_and_lies_in_zone(
    names: list[str], boxes: dict[str, m3.Manifold]
) -> None:
    ZONE = boxes["ZONE"]
    regions = [boxes[n] for n in names]
    c1 = depth_hull(ZONE, regions, k=1)
    c2 = depth_hull(ZONE, regions, k=2)
    assert c2.volume() >= c1.volume() - 1e-9
    # C1 subset of C2: C1 \ C2 is empty (up to round-off).
    assert (c1 - c2).volume() <= 1e-9
    for c in (c1, c2):
        assert (c - ZONE).volume() <= 1e-9
        assert c.status() == m3.Error.NoError


# -- the point oracle for C on simulated scenes -------------------------------------------

_POSES = st.sampled_from(["standing", "walking", "reaching", "crouching"])


@settings(
    max_examples=2,
    deadline=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    x=st.floats(0.35, 1.0),
    y=st.floats(0.35, 2.65),
    yaw=st.floats(-np.pi, np.pi),
    pose=_POSES,
    noisy=st.booleans(),
    seed=st.integers(0, 1000),
)
def test_region_point_oracle_and_people_inside_region(
    small_monitor, small_sim, small_cell, x: float, y: float, yaw: float, pose: str, noisy: bool, seed: int  # noqa: ANN001
) -> None:
    """Zero misses: every point of Z that the exact per-pixel free depth leaves possibly
    occupied is in the engine's R2 (the static hull or a dynamic piece), or in the padded
    robot's declared shadow, or in a solid; the people's bodies are in R3 or that shadow.

    Default sensor effects are used without flying pixels: flying pixels are real
    measurements that legitimately free space inside a person (a depth between foreground
    and background), so the exact classification would call such points free too, but the
    people test below would fail for a reason that is not the engine's.
    """
    person = make_person(pose=pose, position=(x, y), yaw=yaw)  # type: ignore[arg-type]
    effects = SensorEffects(flying_pixels=False) if noisy else SensorEffects.none()
    frames = small_sim.render(targets=[person], seed=seed, stamp=1.0, effects=effects)
    small_monitor.reset()
    q = np.asarray(small_cell.robot.q)
    v = small_monitor.step(frames, q, stamp=1.0)
    assert not any("internal" in f for f in v.faults), v.faults
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(small_cell.zone.min), np.asarray(small_cell.zone.max)
    points = rng.uniform(lo, hi, size=(4000, 3))
    occupied = exactly_possibly_occupied(small_monitor, frames, points)
    assert occupied.sum() > 100  # the oracle tests something
    solids = np.zeros(len(points), dtype=bool)
    for o in small_cell.solid_obstacles:
        b0, b1 = o.mesh.bounds
        solids |= np.all((points >= b0) & (points <= b1), axis=1)
    in_r2 = small_monitor.static.hull_contains(points) | points_in_hexahedra(points, v._geometry.pieces)
    excused = in_robot_occlusion(small_monitor, points) | solids
    misses = occupied & ~in_r2 & ~excused
    assert not misses.any(), f"{misses.sum()} exactly occupied points outside R2: {points[misses][:5]}"
    # People inside R3 unless in the robot's declared shadow or inside a solid obstacle.
    body = sample_points_inside(person, 60, seed=seed)
    body = body[small_cell.zone.contains(body)]  # R lies in Z; an arm may reach out of it
    kept = v._geometry.kept
    in_r3 = manifold_contains(small_monitor.static.region, body) | points_in_hexahedra(body, kept)
    ok = in_r3 | in_robot_occlusion(small_monitor, body)
    for o in small_cell.solid_obstacles:
        b0, b1 = o.mesh.bounds
        ok |= np.all((body >= b0) & (body <= b1), axis=1)
    assert ok.all(), f"{(~ok).sum()} person points outside R3: {body[~ok][:5]}"


def test_person_foot_kept_by_plausibility(small_monitor, small_sim, small_cell) -> None:  # noqa: ANN001
    """A person whose legs the robot hides (in M) keeps the foot that stands out in R2.

    Regression: the floor-shell rule once sliced R2 only, found nothing standing above the
    foot, and removed it with the floor noise sheet.
    """
    person = make_person(pose="standing", position=(0.35, 0.35), yaw=0.0)
    frames = small_sim.render(targets=[person], seed=0, stamp=1.0, effects=SensorEffects.none())
    small_monitor.reset()
    v = small_monitor.step(frames, np.asarray(small_cell.robot.q), stamp=1.0)
    foot = np.array([[0.4391223, 0.21654438, 0.07169663]])
    assert manifold_contains(v.region_r2, foot).all()
    assert manifold_contains(v.region, foot).all()
    assert points_in_hexahedra(foot, v._geometry.kept).all() or manifold_contains(small_monitor.static.region, foot).all()
