"""Ray casting against closed-form depths of planes and boxes, and an independent oracle."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from trimesh.ray import ray_triangle

from polyhull.camera import Camera, Intrinsics, look_at_rotation
from polyhull.cell import Cell, Obstacle, Zone
from polyhull.errors import GeometryError
from polyhull.raycast import (
    MeshCaster,
    StaticScene,
    floor_depth,
    render_depth,
    render_reference,
)

INTRINSICS = Intrinsics(width=64, height=48, fx=50.0, fy=52.0, cx=31.5, cy=23.5)


def camera_at(position, rotation, intrinsics=INTRINSICS, name="cam"):
    T = np.eye(4)
    T[:3, :3] = rotation
    T[:3, 3] = position
    return Camera(name=name, kind="depth", intrinsics=intrinsics, T_world_camera=T)


def looking_down(height, xy=(0.0, 0.0), intrinsics=INTRINSICS):
    # camera x = world x, camera y = world -y, camera z (optical axis) = world -z
    return camera_at((xy[0], xy[1], height), np.diag([1.0, -1.0, -1.0]), intrinsics)


def box(center, size):
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_translation(center)
    return mesh


def pixel_grid(intrinsics, step=1):
    u = np.arange(0, intrinsics.width, step, dtype=np.float64)
    v = np.arange(0, intrinsics.height, step, dtype=np.float64)
    return np.meshgrid(u, v)


def test_floor_seen_straight_down_is_the_height():
    depth = render_depth(looking_down(2.5), [], floor_z=0.0)
    assert depth.dtype == np.float32
    assert depth.shape == (48, 64)
    np.testing.assert_allclose(depth, 2.5, rtol=0, atol=1e-6)


def test_floor_at_nonzero_height():
    depth = floor_depth(looking_down(2.5), floor_z=-0.5)
    np.testing.assert_allclose(depth, 3.0, atol=1e-6)


@pytest.mark.parametrize("alpha_deg", [20.0, 45.0, 70.0])
def test_tilted_camera_sees_floor_in_closed_form(alpha_deg):
    """Optical axis tilted alpha below the horizon, looking along +x from height h.

    Camera z = (cos a, 0, -sin a) and image down y = (-sin a, 0, -cos a) in the world, so
    the ray of row v with b = (v - cy) / fy descends by sin a + b cos a per unit z-depth.
    """
    h = 3.0
    alpha = np.radians(alpha_deg)
    position = np.array([0.0, 0.0, h])
    target = np.array([h / np.tan(alpha), 0.0, 0.0])
    cam = camera_at(position, look_at_rotation(position, target))
    depth = render_depth(cam, [], floor_z=0.0).astype(np.float64)
    _, vv = pixel_grid(INTRINSICS)
    b = (vv - INTRINSICS.cy) / INTRINSICS.fy
    descent = np.sin(alpha) + b * np.cos(alpha)
    expected = np.where(descent > 0, h / np.where(descent > 0, descent, 1.0), np.inf)
    finite = np.isfinite(expected)
    np.testing.assert_array_equal(np.isfinite(depth), finite)
    np.testing.assert_allclose(depth[finite], expected[finite], rtol=1e-5)


def test_sky_is_inf():
    position = np.array([0.0, 0.0, 1.0])
    up = camera_at(position, look_at_rotation(position, [1.0, 0.0, 3.0]))
    assert np.all(np.isposinf(render_depth(up, [], floor_z=0.0)))
    horizontal = camera_at(position, look_at_rotation(position, [1.0, 0.0, 1.0]))
    depth = render_depth(horizontal, [], floor_z=0.0)
    # rows above the principal point look up (sky), rows below hit the floor at 1 / b
    _, vv = pixel_grid(INTRINSICS)
    b = (vv - INTRINSICS.cy) / INTRINSICS.fy
    assert np.all(np.isposinf(depth[b <= 0]))
    np.testing.assert_allclose(depth[b > 0], 1.0 / b[b > 0], rtol=1e-5)
    assert np.all(np.isposinf(render_depth(horizontal, [], floor_z=None)))


def test_box_top_face_from_above():
    cam = looking_down(3.0)
    top = 1.2
    depth = render_depth(cam, [box((0.2, -0.1, top / 2), (0.8, 0.6, top))], floor_z=0.0)
    uu, vv = pixel_grid(INTRINSICS)
    # ray of pixel (u, v) reaches world x = (u - cx) / fx * d, y = -(v - cy) / fy * d
    d_top = 3.0 - top
    x = (uu - INTRINSICS.cx) / INTRINSICS.fx * d_top
    y = -(vv - INTRINSICS.cy) / INTRINSICS.fy * d_top
    on_top = (np.abs(x - 0.2) < 0.4 - 1e-3) & (np.abs(y + 0.1) < 0.3 - 1e-3)
    assert on_top.sum() > 50
    np.testing.assert_allclose(depth[on_top], d_top, atol=1e-6)
    # pixels whose floor point is outside the box footprint see the floor
    xf = (uu - INTRINSICS.cx) / INTRINSICS.fx * 3.0
    yf = -(vv - INTRINSICS.cy) / INTRINSICS.fy * 3.0
    floor = (np.abs(xf - 0.2) > 0.4 + 1e-3) | (np.abs(yf + 0.1) > 0.3 + 1e-3)
    floor &= (np.abs(x - 0.2) > 0.4 + 1e-3) | (np.abs(y + 0.1) > 0.3 + 1e-3)
    np.testing.assert_allclose(depth[floor], 3.0, atol=1e-6)


def test_fronto_parallel_box_face_is_constant_z_depth_not_ray_length():
    position = np.array([0.0, 0.0, 1.0])
    cam = camera_at(position, look_at_rotation(position, [1.0, 0.0, 1.0]))
    wall = box((2.5, 0.0, 1.0), (1.0, 20.0, 20.0))  # front face at x = 2
    depth = render_depth(cam, [wall], floor_z=None)
    np.testing.assert_allclose(depth, 2.0, atol=1e-6)


def test_obstacle_in_front_of_floor_wins_and_behind_camera_is_ignored():
    cam = looking_down(3.0)
    above_camera = box((0.0, 0.0, 4.0), (10.0, 10.0, 0.5))
    depth = render_depth(cam, [above_camera], floor_z=0.0)
    np.testing.assert_allclose(depth, 3.0, atol=1e-6)
    # camera inside a box: it sees the far (inner) side of the box faces
    around = box((0.0, 0.0, 3.0), (1.0, 1.0, 1.0))
    depth = render_depth(cam, [around], floor_z=0.0)
    assert np.all(depth <= 0.5 + 1e-6)


def test_step_subsamples_pixel_centres():
    position = np.array([0.3, -0.2, 2.0])
    cam = camera_at(position, look_at_rotation(position, [2.0, 1.0, 0.0]))
    meshes = [box((1.5, 0.5, 0.3), (0.5, 0.4, 0.6)), trimesh.creation.icosphere(2, 0.3)]
    full = render_depth(cam, meshes, floor_z=0.0)
    sub = render_depth(cam, meshes, floor_z=0.0, step=3)
    assert sub.shape == (16, 22)
    np.testing.assert_array_equal(sub, full[::3, ::3])


def _oracle_depth(cam, meshes):
    """z-depth from trimesh's pure-numpy intersector, computed from hit locations."""
    mesh = trimesh.util.concatenate(meshes)
    rays = cam.pixel_rays() @ cam.T_world_camera[:3, :3].T
    directions = rays.reshape(-1, 3)
    origins = np.broadcast_to(cam.center, directions.shape)
    locations, index_ray, _ = ray_triangle.RayMeshIntersector(mesh).intersects_location(
        origins, directions, multiple_hits=True
    )
    depth = np.full(len(directions), np.inf)
    z = (locations - cam.center) @ cam.T_world_camera[:3, 2]
    np.minimum.at(depth, index_ray, z)
    return depth.reshape(rays.shape[:2])


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    target=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0, 1)),
)
def test_meshes_match_independent_intersector(seed, target):
    rng = np.random.default_rng(seed)
    meshes = []
    for _ in range(3):
        mesh = trimesh.creation.box(extents=rng.uniform(0.1, 0.8, 3))
        mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        mesh.apply_translation(rng.uniform(-1.0, 1.0, 3) * [1, 1, 0.5] + [0, 0, 0.5])
        meshes.append(mesh)
    position = np.array([2.5, 1.5, 2.0])
    small = Intrinsics(width=24, height=18, fx=20.0, fy=20.0, cx=11.5, cy=8.5)
    cam = camera_at(position, look_at_rotation(position, target), small)
    got = MeshCaster(meshes).depth(cam).astype(np.float64)
    want = _oracle_depth(cam, meshes)
    hit_both = np.isfinite(got) & np.isfinite(want)
    # rays grazing an edge may be decided differently by the two intersectors
    agree = np.isfinite(got) == np.isfinite(want)
    assert agree.mean() > 0.97
    close = np.abs(got[hit_both] - want[hit_both]) < 1e-5
    assert close.mean() > 0.97


