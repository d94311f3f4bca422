"""Voxel labels and objectives f1 to f4 of the placement simulation (paper section 4)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from polyhull.camera import Camera, Intrinsics
from polyhull.cell import Zone
from polyhull.errors import GeometryError, PolyhullError
from polyhull.placement.labels import (
    Label,
    VoxelGrid,
    boundary_mask,
    free_depth_image,
    fuse_labels,
    label_voxels,
    mesh_mask,
    project_grid,
)
from polyhull.placement.objectives import (
    Importance,
    ImportanceRegion,
    MeshArrays,
    ObjectiveParams,
    PlacementProblem,
    evaluate_cameras,
    label_scene,
    prepare,
)
from polyhull.placement.optimizer import pan_tilt_rotation
from polyhull.raycast import render_depth

# The hand-computable scene: a 4 m x 4 m x 2.5 m zone, one camera 4 m above the floor
# looking straight down. With 64 x 48 px and f = 80 px its frustum at the floor is
# 3.2 m x 2.4 m, inside the zone, so the free region is a truncated pyramid.
ZONE = Zone((0.0, 0.0, 0.0), (4.0, 4.0, 2.5))
W, H, F = 64, 48, 80.0
TAU = 0.01  # noise 0: the tolerance is tolerance_min
GRID = VoxelGrid(ZONE.min, ZONE.max, (80, 80, 50))  # 5 cm voxels


def down_camera(
    kind: str = "depth", name: str = "down", position=(2.0, 2.0, 4.0), far: float = 8.0
) -> Camera:
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    T[:3, 3] = position
    return Camera(
        name, kind, Intrinsics(W, H, F, F, (W - 1) / 2, (H - 1) / 2), T,
        near=0.3, far=far, noise=0.0, tolerance_min=TAU,
    )


def pyramid(d0: float, d1: float, area_per_depth2: float) -> float:
    """Volume [m^3] of a pyramid section between z-depths d0 and d1 [m]."""
    return area_per_depth2 * (d1**3 - d0**3) / 3.0


FRUSTUM = W * H / F**2  # image area per depth^2
# A box centred under the camera whose top face (0.6 m x 0.45 m at 1 m height, depth 3 m)
# covers exactly 16 x 12 pixels: its cone is a union of whole pixel pyramids.
TOP = 1.0
BOX = trimesh.creation.box(extents=[0.6, 0.45, TOP]).apply_translation([2.0, 2.0, TOP / 2])
FACE = 0.6 * 0.45 / (4.0 - TOP) ** 2


def problem(static=(), targets=(), params=None, grid=GRID) -> PlacementProblem:
    return PlacementProblem(
        grid=grid,
        floor_z=0.0,
        static_meshes=tuple(MeshArrays.of(m) for m in static),
        target_scenes=((tuple(MeshArrays.of(m) for m in targets),) if targets else ()),
        params=params or ObjectiveParams(w1=1.0, w2=2.0, k=2),
    )


def error_bound(prob: PlacementProblem, cameras, label: Label, k: int = 1) -> float:
    """Bound [m^3] of the voxel discretisation error of one label's volume.

    Only voxels cut by the label's boundary err, each by at most its volume, the ones
    inside the label by over-counting and the ones outside by under-counting, so the
    error is at most the larger of the two counts of boundary voxels (boundary_mask).
    """
    inside = label_scene(prob, cameras, k=k) == label
    edge = boundary_mask(inside, prob.grid.shape)
    n = max(np.count_nonzero(edge & inside), np.count_nonzero(edge & ~inside))
    return float(n) * prob.grid.voxel_volume


def test_empty_box_one_camera_matches_the_pyramid():
    cam = down_camera()
    prob = problem()
    obj = evaluate_cameras(prob, [cam])
    free = pyramid(4.0 - 2.5, 4.0 - TAU, FRUSTUM)
    bound = error_bound(prob, [cam], Label.FREE)
    assert 0 < bound < 0.15 * free  # the bound is informative
    assert obj.free == pytest.approx(free, abs=bound)
    assert obj.f1 == pytest.approx(ZONE.volume - free, abs=bound)
    assert obj.changed == 0.0
    assert obj.f2 == pytest.approx(obj.f1)
    assert obj.f3 == pytest.approx(2.0 * obj.f1)
    # One camera and k = 2: nothing is free under the k-of-n rule.
    assert obj.free_k == 0.0
    assert obj.f4 == pytest.approx(2.0 * ZONE.volume)
    assert obj.free + obj.changed + obj.undetectable == pytest.approx(ZONE.volume)
    # Golden value at this grid (voxel centres on 5 cm layers).
    assert obj.f1 == pytest.approx(30.2975, abs=1e-9)


def test_target_under_the_camera_changed_cone():
    cam = down_camera()
    prob = problem(targets=[BOX])
    obj = evaluate_cameras(prob, [cam])
    d_top = 4.0 - TOP
    changed = pyramid(d_top - TAU, 4.0, FACE)
    free = pyramid(1.5, 4.0 - TAU, FRUSTUM) - pyramid(d_top - TAU, 4.0 - TAU, FACE)
    b_changed = error_bound(prob, [cam], Label.CHANGED)
    b_free = error_bound(prob, [cam], Label.FREE)
    assert obj.changed == pytest.approx(changed, abs=b_changed)
    assert obj.free == pytest.approx(free, abs=b_free)
    undetectable = ZONE.volume - free - changed
    assert obj.f3 == pytest.approx(changed + 2.0 * undetectable, abs=b_changed + 2.0 * (b_free + b_changed))
    # The target's inside is changed: f3 is above its optimum.
    assert obj.f3 >= prepare(prob).optimum.f3


def test_color_camera_frees_nothing_along_changed_pixels():
    depth, color = down_camera("depth"), down_camera("color")
    prob = problem(targets=[BOX])
    o_depth = evaluate_cameras(prob, [depth])
    o_color = evaluate_cameras(prob, [color])
    cone_above = pyramid(1.5, 4.0 - TOP - TAU, FACE)  # free for depth, changed for colour
    b_free = error_bound(prob, [color], Label.FREE) + error_bound(prob, [depth], Label.FREE)
    b_changed = error_bound(prob, [color], Label.CHANGED)
    b_und = error_bound(prob, [color], Label.UNDETECTABLE) + error_bound(prob, [depth], Label.UNDETECTABLE)
    assert o_color.free == pytest.approx(o_depth.free - cone_above, abs=b_free)
    assert o_color.changed == pytest.approx(pyramid(1.5, 4.0, FACE), abs=b_changed)
    assert o_color.undetectable == pytest.approx(o_depth.undetectable, abs=b_und)


def test_static_obstacle_is_undetectable_and_f1_opt_is_its_volume():
    cam = down_camera()
    prob = problem(static=[BOX])
    obj = evaluate_cameras(prob, [cam])
    opt = prepare(prob).optimum
    # x and z faces lie on voxel faces; the y faces (1.775, 2.225) pass through voxel
    # centres, which the closed box contains: 12 x 10 x 20 voxels.
    assert opt.f1 == pytest.approx(0.6 * 0.5 * 1.0, rel=1e-9)
    free = pyramid(1.5, 4.0 - TAU, FRUSTUM) - pyramid(4.0 - TOP - TAU, 4.0 - TAU, FACE)
    assert obj.free == pytest.approx(free, abs=error_bound(prob, [cam], Label.FREE))
    assert obj.changed == 0.0
    labels = label_scene(prob, [cam])
    assert np.all(labels[prepare(prob).static_mask] == Label.UNDETECTABLE)


def test_k_of_n_with_two_identical_cameras_equals_one_camera():
    a, b = down_camera(name="a"), down_camera(name="b")
    prob = problem(targets=[BOX], params=ObjectiveParams(k=2))
    one = evaluate_cameras(prob, [a])
    two = evaluate_cameras(prob, [a, b])
    assert two.free_k == pytest.approx(one.free)
    assert two.changed_k == pytest.approx(one.changed)
    assert two.f4 == pytest.approx(one.f3)
    three = evaluate_cameras(problem(targets=[BOX], params=ObjectiveParams(k=3)), [a, b])
    assert three.free_k == 0.0


def test_f_opt_is_reached_by_a_camera_that_sees_all_of_an_empty_zone():
    # High above the zone (floor within range), its frustum holds all of Z.
    cam = down_camera(position=(2.0, 2.0, 10.0), far=12.0)
    prob = problem()
    obj = evaluate_cameras(prob, [cam])
    assert obj.f1 == 0.0 == prepare(prob).optimum.f1
    assert obj.free == pytest.approx(ZONE.volume)


def test_importance_regions_weight_f2():
    cam = down_camera()
    region = ImportanceRegion(lo=(0.0, 0.0, 0.0), hi=(4.0, 4.0, 1.0), weight=5.0)
    prob = problem(params=ObjectiveParams(importance=Importance(regions=(region,), default=0.0)))
    obj = evaluate_cameras(prob, [cam])
    labels = label_scene(prob, [cam])
    low = GRID.centers()[:, 2] <= 1.0
    expected = 5.0 * np.count_nonzero((labels == Label.UNDETECTABLE) & low) * GRID.voxel_volume
    assert obj.f2 == pytest.approx(expected)
    assert 0 < obj.f2 < 5.0 * obj.f1
    field = np.full(GRID.shape, 3.0)
    obj_field = evaluate_cameras(problem(params=ObjectiveParams(importance=Importance(field=field))), [cam])
    assert obj_field.f2 == pytest.approx(3.0 * obj_field.f1)
    with pytest.raises(PolyhullError, match="grid shape"):
        Importance(field=np.ones((2, 2, 2))).weights(GRID)


def test_label_voxels_from_rendered_images_matches_the_problem_path():
    cam = down_camera()
    B = render_depth(cam, [], 0.0)
    D = render_depth(cam, [BOX], 0.0)
    static = mesh_mask(GRID, [])
    target = mesh_mask(GRID, [BOX])
    direct = label_voxels([cam], GRID, [B], [D], k=1, static_mask=static, target_mask=target)
    assert np.array_equal(direct, label_scene(problem(targets=[BOX]), [cam]))
    with pytest.raises(GeometryError, match="one reference"):
        label_voxels([cam], GRID, [B], [], k=1)


def test_free_depth_image_semantics():
    cam = down_camera()
    B = np.array([[4.0, 4.0, np.inf]], dtype=np.float32)
    D = np.array([[4.0, 3.0, 2.0]], dtype=np.float32)
    small = Camera("s", "depth", Intrinsics(3, 1, 10, 10, 1, 0), cam.T_world_camera,
                   near=0.3, far=8.0, noise=0.0, tolerance_min=TAU)
    f, ch = free_depth_image(small, B, D)
    assert ch[0].tolist() == [False, True, True]
    assert f[0].tolist() == pytest.approx([4.0 - TAU, 3.0 - TAU, 2.0 - TAU])
    color = Camera("c", "color", small.intrinsics, cam.T_world_camera,
                   near=0.3, far=8.0, noise=0.0, tolerance_min=TAU)
    f, ch = free_depth_image(color, B, D)
    assert ch[0].tolist() == [False, True, True]
    assert f[0].tolist() == pytest.approx([4.0 - TAU, 0.3, 0.3])  # near: nothing free
    # A background beyond the range reads "no return": free up to far - tau(far); a
    # target within range in front of it is a change.
    short = Camera("r", "depth", small.intrinsics, cam.T_world_camera,
                   near=0.3, far=5.0, noise=0.0, tolerance_min=TAU)
    B = np.array([[9.0, 9.0, 9.0]], dtype=np.float32)
    D = np.array([[9.0, 4.0, 6.0]], dtype=np.float32)
    f, ch = free_depth_image(short, B, D)
    assert ch[0].tolist() == [False, True, False]
    assert f[0].tolist() == pytest.approx([5.0 - TAU, 4.0 - TAU, 5.0 - TAU])


def test_fuse_labels_rules():
    count = np.array([0, 0, 1, 2, 2, 0])
    changed = np.array([False, True, True, False, True, True])
    static = np.array([False, False, False, False, False, True])
    target = np.array([False, False, False, False, True, False])
    lab = fuse_labels(count, changed, 1, static, target)
    assert lab.tolist() == [2, 1, 0, 0, 1, 2]
    lab2 = fuse_labels(count, changed, 2, static, target)
    assert lab2.tolist() == [2, 1, 1, 0, 1, 2]
    with pytest.raises(GeometryError):
        fuse_labels(count, changed, 0)


def test_mesh_mask_box_and_general_mesh_agree_with_containment():
    grid = VoxelGrid((0.0, 0.0, 0.0), (2.0, 2.0, 2.0), (20, 20, 20))
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.6).apply_translation([1.0, 1.0, 1.0])
    mask = mesh_mask(grid, [sphere])
    centers = grid.centers()
    assert np.array_equal(mask, sphere.contains(centers))
    box = trimesh.creation.box(extents=[0.5, 0.5, 0.5]).apply_translation([0.25, 0.25, 0.25])
    assert np.count_nonzero(mesh_mask(grid, [box])) == 125
    open_mesh = trimesh.Trimesh(sphere.vertices, sphere.faces[:-4])
    with pytest.raises(GeometryError, match="watertight"):
        mesh_mask(grid, [open_mesh])


def test_boundary_mask_marks_both_sides_of_a_plane():
    labels = np.zeros((4, 3, 3), dtype=np.int8)
    labels[2:] = 1
    mask = boundary_mask(labels.ravel(), (4, 3, 3)).reshape(4, 3, 3)
    assert mask[1:3].all() and not mask[0].any() and not mask[3].any()


def test_voxel_grid_validation_and_centres():
    grid = VoxelGrid((0.0, 0.0, 0.0), (1.0, 2.0, 3.0), (2, 4, 6))
    assert grid.voxel_volume == pytest.approx(0.125)
    assert grid.centers()[0].tolist() == pytest.approx([0.25, 0.25, 0.25])
    assert grid.centers()[-1].tolist() == pytest.approx([0.75, 1.75, 2.75])
    with pytest.raises(GeometryError, match="shape"):
        VoxelGrid((0, 0, 0), (1, 1, 1), (0, 1, 1))
    with pytest.raises(GeometryError, match="exceed"):
        VoxelGrid((0, 0, 0), (1, 0, 1), (1, 1, 1))


# -- properties ------------------------------------------------------------------------

SMALL_ZONE = Zone((0.0, 0.0, 0.0), (3.0, 3.0, 2.0))
SMALL_GRID = VoxelGrid(SMALL_ZONE.min, SMALL_ZONE.max, (18, 18, 12))
OBSTACLE = trimesh.creation.box(extents=[0.6, 0.6, 0.8]).apply_translation([2.0, 1.0, 0.4])
TARGET = trimesh.creation.box(extents=[0.4, 0.4, 1.6]).apply_translation([1.0, 2.0, 0.8])
SMALL_PROBLEM = PlacementProblem(
    grid=SMALL_GRID,
    floor_z=0.0,
    static_meshes=(MeshArrays.of(OBSTACLE),),
    target_scenes=((MeshArrays.of(TARGET),),),
    params=ObjectiveParams(w1=1.0, w2=3.0, k=2),
)

positions = st.tuples(
    st.floats(0.1, 2.9), st.floats(0.1, 2.9), st.floats(1.0, 2.4)
)
# Optical axis as (pan, tilt below the horizontal) [rad]; straight down included.
look_ats = st.tuples(st.floats(-np.pi, np.pi), st.floats(0.0, np.pi / 2))


def small_camera(name, kind, position, pan_tilt) -> Camera:
    T = np.eye(4)
    T[:3, :3] = pan_tilt_rotation(*pan_tilt)
    T[:3, 3] = position
    return Camera(name, kind, Intrinsics(40, 30, 30.0, 30.0, 19.5, 14.5), T, near=0.2, far=6.0)


cameras_st = st.lists(
    st.tuples(st.sampled_from(["depth", "color"]), positions, look_ats), min_size=1, max_size=3
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cameras_st, st.tuples(st.sampled_from(["depth", "color"]), positions, look_ats))
def test_objective_invariants(specs, extra):
    cams = [small_camera(f"c{i}", *s) for i, s in enumerate(specs)]
    more = [*cams, small_camera("extra", *extra)]
    opt = prepare(SMALL_PROBLEM).optimum
    a = evaluate_cameras(SMALL_PROBLEM, cams)
    b = evaluate_cameras(SMALL_PROBLEM, more)
    for o in (a, b):
        # The three sections partition Z, under both rules.
        assert o.free + o.changed + o.undetectable == pytest.approx(SMALL_ZONE.volume)
        assert o.free_k + o.changed_k + o.undetectable_k == pytest.approx(SMALL_ZONE.volume)
        # The optimal values are lower bounds; the k-of-n rule frees less.
        for name in ("f1", "f2", "f3", "f4"):
            assert o[name] >= opt[name] - 1e-9
        assert o.free_k <= o.free + 1e-12
        assert o.f4 >= o.f3 - 1e-9
    # Another camera never makes a voxel undetectable nor takes a free one away.
    assert b.f1 <= a.f1 + 1e-12
    assert b.free >= a.free - 1e-12
    assert b.free_k >= a.free_k - 1e-12


@settings(max_examples=25, deadline=None)
@given(positions, look_ats, st.sampled_from([1, 2, 3]))
def test_project_grid_matches_camera_project(position, look_at, step):
    cam = small_camera("p", "depth", position, look_at)
    proj = project_grid(cam, SMALL_GRID, step)
    uv, z = cam.project(SMALL_GRID.centers())
    k = cam.intrinsics
    inside = (
        (z >= cam.near) & (z <= cam.far)
        & (uv[:, 0] >= -0.5) & (uv[:, 0] < k.width - 0.5)
        & (uv[:, 1] >= -0.5) & (uv[:, 1] < k.height - 0.5)
    )
    sub_w = -(-k.width // step)
    sub_h = -(-k.height // step)
    iu = np.minimum(np.floor(uv[:, 0] / step + 0.5), sub_w - 1)
    iv = np.minimum(np.floor(uv[:, 1] / step + 0.5), sub_h - 1)
    expected = np.where(inside, iv * sub_w + iu, -1)
    # float32 in the fast path: ignore centres within 1e-3 px of a pixel edge.
    frac_u = np.abs((uv[:, 0] / step + 0.5) - np.round(uv[:, 0] / step + 0.5))
    frac_v = np.abs((uv[:, 1] / step + 0.5) - np.round(uv[:, 1] / step + 0.5))
    edge_u = np.abs(uv[:, 0] + 0.5) % 1
    sure = (frac_u > 1e-3) & (frac_v > 1e-3) & (np.minimum(edge_u, 1 - edge_u) > 1e-3)
    sure &= np.abs(z - cam.near) > 1e-4
    assert np.array_equal(proj.pixel[sure], expected[sure].astype(np.int64))
    assert np.allclose(proj.depth, z, atol=1e-4)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.tuples(st.floats(0.3, 2.7), st.floats(0.3, 2.7), st.floats(0.2, 1.95)),
    look_ats,
    st.sampled_from(["depth", "color"]),
)
def test_fast_path_matches_full_renders(position, pan_tilt, kind):
    # The evaluation renders targets only over the image rectangle of their bounding box
    # (clipped to the camera's range); it must label exactly as full renders do, also for
    # cameras next to or above the target, or with the target partly behind them.
    cam = small_camera("c", kind, position, pan_tilt)
    B = render_depth(cam, [OBSTACLE], 0.0)
    D = render_depth(cam, [OBSTACLE, TARGET], 0.0)
    prep = prepare(SMALL_PROBLEM)
    direct = label_voxels(
        [cam], SMALL_GRID, [B], [D], k=1,
        static_mask=prep.static_mask, target_mask=prep.target_masks[0],
    )
    assert np.array_equal(label_scene(SMALL_PROBLEM, [cam]), direct)


@settings(max_examples=60, deadline=None)
@given(
    st.tuples(st.floats(0.3, 2.7), st.floats(0.3, 2.7), st.floats(0.2, 1.95)),
    st.tuples(st.floats(-np.pi, np.pi), st.floats(-0.5, np.pi / 2)),
    st.sampled_from([1, 2]),
)
def test_windowed_renders_equal_full_renders(position, pan_tilt, step):
    # Targets are traced only over the image window of their bounding box (cut to the
    # part in front of the camera), and the reference one static mesh at a time over its
    # own window, on an analytic floor: both must equal full renders, pixel for pixel.
    from polyhull.placement.objectives import _render_reference, _render_window
    from polyhull.raycast import MeshCaster

    lo, hi = TARGET.bounds
    # A camera inside the target sees nothing of the cell (the full render reads 0 there):
    # not a placement the optimiser can make (cameras hang on the mounting surfaces).
    assume(not np.all((np.asarray(position) > lo - 0.1) & (np.asarray(position) < hi + 0.1)))
    cam = small_camera("c", "depth", position, pan_tilt)
    caster = MeshCaster([TARGET])
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    full = caster.depth(cam, step)
    window = _render_window(cam, caster, corners, step, full.shape)
    fast = np.full(full.shape, np.inf, dtype=np.float32)
    if window is not None:
        (rows, cols), depth = window
        fast[rows, cols] = depth
    assert np.allclose(fast, full, rtol=1e-6)  # inf == inf where nothing is hit
    reference = _render_reference(prepare(SMALL_PROBLEM), cam, step)
    assert np.allclose(reference, render_depth(cam, [OBSTACLE], 0.0, step), rtol=1e-6)
