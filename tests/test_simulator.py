"""The depth simulator: seeded, switchable sensor effects doing what they say."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from polyhull.camera import Camera, Intrinsics, look_at_rotation
from polyhull.cell import Cell, Obstacle, RobotSpec, Zone
from polyhull.errors import PolyhullError, RobotError
from polyhull.frames import DepthFrame
from polyhull.raycast import render_depth
from polyhull.simulator import SensorEffects, Simulator, apply_sensor_effects

INTRINSICS = Intrinsics(width=160, height=120, fx=120.0, fy=120.0, cx=79.5, cy=59.5)


def camera(name, position, target=None, *, kind="depth", near=0.3, far=8.0, noise=0.003):
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) if target is None else look_at_rotation(position, target)
    T[:3, 3] = position
    return Camera(
        name=name, kind=kind, intrinsics=INTRINSICS, T_world_camera=T, near=near, far=far, noise=noise
    )


class BoxArm:
    """A stand-in robot: a vertical post whose top swings along +x with q[0] [m]."""

    def mesh(self, q):
        post = trimesh.creation.box(extents=(0.2, 0.2, 1.0))
        post.apply_translation((float(q[0]), 0.0, 0.5))
        return post


def make_cell(cameras=None, robot=True, obstacles=None):
    cameras = cameras or (camera("top", (0.0, 0.0, 3.0)), camera("side", (3.0, 0.5, 2.0), (0.0, 0.0, 0.5)))
    return Cell(
        name="sim test",
        zone=Zone(min=(-2.0, -2.0, 0.0), max=(3.5, 2.0, 3.2)),
        cameras=tuple(cameras),
        obstacles=(Obstacle.box("table", (-1.2, 1.0, 0.4), (0.8, 0.6, 0.8)),) if obstacles is None else obstacles,
        robot=RobotSpec(urdf="none.urdf", q=(0.3,)) if robot else None,  # type: ignore[arg-type]
    )


def simulator(cell=None, **kwargs):
    cell = cell or make_cell()
    return Simulator(cell, robot=BoxArm() if cell.robot is not None else None, **kwargs)


def person_box(x=1.0, y=-0.8):
    target = trimesh.creation.box(extents=(0.4, 0.3, 1.7))
    target.apply_translation((x, y, 0.85))
    return target


def test_exact_render_is_first_hit_of_floor_obstacles_robot_and_targets():
    sim = simulator()
    frames = sim.render(q=[0.3], targets=[person_box()], effects=SensorEffects.none())
    assert set(frames) == {"top", "side"}
    for cam in sim.cell.cameras:
        frame = frames[cam.name]
        assert isinstance(frame, DepthFrame)
        assert frame.shape == (120, 160)
        meshes = [sim.cell.obstacles[0].mesh, BoxArm().mesh([0.3]), person_box()]
        expected = render_depth(cam, meshes, floor_z=0.0)
        np.testing.assert_array_equal(frame.depth, expected)
    top = frames["top"].depth
    assert np.sum(np.isclose(top, 2.0, atol=1e-6)) > 50  # top of the 1 m post seen from 3 m
    assert top.min() < 2.0  # the side of the 1.7 m person, near the image corner
    assert np.isclose(top.max(), 3.0, atol=1e-6)


def test_reference_has_no_robot_and_no_targets_and_is_cached():
    sim = simulator()
    reference = sim.reference()
    top = reference["top"]
    assert not top.flags.writeable
    expected = render_depth(sim.cell.cameras[0], [sim.cell.obstacles[0].mesh], floor_z=0.0)
    np.testing.assert_array_equal(top, expected)
    assert sim.reference()["top"] is top
    # the robot moves in the frames, never in the reference
    a = sim.render_exact(q=[0.0])["top"]
    b = sim.render_exact(q=[0.8])["top"]
    assert not np.array_equal(a, b)
    assert np.all(a <= top) and np.all(b <= top)


def test_default_q_comes_from_the_cell():
    sim = simulator()
    np.testing.assert_array_equal(sim.render_exact()["top"], sim.render_exact(q=[0.3])["top"])


def test_same_seed_same_frames_different_seed_different_frames():
    sim = simulator()
    a = sim.render(targets=[person_box()], seed=7, stamp=1.5)
    b = sim.render(targets=[person_box()], seed=7, stamp=1.5)
    c = sim.render(targets=[person_box()], seed=8, stamp=1.5)
    for name in a:
        np.testing.assert_array_equal(a[name].depth, b[name].depth)
        assert not np.array_equal(a[name].depth, c[name].depth)
        assert a[name].stamp == 1.5
    # every camera has its own random streams
    twins = make_cell(cameras=(camera("a", (0.0, 0.0, 3.0)), camera("b", (0.0, 0.0, 3.0))), robot=False)
    frames = simulator(twins).render(seed=1)
    assert not np.array_equal(frames["a"].depth, frames["b"].depth)


def test_noise_std_grows_with_depth_squared():
    sigma_1m = 0.01
    cell = make_cell(cameras=(camera("top", (0.0, 0.0, 2.0), noise=sigma_1m),), robot=False, obstacles=())
    sim = simulator(cell)
    only_noise = SensorEffects(noise=True, dropout=0.0, out_of_range=False, flying_pixels=False)
    depth = sim.render(seed=3, effects=only_noise)["top"].depth.astype(np.float64)
    error = depth - 2.0
    expected = sigma_1m * 2.0**2
    assert abs(error.std() - expected) < 0.1 * expected
    assert abs(error.mean()) < 3 * expected / np.sqrt(error.size)


def test_noise_and_dropout_switch_independently():
    sim = simulator()
    base = SensorEffects(noise=False, dropout=0.1, dropout_cluster=1, out_of_range=False, flying_pixels=False)
    dropped = sim.render(seed=5, effects=base)["top"].depth
    with_noise = sim.render(
        seed=5,
        effects=SensorEffects(noise=True, dropout=0.1, dropout_cluster=1, out_of_range=False, flying_pixels=False),
    )
    # the same pixels drop out whether or not noise is on
    np.testing.assert_array_equal(dropped == 0, with_noise["top"].depth == 0)
    share = np.mean(dropped == 0)
    n = dropped.size
    assert abs(share - 0.1) < 4 * np.sqrt(0.1 * 0.9 / n)
    exact = sim.render(seed=5, effects=SensorEffects.none())["top"].depth
    kept = dropped != 0
    np.testing.assert_array_equal(dropped[kept], exact[kept])


def test_dropouts_come_in_patches():
    sim = simulator()
    effects = SensorEffects(noise=False, dropout=0.05, dropout_cluster=4, out_of_range=False, flying_pixels=False)
    dropped = sim.render(seed=2, effects=effects)["top"].depth == 0
    # Patches overlap a little: the share lies a bit under the nominal one.
    assert 0.03 < dropped.mean() <= 0.055
    # Every dropped pixel lies in a fully dropped 4 x 4 patch (no isolated pixels); patches
    # cut by the image border count as full (outside is padded as dropped).
    from numpy.lib.stride_tricks import sliding_window_view

    dropped = np.pad(dropped, 3, constant_values=True)
    full = sliding_window_view(dropped, (4, 4)).all(axis=(2, 3))
    covered = np.zeros_like(dropped)
    for dv in range(4):
        for du in range(4):
            covered[dv : dv + full.shape[0], du : du + full.shape[1]] |= full
    isolated = (dropped & ~covered)[3:-3, 3:-3]  # the image itself, not its padding
    assert not isolated.any()
    with pytest.raises(PolyhullError, match="dropout_cluster"):
        SensorEffects(dropout_cluster=0)


def test_out_of_range_is_reported_as_zero():
    cams = (
        camera("far", (0.0, 0.0, 2.5), far=2.0),
        camera("near", (0.0, 0.0, 1.1), near=0.3),
        camera("sky", (2.0, 0.0, 1.0), (3.0, 0.0, 3.0)),
    )
    cell = make_cell(cameras=cams, robot=False, obstacles=(Obstacle.box("post", (0.0, 0.0, 0.5), (0.3, 0.3, 1.0)),))
    sim = simulator(cell)
    on = SensorEffects(noise=False, dropout=0.0, out_of_range=True, flying_pixels=False)
    off = SensorEffects(noise=False, dropout=0.0, out_of_range=False, flying_pixels=False)
    frames = sim.render(effects=on)
    exact = sim.render(effects=off)
    far_exact = exact["far"].depth
    beyond = far_exact > 2.0  # the floor at 2.5 m is beyond far = 2 m; the post is not
    assert beyond.any() and (~beyond).any()
    assert np.all(frames["far"].depth[beyond] == 0)
    np.testing.assert_array_equal(frames["far"].depth[~beyond], far_exact[~beyond])
    near_exact = exact["near"].depth
    too_close = near_exact < 0.3  # top of the post 0.1 m below the camera
    assert too_close.any()
    assert np.all(frames["near"].depth[too_close] == 0)
    np.testing.assert_array_equal(frames["near"].depth[~too_close], near_exact[~too_close])
    assert np.all(frames["sky"].depth == 0)
    assert np.all(np.isposinf(exact["sky"].depth))  # kept as "no return" when switched off


def test_flying_pixels_only_at_depth_edges_and_between_neighbours():
    sim = simulator()
    effects = SensorEffects(noise=False, dropout=0.0, out_of_range=False, flying_pixels=True, flying_share=0.5)
    exact = sim.render(targets=[person_box()], effects=SensorEffects.none())
    flown = sim.render(targets=[person_box()], seed=2, effects=effects)
    total_changed = 0
    for name, frame in flown.items():
        d = exact[name].depth.astype(np.float64)
        f = frame.depth.astype(np.float64)
        changed = f != d
        total_changed += changed.sum()
        padded = np.pad(d, 1, mode="edge")
        h, w = d.shape
        windows = np.stack([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)])
        lo, hi = windows.min(axis=0), windows.max(axis=0)
        edge = (hi - lo) > effects.flying_jump
        assert np.all(edge[changed]), "a flying pixel away from a depth edge"
        assert np.all(f[changed] >= lo[changed] - 1e-6)
        assert np.all(f[changed] <= hi[changed] + 1e-6)
        share = changed.sum() / edge.sum()
        assert 0.3 < share < 0.7
    assert total_changed > 100
    again = sim.render(targets=[person_box()], seed=2, effects=effects)
    np.testing.assert_array_equal(again["side"].depth, flown["side"].depth)


def test_uint16_quantises_to_millimetres():
    sim = simulator()
    effects = SensorEffects(noise=True, dropout=0.0, out_of_range=True, flying_pixels=False, uint16=True)
    frame = sim.render(seed=1, effects=effects)["side"]
    assert frame.depth.dtype == np.float32  # DepthFrame reads uint16 mm into metres
    mm = frame.depth.astype(np.float64) * 1000.0
    np.testing.assert_allclose(mm, np.round(mm), atol=2e-3)
    raw = apply_sensor_effects(sim.render_exact()["side"], sim.cell.cameras[1], effects, seed=1, camera_index=1)
    assert raw.dtype == np.uint16
    np.testing.assert_allclose(raw.astype(np.float32) * np.float32(1e-3), frame.depth)


def test_color_cameras_render_like_depth_cameras():
    cams = (camera("rgb", (0.0, 0.0, 3.0), kind="color"),)
    sim = simulator(make_cell(cameras=cams))
    frame = sim.render(effects=SensorEffects.none())["rgb"]
    assert frame.shape == (120, 160)
    assert np.isclose(frame.depth.min(), 2.0, atol=1e-6)


def test_invalid_requests():
    no_robot = simulator(make_cell(robot=False))
    assert no_robot.render(seed=0)["top"].shape == (120, 160)
    with pytest.raises(RobotError, match="no robot"):
        no_robot.render(q=[0.1])
    with pytest.raises(RobotError, match="finite"):
        simulator().render(q=[np.nan])
    with pytest.raises(PolyhullError, match="seed"):
        simulator().render(seed=-1)
    with pytest.raises(PolyhullError, match="dropout"):
        SensorEffects(dropout=1.5)
    with pytest.raises(PolyhullError, match="flying_share"):
        SensorEffects(flying_share=-0.1)


def test_small_cell_fixture_with_the_urdf_robot():
    from pathlib import Path

    from polyhull.cellfile import load_cell

    cell = load_cell(Path(__file__).parent.parent / "fixtures" / "cells" / "small_cell.toml")
    sim = Simulator(cell)
    assert sim.robot is not None
    frames = sim.render(seed=0, effects=SensorEffects.none())
    reference = sim.reference()
    for cam in cell.cameras:
        depth = frames[cam.name].depth
        assert depth.shape == cam.shape
        assert np.all(depth <= reference[cam.name])
        robot_pixels = depth < reference[cam.name] - 0.05
        assert robot_pixels.mean() > 0.01  # the arm in the middle of the cell is seen


FRAMES_DIR = __import__("pathlib").Path(__file__).parent.parent / "fixtures" / "frames"


def _manifest():
    import json

    return json.loads((FRAMES_DIR / "manifest.json").read_text())


def test_recorded_fixtures_are_complete_and_small():
    from polyhull.cellfile import load_cell
    from polyhull.frames import load_frames

    manifest = _manifest()
    files = sorted(p.name for p in FRAMES_DIR.glob("*.npz"))
    assert files == sorted(e["file"] for e in manifest["frames"])
    assert sum((FRAMES_DIR / f).stat().st_size for f in files) < 10e6
    dtypes = set()
    for entry in manifest["frames"]:
        cell = load_cell(FRAMES_DIR / entry["cell"])
        loaded = load_frames(FRAMES_DIR / entry["file"])
        assert set(loaded.frames) == {c.name for c in cell.cameras}
        for cam in cell.cameras:
            assert loaded.frames[cam.name].shape == cam.shape
        np.testing.assert_allclose(loaded.q, entry["q"])
        assert loaded.stamp == entry["stamp"]
        with np.load(FRAMES_DIR / entry["file"]) as raw:
            dtypes.add(str(raw[cell.cameras[0].name].dtype))
    assert dtypes == {"uint16", "float32"}
    assert len([e for e in manifest["frames"] if e["file"].startswith("small_walk")]) >= 8


@pytest.mark.parametrize("name", ["small_walk_000.npz", "small_walk_005.npz", "paper_walk_001.npz"])
def test_recorded_fixtures_replay_from_the_manifest(name):
    from polyhull.cellfile import load_cell
    from polyhull.frames import load_frames
    from polyhull.person import make_person

    entry = next(e for e in _manifest()["frames"] if e["file"] == name)
    cell = load_cell(FRAMES_DIR / entry["cell"])
    persons = [make_person(**{**p, "position": tuple(p["position"])}) for p in entry["persons"]]
    sim = Simulator(cell)
    frames = sim.render(
        entry["q"], targets=persons, seed=entry["seed"], stamp=entry["stamp"],
        effects=SensorEffects(**entry["effects"]),
    )
    recorded = load_frames(FRAMES_DIR / name).frames
    for cam in cell.cameras:
        same = frames[cam.name].depth == recorded[cam.name].depth
        assert same.mean() > 0.999, f"{name} camera {cam.name}: simulator output changed"
    # the person is in the frames: some camera sees it in front of the empty cell
    exact = sim.render_exact(entry["q"], targets=persons)
    empty = sim.render_exact(entry["q"])
    assert any(np.sum(exact[c.name] < empty[c.name] - 0.05) > 100 for c in cell.cameras)


def test_a_colour_camera_gets_no_flying_pixels_and_no_dropouts():
    """Flying pixels and dropouts are a depth sensor's: a colour camera's frame (where the
    image changed) gets neither; a depth camera at the same place gets both."""
    heavy = SensorEffects(noise=False, dropout=0.05, flying_share=1.0, out_of_range=False)
    for kind, expect in (("color", False), ("depth", True)):
        cams = (camera("c", (0.0, 0.0, 3.0), kind=kind),)
        sim = simulator(make_cell(cameras=cams))
        exact = sim.render_exact()["c"]
        depth = sim.render(effects=heavy, seed=2)["c"].depth
        changed = ~((depth == exact) | (np.isinf(depth) & np.isinf(exact)))
        assert changed.any() == expect, kind