def test_culling_handles_meshes_partly_behind_the_camera():
    cam = looking_down(1.0)
    slab = box((0.0, 0.0, 0.8), (0.4, 0.4, 1.0))  # from z = 0.3 to 1.3, around the camera
    got = MeshCaster([slab]).depth(cam).astype(np.float64)
    # from inside, the ray (a, b, 1) leaves through the bottom (z-depth 0.7) or a side wall
    uu, vv = pixel_grid(INTRINSICS)
    a = np.abs(uu - INTRINSICS.cx) / INTRINSICS.fx
    b = np.abs(vv - INTRINSICS.cy) / INTRINSICS.fy
    expected = np.minimum(0.7, np.minimum(0.2 / a, 0.2 / b))
    assert np.any(expected == 0.7)
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_first_hit_parameter_scales_with_direction_length():
    caster = MeshCaster([box((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))])
    origins = np.array([[-3.0, 0.0, 0.0], [-3.0, 0.0, 0.0], [-3.0, 0.0, 0.0]])
    directions = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    t = caster.first_hit(origins, directions)
    np.testing.assert_allclose(t[:2], [2.5, 1.25], atol=1e-9)
    assert np.isposinf(t[2])


def test_empty_scene_and_bad_input():
    cam = looking_down(2.0)
    assert np.all(np.isposinf(MeshCaster([]).depth(cam)))
    assert np.all(np.isposinf(render_depth(cam, [trimesh.Trimesh()], floor_z=None)))
    with pytest.raises(GeometryError, match=r"meshes\[0\]"):
        MeshCaster(["not a mesh"])  # type: ignore[list-item]
    bad = box((0, 0, 0), (1, 1, 1))
    bad.vertices[0] = np.nan
    with pytest.raises(GeometryError, match="non-finite"):
        MeshCaster([bad])
    with pytest.raises(GeometryError, match="step"):
        render_depth(cam, [], floor_z=0.0, step=0)
    with pytest.raises(GeometryError, match="floor_z"):
        StaticScene([], floor_z=float("nan"))


