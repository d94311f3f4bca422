"""The procedural person: a watertight body with the right size, pose and placement."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.errors import GeometryError
from polyhull.person import PersonTrack, make_person, sample_points_inside


@pytest.mark.parametrize("pose", ["standing", "walking", "reaching", "crouching"])
def test_person_is_one_watertight_body(pose):
    mesh = make_person(1.75, pose, phase=0.7)
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0  # outward orientation
    assert len(mesh.split(only_watertight=False)) == 1
    # an adult of 1.75 m displaces 60 to 90 litres
    assert 0.05 < mesh.volume < 0.09


@pytest.mark.parametrize("height", [1.55, 1.75, 1.95])
@pytest.mark.parametrize("pose", ["standing", "reaching"])
def test_height_and_feet_on_the_floor(height, pose):
    mesh = make_person(height, pose, position=(1.0, 2.0), floor_z=0.25)
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(0.25, abs=1e-9)
    assert hi[2] - 0.25 == pytest.approx(height, rel=0.02)


def test_walking_keeps_a_foot_on_the_floor_and_moves_the_legs():
    lowest = []
    for phase in np.linspace(0.0, 2 * np.pi, 7):
        mesh = make_person(1.8, "walking", phase=float(phase), floor_z=0.0)
        lowest.append(mesh.bounds[0, 2])
        assert mesh.bounds[1, 2] == pytest.approx(1.8, rel=0.05)
    np.testing.assert_allclose(lowest, 0.0, atol=1e-9)
    a = make_person(1.8, "walking", phase=0.0)
    b = make_person(1.8, "walking", phase=np.pi / 2)
    # legs apart at mid-stride: longer footprint along the walking direction
    assert (b.bounds[1, 0] - b.bounds[0, 0]) > (a.bounds[1, 0] - a.bounds[0, 0]) + 0.1
    standing = make_person(1.8, "standing")
    assert (b.bounds[1, 0] - b.bounds[0, 0]) > (standing.bounds[1, 0] - standing.bounds[0, 0]) + 0.3


def test_reaching_hands_are_in_front_of_the_chest():
    height = 1.75
    mesh = make_person(height, "reaching")
    standing = make_person(height, "standing")
    v = mesh.vertices
    front = v[:, 0].max()
    # hands about 0.6 m in front of the chest surface (which is ~0.12 m ahead of the axis)
    chest_front = standing.vertices[(standing.vertices[:, 2] > 1.2) & (standing.vertices[:, 2] < 1.3), 0].max()
    assert 0.45 < front - chest_front < 0.75
    # the hands are below the shoulders (reaching down, as over a table) and above the hips
    hand_z = v[v[:, 0] > front - 0.1, 2]
    assert 0.53 * height < hand_z.mean() < 0.818 * height


def test_pose_placement_and_yaw():
    reach = make_person(1.75, "reaching", position=(3.0, -1.0), yaw=np.pi / 2)
    lo, hi = reach.bounds
    # facing +y after a quarter turn: the arms extend along +y from the position
    assert hi[1] - (-1.0) > 0.6
    assert (-1.0) - lo[1] < 0.25
    assert abs((lo[0] + hi[0]) / 2 - 3.0) < 0.05


@settings(max_examples=10, deadline=None)
@given(
    height=st.floats(1.4, 2.1),
    phase=st.floats(0.0, 2 * np.pi),
    yaw=st.floats(-np.pi, np.pi),
    pose=st.sampled_from(["standing", "walking", "reaching", "crouching"]),
)
def test_person_is_watertight_for_any_parameters(height, phase, yaw, pose):
    mesh = make_person(height, pose, position=(0.5, 0.5), yaw=yaw, phase=phase)
    assert mesh.is_watertight
    assert mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
    assert np.isfinite(mesh.vertices).all()


def test_crouching_is_a_low_squat_leaning_forward():
    height = 1.75
    mesh = make_person(height, "crouching", floor_z=0.1)
    standing = make_person(height, "standing", floor_z=0.1)
    lo, hi = mesh.bounds
    assert lo[2] == pytest.approx(0.1, abs=1e-9)  # feet on the floor
    # about 0.65 of the height tall (a deep squat)
    assert 0.55 * height < hi[2] - 0.1 < 0.75 * height
    # the same body: the volume within a few per cent of the standing one's
    assert mesh.volume == pytest.approx(standing.volume, rel=0.05)
    v = mesh.vertices
    # the knees in front (+x), the head forward of the feet's midpoint by the trunk's lean
    assert v[:, 0].max() > 0.35
    head = v[v[:, 2] > hi[2] - 0.1]
    assert head[:, 0].mean() > 0.15
    # the body folded low: over a third of it within 0.5 m of the floor (0.42 of it;
    # standing, walking or reaching 0.15 to 0.16)
    for pose, (least, most) in (("crouching", (0.35, 0.5)), ("standing", (0.1, 0.2))):
        inside = sample_points_inside(make_person(height, pose), 4000, seed=1)  # type: ignore[arg-type]
        assert least < (inside[:, 2] < 0.5).mean() < most, pose


def test_invalid_parameters_are_rejected():
    with pytest.raises(GeometryError, match="height"):
        make_person(0.1)
    with pytest.raises(GeometryError, match="pose"):
        make_person(1.7, "dancing")  # type: ignore[arg-type]
    with pytest.raises(GeometryError, match="position"):
        make_person(1.7, position=(1.0, 2.0, 3.0))
    with pytest.raises(GeometryError, match="yaw"):
        make_person(1.7, yaw=float("nan"))


def test_sample_points_inside():
    mesh = make_person(1.75, "standing", position=(1.0, 1.0))
    points = sample_points_inside(mesh, 500, seed=3)
    assert points.shape == (500, 3)
    # independent of the ray-parity test used for sampling: signed distance, > 0 inside
    assert (trimesh.proximity.signed_distance(mesh, points[:200]) > -1e-9).all()
    np.testing.assert_array_equal(points, sample_points_inside(mesh, 500, seed=3))
    assert not np.array_equal(points, sample_points_inside(mesh, 500, seed=4))
    # uniform: the share of points above the hips matches the share of volume up there
    assert 0.35 < np.mean(points[:, 2] > 0.53 * 1.75) < 0.75
    assert sample_points_inside(mesh, 0).shape == (0, 3)
    open_mesh = mesh.copy()
    open_mesh.update_faces(np.arange(len(open_mesh.faces) - 1))
    with pytest.raises(GeometryError, match="watertight"):
        sample_points_inside(open_mesh, 10)


def test_person_track():
    track = PersonTrack(start=(0.0, 0.0), end=(3.0, 4.0), speed=1.25, t0=1.0, end_pose="reaching")
    assert track.length == pytest.approx(5.0)
    assert track.duration == pytest.approx(4.0)
    assert track.yaw == pytest.approx(np.arctan2(4.0, 3.0))
    np.testing.assert_allclose(track.position(0.0), [0.0, 0.0])
    np.testing.assert_allclose(track.position(3.0), [1.5, 2.0])
    np.testing.assert_allclose(track.position(99.0), [3.0, 4.0])
    assert track.is_walking(2.0) and not track.is_walking(0.5) and not track.is_walking(5.0)
    mid = track.mesh(3.0)
    assert mid.is_watertight
    centre = (mid.bounds[0, :2] + mid.bounds[1, :2]) / 2
    assert np.linalg.norm(centre - [1.5, 2.0]) < 0.3
    # after arrival the person reaches forward along the walking direction
    end = track.mesh(10.0)
    heading = np.array([0.6, 0.8])
    reach = (end.vertices[:, :2] - [3.0, 4.0]) @ heading
    assert reach.max() > 0.6
    with pytest.raises(GeometryError, match="speed"):
        PersonTrack(start=(0.0, 0.0), end=(1.0, 0.0), speed=0.0)


def test_person_track_params_replay_the_mesh():
    track = PersonTrack(start=(0.0, 1.0), end=(2.0, 1.0), speed=1.0)
    params = track.params(0.5)
    assert params["pose"] == "walking"
    assert params["position"] == (0.5, 1.0)
    assert params["phase"] == pytest.approx(2 * np.pi * 0.5 / (0.8 * 1.75))
    np.testing.assert_array_equal(make_person(**params).vertices, track.mesh(0.5).vertices)
    assert track.params(5.0)["pose"] == "standing"