def test_static_scene_combines_static_and_dynamic_meshes():
    cam = looking_down(3.0)
    scene = StaticScene([box((0.0, 0.0, 0.25), (4.0, 4.0, 0.5))], floor_z=0.0)
    static = scene.render(cam)
    np.testing.assert_allclose(static, 2.5, atol=1e-6)
    person_like = box((0.0, 0.0, 1.0), (0.2, 0.2, 2.0))
    combined = scene.render(cam, [person_like])
    assert np.isclose(combined.min(), 1.0, atol=1e-6)
    assert np.all(combined <= static)
    reused = scene.render(cam, MeshCaster([person_like]))
    np.testing.assert_array_equal(reused, combined)


def test_render_reference_is_floor_and_obstacles_only():
    cams = (
        looking_down(3.0),
        camera_at((3.0, 0.0, 2.0), look_at_rotation((3.0, 0.0, 2.0), (0.0, 0.0, 0.5)), name="side"),
    )
    cell = Cell(
        name="test",
        zone=Zone(min=(-2.0, -2.0, 0.0), max=(4.0, 2.0, 3.0)),
        cameras=cams,
        obstacles=(Obstacle.box("table", (0.0, 0.0, 0.4), (1.0, 0.6, 0.8)),),
    )
    reference = render_reference(cell)
    assert set(reference) == {"cam", "side"}
    assert reference["cam"].shape == (48, 64)
    assert np.isclose(reference["cam"].min(), 2.2, atol=1e-6)  # table top at 0.8
    assert np.isclose(reference["cam"].max(), 3.0, atol=1e-6)  # floor
    np.testing.assert_array_equal(
        reference["side"], render_depth(cams[1], [cell.obstacles[0].mesh], floor_z=0.0)
    )
