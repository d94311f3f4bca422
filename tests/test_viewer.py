"""Tests of polyhull_viewer: geometry conversion, colours, scene tree, HTML, demo animation.

The scene tree is checked on :class:`polyhull_viewer.StaticVisualizer`, which keeps the
tree the way the meshcat server does (a live ``meshcat.Visualizer`` keeps none locally).
"""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import manifold3d as m3
import numpy as np
import pytest
import trimesh
import umsgpack
from hypothesis import given, settings
from hypothesis import strategies as st

import polyhull_viewer as pv
from polyhull.camera import Camera, Intrinsics, look_at_rotation
from polyhull.cell import Cell, Obstacle, RobotSpec, Zone
from polyhull.errors import FrameError, PolyhullError
from polyhull.frames import DepthFrame
from polyhull_viewer._demo import rigid_transform
from polyhull_viewer._geometry import cluster_decimate, manifold_arrays, mesh_object
from polyhull_viewer._scene import view_pose

# -- fixtures ---------------------------------------------------------------------------------


def _camera(name: str, position: list[float], target: list[float], w: int = 64, h: int = 48) -> Camera:
    T = np.eye(4)
    T[:3, :3] = look_at_rotation(np.array(position), np.array(target))
    T[:3, 3] = position
    k = Intrinsics(w, h, 0.82 * w, 0.82 * w, (w - 1) / 2, (h - 1) / 2)
    return Camera(name, "depth", k, T, near=0.3, far=8.0)


@pytest.fixture(scope="module")
def cell() -> Cell:
    cameras = (
        _camera("ne", [5.8, 5.8, 3.3], [3.0, 3.0, 0.8]),
        _camera("sw/low", [0.2, 0.2, 2.0], [3.0, 3.0, 0.8]),
    )
    obstacles = (
        Obstacle.box("table", np.array([1.5, 4.5, 0.4]), np.array([1.6, 0.8, 0.8])),
        Obstacle.box("curtain", np.array([5.0, 1.0, 1.0]), np.array([0.6, 1.2, 2.0]), solid=False),
    )
    robot = RobotSpec(urdf=Path("unused.urdf"), base=(3.0, 3.0, 0.0), q=(0.3, 0.0))
    return Cell("test cell", Zone((0.0, 0.0, 0.0), (6.0, 6.0, 3.5)), cameras, obstacles, robot)


class FakeRobot:
    """Two rigid links turning about the base's z axis by q[0]; world frame meshes."""

    def __init__(self, base: tuple[float, float, float] = (3.0, 3.0, 0.0)) -> None:
        self.base = np.asarray(base)
        self.calls = 0

    def visual_meshes(self, q: Any) -> dict[str, trimesh.Trimesh]:
        self.calls += 1
        q = np.asarray(q, dtype=np.float64)
        R = trimesh.transformations.rotation_matrix(float(q[0]), [0, 0, 1])
        column = trimesh.creation.cylinder(radius=0.2, height=1.2)
        column.apply_translation([0.0, 0.0, 0.6])
        arm = trimesh.creation.box(extents=[0.9, 0.15, 0.15])
        arm.apply_translation([0.45, 0.0, 1.2])
        out = {}
        for name, mesh in (("column", column), ("arm", arm)):
            mesh.apply_transform(R)
            mesh.apply_translation(self.base)
            out[name] = mesh
        return out


class RemeshingRobot(FakeRobot):
    """A robot whose meshes change vertex count with q (not rigidly animatable)."""

    def visual_meshes(self, q: Any) -> dict[str, trimesh.Trimesh]:
        meshes = super().visual_meshes(q)
        sections = 8 + self.calls  # a different tessellation on every call
        column = trimesh.creation.cylinder(radius=0.2, height=1.2, sections=sections)
        column.apply_translation(self.base + [0.0, 0.0, 0.6])
        meshes["column"] = column
        return meshes


@dataclass(frozen=True)
class Removed:
    rule: str
    volume: float
    centroid: np.ndarray
    mesh: m3.Manifold


@dataclass(frozen=True)
class FakeVerdict:
    """Duck type of polyhull.verdict.Verdict with the fields the viewer reads."""

    hull: m3.Manifold
    robot_occlusion: m3.Manifold
    region: m3.Manifold
    region_r2: m3.Manifold
    removed: tuple[Removed, ...]
    min_distance: float
    closest_points: np.ndarray | None
    closest_link: str | None
    speed_scale: float
    faults: tuple[str, ...] = ()
    timings: dict[str, float] = field(default_factory=dict)
    q: np.ndarray = field(default_factory=lambda: np.array([0.3, 0.0]))
    stamp: float = 0.0
    region_dynamic: m3.Manifold | None = None  # None: the split is unknown, all is dynamic


def _box(lo: list[float], size: list[float]) -> m3.Manifold:
    return m3.Manifold.cube(tuple(size)).translate(tuple(lo))


def _verdict(region: m3.Manifold | None = None, speed: float = 0.4, points: Any = "default") -> FakeVerdict:
    region = _box([1.0, 1.0, 0.0], [0.5, 0.4, 1.8]) if region is None else region
    occlusion = _box([2.6, 2.6, 0.0], [0.8, 0.8, 2.0])
    hull = region + occlusion + _box([0.0, 0.0, 0.0], [6.0, 6.0, 0.2])
    removed = (
        Removed("flying", 0.008, np.array([4.1, 4.1, 2.1]), _box([4.0, 4.0, 2.0], [0.2, 0.2, 0.2])),
        Removed("too small", 0.001, np.array([5.1, 0.1, 0.05]), _box([5.0, 0.0, 0.0], [0.1, 0.1, 0.1])),
    )
    cp = np.array([[1.5, 1.4, 1.0], [2.9, 3.0, 1.1]]) if isinstance(points, str) else points
    distance = float(np.linalg.norm(cp[1] - cp[0])) if cp is not None else float("inf")
    return FakeVerdict(hull, occlusion, region, region, removed, distance, cp, "arm", speed)


def _json(vis: pv.StaticVisualizer, path: str) -> dict[str, Any]:
    """The three.js JSON (metadata, geometries, materials, object) set at ``path``."""
    info = vis.node_info(path)
    assert info is not None and info["object"] is not None, f"no object at {path}"
    return info["object"]["object"]  # type: ignore[no-any-return]


def _material(vis: pv.StaticVisualizer, path: str) -> dict[str, Any]:
    return _json(vis, path)["materials"][0]  # type: ignore[no-any-return]


def _positions(vis: pv.StaticVisualizer, path: str) -> np.ndarray:
    attrs = _json(vis, path)["geometries"][0]["data"]["attributes"]
    return _decode(attrs["position"]["array"], np.float32).reshape(-1, 3)


def _decode(buffer: Any, dtype: Any) -> np.ndarray:
    return np.frombuffer(buffer.data, dtype=dtype)


# -- colours ----------------------------------------------------------------------------------


def test_speed_color_endpoints() -> None:
    assert pv.speed_color(0.0) == pytest.approx((0.9, 0.0, 0.0))
    assert pv.speed_color(0.5) == pytest.approx((0.9, 0.8, 0.0))
    assert pv.speed_color(1.0) == pytest.approx((0.0, 0.8, 0.0))
    # Out of range clips; NaN is drawn as a stop.
    assert pv.speed_color(-3.0) == pv.speed_color(0.0)
    assert pv.speed_color(7.0) == pv.speed_color(1.0)
    assert pv.speed_color(float("nan")) == pv.speed_color(0.0)
    assert pv.speed_color_hex(0.0) == 0xE60000
    assert pv.speed_color_hex(1.0) == 0x00CC00


@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_speed_color_is_monotone(a: float, b: float) -> None:
    lo, hi = sorted((a, b))
    r_lo, g_lo, b_lo = pv.speed_color(lo)
    r_hi, g_hi, b_hi = pv.speed_color(hi)
    assert r_hi <= r_lo + 1e-12  # less red as the robot may go faster
    assert g_hi >= g_lo - 1e-12  # more green
    assert b_lo == b_hi == 0.0


def test_depth_colors() -> None:
    c = pv.depth_colors(np.array([1.0, 2.0, 3.0, 0.0, 9.0]), 1.0, 3.0)
    assert c.shape == (5, 3) and c.dtype == np.float32
    assert np.all((c >= 0) & (c <= 1))
    np.testing.assert_allclose(c[0], c[3], atol=1e-6)  # clipped below near
    np.testing.assert_allclose(c[2], c[4], atol=1e-6)  # clipped above far
    assert c[0, 2] > c[2, 2] and c[2, 0] > c[0, 0]  # purple near, yellow far


# -- geometry conversion ----------------------------------------------------------------------


def test_manifold_to_meshcat_geometry_round_trip() -> None:
    sphere = m3.Manifold.sphere(0.7, 24).translate((1.0, -2.0, 0.5))
    vertices, faces = manifold_arrays(sphere)
    assert vertices.dtype == np.float32 and vertices.shape[1] == 3
    assert faces.dtype == np.uint32 and faces.shape[1] == 3
    lowered = mesh_object(vertices, faces, 0x123456, 0.5).lower()
    geometry = lowered["geometries"][0]
    position = geometry["data"]["attributes"]["position"]
    index = geometry["data"]["index"]
    assert (position["itemSize"], position["type"]) == (3, "Float32Array")
    assert (index["itemSize"], index["type"]) == (3, "Uint32Array")
    v = _decode(position["array"], np.float32).reshape(-1, 3)
    f = _decode(index["array"], np.uint32).reshape(-1, 3)
    np.testing.assert_array_equal(v, vertices)
    np.testing.assert_array_equal(f, faces)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(sphere.volume(), rel=1e-5)
    material = lowered["materials"][0]
    assert material["color"] == 0x123456 and material["transparent"] is True
    assert material["opacity"] == 0.5 and material["depthWrite"] is False


def test_manifold_with_extra_properties_keeps_xyz() -> None:
    # A manifold carrying 2 extra vertex properties (e.g. UVs): only x, y, z are drawn.
    cube = m3.Manifold.cube((1.0, 2.0, 3.0)).set_properties(5, lambda pos, old: np.array([*pos, 7.0, 8.0]))
    vertices, faces = manifold_arrays(cube)
    assert vertices.shape[1] == 3
    np.testing.assert_allclose(vertices.min(axis=0), [0, 0, 0])
    np.testing.assert_allclose(vertices.max(axis=0), [1, 2, 3])


def test_feature_edges_of_box_and_frustum() -> None:
    vertices, faces = manifold_arrays(m3.Manifold.cube((1.0, 2.0, 3.0)))
    assert len(pv.feature_edges(vertices, faces)) == 12
    # A subdivided box with every triangle's vertices split apart: the crease lines are
    # still the 12 box edges (now in 2 pieces each), total length 4 (1 + 2 + 3) m.
    fine = trimesh.creation.box(extents=(1, 2, 3)).subdivide()
    soup_v = fine.vertices[fine.faces].reshape(-1, 3)
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    edges = pv.feature_edges(soup_v, soup_f)
    assert len(edges) == 24
    assert np.linalg.norm(soup_v[edges[:, 0]] - soup_v[edges[:, 1]], axis=1).sum() == pytest.approx(24.0)
    camera = _camera("c", [0.0, 0.0, 2.0], [1.0, 0.0, 0.0])
    frustum_v, frustum_f = manifold_arrays(camera.frustum())
    edges = pv.feature_edges(frustum_v, frustum_f)
    assert len(edges) == 12
    # The 4 lateral edges meet at the camera's centre when extended: check they point at it.
    centre = camera.center
    lateral = 0
    for a, b in frustum_v[edges].astype(np.float64):
        d1, d2 = a - centre, b - centre
        if np.linalg.norm(np.cross(d1, d2)) < 1e-3 * np.linalg.norm(d1) * np.linalg.norm(d2):
            lateral += 1
    assert lateral == 4


def test_feature_edges_of_smooth_mesh_keeps_all() -> None:
    tetra = trimesh.creation.icosahedron()
    assert len(pv.feature_edges(tetra.vertices, tetra.faces)) == 30
    assert pv.feature_edges(np.zeros((0, 3)), np.zeros((0, 3), int)).shape == (0, 2)


def test_cluster_decimate_reduces_and_keeps_extent() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    v, f = cluster_decimate(sphere.vertices, sphere.faces, 500)
    assert 0 < len(f) <= 500 < len(sphere.faces)
    assert f.max() < len(v)
    np.testing.assert_allclose(v.min(axis=0), -1.0, atol=0.25)
    np.testing.assert_allclose(v.max(axis=0), 1.0, atol=0.25)
    same_v, same_f = cluster_decimate(sphere.vertices, sphere.faces, 10**6)
    assert len(same_f) == len(sphere.faces)


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
)
def test_rigid_transform_recovers_a_pose(translation: list[float], quaternion: list[float]) -> None:
    T = trimesh.transformations.quaternion_matrix(np.asarray(quaternion) / np.linalg.norm(quaternion))
    T[:3, 3] = translation
    points = trimesh.creation.box(extents=(0.3, 0.5, 0.9)).vertices
    moved = trimesh.transform_points(points, T)
    T_est, residual = rigid_transform(points, moved)
    np.testing.assert_allclose(T_est, T, atol=1e-9)
    assert residual < 1e-9


# -- the static visualizer --------------------------------------------------------------------


def test_static_visualizer_tree_semantics() -> None:
    vis = pv.StaticVisualizer()
    vis["a/b"].set_object(pv.TextLabel("x"))
    vis["/top/c"].set_object(pv.TextLabel("y"))
    vis["a"]["b2"].set_property("visible", False)
    vis["/top/c"].set_transform(np.diag([1.0, 1.0, 1.0, 1.0]))
    assert vis.object_paths() == ["/meshcat/a/b", "/top/c"]
    assert vis.node_info("/meshcat/a/b2")["properties"] == {"visible": False}  # type: ignore[index]
    vis["a"].delete()
    assert vis.object_paths() == ["/top/c"]
    vis["/top/c"].set_object(pv.TextLabel("z"))  # replaces, does not duplicate
    assert vis.object_paths() == ["/top/c"]
    with pytest.raises(ValueError):
        vis["/top/c"].set_transform(np.eye(3))
    vis["/"].delete()
    assert vis.object_paths() == []


def test_draw_cell_paths_and_colours(cell: Cell) -> None:
    vis = pv.StaticVisualizer()
    robot = FakeRobot()
    pv.draw_cell(vis, cell, robot=robot)
    paths = set(vis.object_paths())
    expected = {
        "/polyhull/cell/zone",
        "/polyhull/cell/obstacles/table",
        "/polyhull/cell/obstacles/curtain",
        "/polyhull/robot/column",
        "/polyhull/robot/arm",
        "/polyhull/cameras/ne/frustum",
        "/polyhull/cameras/ne/body",
        "/polyhull/cameras/ne/label",
        "/polyhull/cameras/sw_low/frustum",  # "/" in a name would split the path
        "/polyhull/cameras/sw_low/body",
        "/polyhull/cameras/sw_low/label",
    }
    assert paths == expected
    for link in ("column", "arm"):
        material = _material(vis, f"/polyhull/robot/{link}")
        assert material["color"] == pv.STYLE.robot
    # The robot is drawn at the cell's default q: the arm points along (cos 0.3, sin 0.3).
    v = _positions(vis, "/polyhull/robot/arm")
    tip = v[np.argmax(np.linalg.norm(v[:, :2] - [3.0, 3.0], axis=1))]
    angle = np.arctan2(tip[1] - 3.0, tip[0] - 3.0)
    assert abs(angle - 0.3) < 0.12
    # Zone: 12 lines = 24 endpoints; frustum lines clipped to the zone.
    assert _json(vis, "/polyhull/cell/zone")["object"]["type"] == "LineSegments"
    assert len(_positions(vis, "/polyhull/cell/zone")) == 24
    pts = _positions(vis, "/polyhull/cameras/ne/frustum")
    assert np.all(pts >= -1e-4) and np.all(pts <= np.array([6.0, 6.0, 3.5]) + 1e-4)
    # Camera labels are sprites of one size on screen, whatever their distance.
    labels = [_json(vis, f"/polyhull/cameras/{n}/label") for n in ("ne", "sw_low")]
    assert all(label["object"]["type"] == "Sprite" for label in labels)
    assert all(label["materials"][0]["sizeAttenuation"] is False for label in labels)
    assert labels[0]["object"]["matrix"] == labels[1]["object"]["matrix"]
    # An open obstacle is see-through, a solid one is not.
    assert _material(vis, "/polyhull/cell/obstacles/curtain")["transparent"]
    assert not _material(vis, "/polyhull/cell/obstacles/table")["transparent"]


def test_draw_cell_unclipped_frustum_reaches_far(cell: Cell) -> None:
    vis = pv.StaticVisualizer()
    pv.draw_cell(vis, cell, q=[0.0, 0.0], robot=FakeRobot(), clip_frustums=False, labels=False)
    pts = _positions(vis, "/polyhull/cameras/ne/frustum")
    far = np.max(np.linalg.norm(pts - cell.camera("ne").center, axis=1))
    assert far > 8.0  # the far plane's corners lie beyond 8 m from the centre
    assert "/polyhull/cameras/ne/label" not in vis.object_paths()


def test_draw_cell_without_robot(cell: Cell) -> None:
    bare = Cell("bare", cell.zone, cell.cameras, cell.obstacles, robot=None)
    vis = pv.StaticVisualizer()
    pv.draw_cell(vis, bare, prefix="/mine")
    assert not any(p.startswith("/mine/robot") for p in vis.object_paths())
    assert "/mine/cell/zone" in vis.object_paths()


def _tube_axis_check(points: np.ndarray, ends: np.ndarray, radius: float) -> None:
    """A tube's vertices lie between the ends (2, 3), on the axis (cap centres) or ``radius`` off it."""
    a, b = ends
    axis = (b - a) / np.linalg.norm(b - a)
    t = (points - a) @ axis
    off = np.linalg.norm((points - a) - np.outer(t, axis), axis=1)
    assert t.min() > -1e-4 and t.max() < np.linalg.norm(b - a) + 1e-4
    assert np.isclose(t.min(), 0.0, atol=1e-4) and np.isclose(t.max(), np.linalg.norm(b - a), atol=1e-4)
    rim = off > 1e-6
    assert rim.sum() >= 16
    np.testing.assert_allclose(off[rim], radius, atol=1e-4)


def test_draw_verdict_paths_colours_and_updates() -> None:
    vis = pv.StaticVisualizer()
    verdict = _verdict(speed=0.25)
    pv.draw_verdict(vis, verdict)
    paths = set(vis.object_paths())
    assert {
        "/polyhull/regions/hull",
        "/polyhull/regions/robot_occlusion",
        "/polyhull/regions/dynamic",  # no region_dynamic: all of R counts as dynamic
        "/polyhull/regions/removed/0_flying",
        "/polyhull/regions/removed/1_too small",
        "/polyhull/distance/segment",
        "/polyhull/distance/region_point",
        "/polyhull/distance/robot_point",
        "/polyhull/distance/label",
    } == paths
    colours = {
        name: _material(vis, f"/polyhull/regions/{name}")
        for name in ("hull", "robot_occlusion", "dynamic")
    }
    assert len({m["color"] for m in colours.values()}) == 3  # C, M, R distinct
    assert all(m["transparent"] for m in colours.values())
    assert colours["hull"]["opacity"] < colours["robot_occlusion"]["opacity"] < colours["dynamic"]["opacity"]
    # C, M and the removed parts start hidden; the dynamic region shows.
    for hidden in ("hull", "robot_occlusion", "removed"):
        assert vis.node_info(f"/polyhull/regions/{hidden}")["properties"] == {"visible": False}  # type: ignore[index]
    assert "visible" not in vis.node_info("/polyhull/regions/dynamic")["properties"]  # type: ignore[index]
    assert _material(vis, "/polyhull/distance/segment")["color"] == pv.speed_color_hex(0.25)
    assert verdict.closest_points is not None
    _tube_axis_check(_positions(vis, "/polyhull/distance/segment"), verdict.closest_points, pv.STYLE.segment_radius)
    T = vis.node_info("/polyhull/distance/robot_point")["transform"]["matrix"]  # type: ignore[index]
    np.testing.assert_allclose(np.reshape(T, (4, 4)).T[:3, 3], verdict.closest_points[1])
    d = np.linalg.norm(verdict.closest_points[1] - verdict.closest_points[0])
    assert vis.status == (f"{d:.2f} m to arm, speed 25 %", pv.speed_color_hex(0.25))
    label = _json(vis, "/polyhull/distance/label")
    assert label["textures"][0]["text"] == vis.status[0]

    # Next cycle: the region is empty, no distance, one removed component fewer.
    empty = m3.Manifold()
    nothing = FakeVerdict(empty, empty, empty, empty, verdict.removed[:1], float("inf"), None, None, 1.0)
    pv.draw_verdict(vis, nothing)
    assert set(vis.object_paths()) == {"/polyhull/regions/removed/0_flying"}
    assert vis.status is not None and vis.status[0] == "no possibly occupied region near the robot, speed 100 %"


def test_draw_verdict_splits_static_and_dynamic_around_the_robot() -> None:
    """The person's region is saturated; the static region shows faintly only near the robot."""
    person = _box([1.0, 1.0, 0.0], [0.5, 0.4, 1.8])
    near_static = _box([3.5, 2.5, 0.0], [0.4, 0.4, 0.3])  # a shadow next to the robot
    far_static = _box([0.0, 5.5, 3.0], [0.5, 0.5, 0.5])  # blind space in a far ceiling corner
    static = near_static + far_static
    verdict = replace(_verdict(region=person + static, speed=0.6), region_dynamic=person)
    for static_region in (None, static):  # computed as region - region_dynamic, or given
        vis = pv.StaticVisualizer()
        pv.draw_verdict(vis, verdict, robot=FakeRobot(), static_region=static_region)
        dynamic = _positions(vis, "/polyhull/regions/dynamic")
        np.testing.assert_allclose(dynamic.min(axis=0), [1.0, 1.0, 0.0], atol=1e-5)
        np.testing.assert_allclose(dynamic.max(axis=0), [1.5, 1.4, 1.8], atol=1e-5)
        near = _positions(vis, "/polyhull/regions/static/near")
        far = _positions(vis, "/polyhull/regions/static/far")
        np.testing.assert_allclose(near.min(axis=0), [3.5, 2.5, 0.0], atol=1e-5)
        assert far.min(axis=0)[2] > 2.9  # the ceiling corner
        assert "visible" not in vis.node_info("/polyhull/regions/static/near")["properties"]  # type: ignore[index]
        assert vis.node_info("/polyhull/regions/static/far")["properties"] == {"visible": False}  # type: ignore[index]
        dyn_m, static_m = (_material(vis, f"/polyhull/regions/{p}") for p in ("dynamic", "static/near"))
        assert dyn_m["opacity"] >= 3 * static_m["opacity"]  # saturated against a faint tint
        # The closest link ("arm") gets a shell in the speed colour, around the link.
        shell = _positions(vis, "/polyhull/distance/closest_link")
        arm = FakeRobot().visual_meshes(verdict.q)["arm"]
        assert _material(vis, "/polyhull/distance/closest_link")["color"] == pv.speed_color_hex(0.6)
        np.testing.assert_allclose(shell.mean(axis=0), arm.vertices.mean(axis=0), atol=0.02)
        assert np.all(np.ptp(shell, axis=0) > np.ptp(arm.vertices, axis=0))


def test_dynamic_region_drawn_is_what_the_cycle_adds_to_the_static_region() -> None:
    """A restored sheet that already lies in the static region is drawn with the static region."""
    person = _box([1.0, 1.0, 0.0], [0.5, 0.4, 1.8])
    static = _box([0.0, 5.5, 3.0], [0.5, 0.5, 0.5])
    sheet_in_static = _box([0.0, 5.6, 3.1], [0.3, 0.3, 0.3])
    verdict = replace(_verdict(region=person + static), region_dynamic=person + sheet_in_static)
    vis = pv.StaticVisualizer()
    pv.draw_verdict(vis, verdict, static_region=static)
    drawn = _positions(vis, "/polyhull/regions/dynamic")
    np.testing.assert_allclose(drawn.max(axis=0), [1.5, 1.4, 1.8], atol=1e-5)  # the person only
    far_or_near = [p for p in vis.object_paths() if p.startswith("/polyhull/regions/static/")]
    assert far_or_near == ["/polyhull/regions/static/near"]  # no robot given: all of it "near"


def test_robot_links_keep_their_urdf_colours() -> None:
    grey = trimesh.creation.box(extents=[1, 1, 1])
    grey.visual.face_colors = [64, 64, 70, 255]
    two = trimesh.creation.box(extents=[1, 1, 1])
    colors = np.tile([255, 107, 0, 255], (len(two.faces), 1))
    colors[:4] = [30, 30, 30, 255]
    two.visual.face_colors = colors
    plain = trimesh.creation.box(extents=[1, 1, 1])

    class Robot:
        def visual_meshes(self, q: Any) -> dict[str, trimesh.Trimesh]:
            return {"base": grey, "arm": two, "plain": plain}

    vis = pv.StaticVisualizer()
    pv.draw_robot(vis["/r"], Robot(), np.zeros(1))
    assert _material(vis, "/r/base")["color"] == 0x404046
    assert _material(vis, "/r/plain")["color"] == pv.STYLE.robot
    arm = _json(vis, "/r/arm")
    assert arm["materials"][0]["vertexColors"]
    rgb = _decode(arm["geometries"][0]["data"]["attributes"]["color"]["array"], np.float32).reshape(-1, 3)
    assert len(rgb) == 3 * len(two.faces)  # unshared vertices: flat colour per face
    np.testing.assert_allclose(rgb[0], [30 / 255, 30 / 255, 30 / 255], atol=1e-6)
    np.testing.assert_allclose(rgb[-1], [1.0, 107 / 255, 0.0], atol=1e-6)


def test_draw_frames_point_clouds(cell: Cell) -> None:
    camera = cell.camera("ne")
    depth = np.full(camera.shape, 3.0, dtype=np.float32)
    depth[0, :] = 0.0  # unknown
    depth[1, :] = np.nan
    depth[2, :] = np.inf  # no return
    depth[3, :] = 9.0  # beyond far
    frames = {"ne": DepthFrame("ne", depth)}
    vis = pv.StaticVisualizer()
    drawn = pv.draw_frames(vis, cell, frames, max_points=500)
    assert drawn == ["ne"]
    assert vis.node_info("/polyhull/frames")["properties"] == {"visible": False}  # type: ignore[index]
    obj = _json(vis, "/polyhull/frames/ne")
    assert obj["object"]["type"] == "Points"
    attrs = obj["geometries"][0]["data"]["attributes"]
    points = _decode(attrs["position"]["array"], np.float32).reshape(-1, 3)
    colors = _decode(attrs["color"]["array"], np.float32).reshape(-1, 3)
    assert len(points) == len(colors) == 500
    # Every drawn point is a valid pixel at z-depth 3 m in the camera frame.
    z = camera.world_to_camera(points.astype(np.float64))[:, 2]
    np.testing.assert_allclose(z, 3.0, atol=1e-4)
    uv, _ = camera.project(points.astype(np.float64))
    assert uv[:, 1].min() > 3.5  # rows 0..3 are invalid

    all_points, depths = pv.frame_points(camera, frames["ne"], max_points=10**6)
    assert len(all_points) == (camera.shape[0] - 4) * camera.shape[1]

    # Points beyond the zone are clipped: at 7.9 m the rays leave the 6 x 6 x 3.5 m box.
    far = {"ne": DepthFrame("ne", np.where(np.isfinite(depth) & (depth > 0), 7.9, depth).astype(np.float32))}
    unclipped, _ = pv.frame_points(camera, far["ne"], max_points=10**6)
    outside = ~np.all((unclipped >= 0.0) & (unclipped <= [6.0, 6.0, 3.5]), axis=1)
    assert outside.any()
    pv.draw_frames(vis, cell, far, max_points=10**6)
    drawn_far = _positions(vis, "/polyhull/frames/ne")
    assert len(drawn_far) == int((~outside).sum())
    assert np.all(drawn_far >= -1e-5) and np.all(drawn_far <= np.array([6.0, 6.0, 3.5]) + 1e-5)

    with pytest.raises(FrameError, match="unknown cameras"):
        pv.draw_frames(vis, cell, {"nope": DepthFrame("nope", depth)})
    with pytest.raises(FrameError, match="does not match"):
        pv.draw_frames(vis, cell, {"ne": DepthFrame("ne", np.ones((5, 5), np.float32))})


def test_draw_camera_regions_hidden_by_default() -> None:
    vis = pv.StaticVisualizer()
    regions = {"a": _box([0, 0, 0], [1, 1, 1]), "b": _box([2, 0, 0], [1, 1, 1]), "c": m3.Manifold()}
    pv.draw_camera_regions(vis, regions)
    assert vis.object_paths() == ["/polyhull/regions/camera/a", "/polyhull/regions/camera/b"]
    for name in ("a", "b"):
        assert vis.node_info(f"/polyhull/regions/camera/{name}")["properties"] == {"visible": False}  # type: ignore[index]
    colours = {
        _material(vis, f"/polyhull/regions/camera/{n}")["color"]
        for n in ("a", "b")
    }
    assert len(colours) == 2
    pv.draw_camera_regions(vis, {"a": regions["a"]}, visible=True, colors={"a": 0x010203})
    assert vis.node_info("/polyhull/regions/camera/a")["properties"] == {"visible": True}  # type: ignore[index]
    assert _material(vis, "/polyhull/regions/camera/a")["color"] == 0x010203
    assert vis.object_paths() == ["/polyhull/regions/camera/a"]


def test_set_view_looks_at_the_robot_from_a_corner(cell: Cell) -> None:
    vis = pv.StaticVisualizer()
    pv.set_view(vis, cell)
    T = np.reshape(vis.node_info("/polyhull")["transform"]["matrix"], (4, 4)).T  # type: ignore[index]
    target = -T[:3, 3]  # what goes to the orbit centre: the robot base at working height
    np.testing.assert_allclose(target[:2], [3.0, 3.0])
    assert 0.0 < target[2] < 1.0
    grid = np.reshape(vis.node_info("/Grid")["transform"]["matrix"], (4, 4)).T  # type: ignore[index]
    assert np.isclose(grid[2, 3] + target[2], 0.0)  # the grid lies on the zone's floor
    x, y_up, minus_y = vis.node_info("/Cameras/default/rotated/<object>")["properties"]["position"]  # type: ignore[index]
    eye = target + np.array([x, -minus_y, y_up])
    assert eye[0] > 6.0 and eye[1] < 0.0 and eye[2] > 3.5  # beyond the (+x, -y, top) corner
    # Every corner of Z is in view (75 degree vertical field, 4:3).
    _, eye_scene = view_pose(cell)
    forward = -eye_scene / np.linalg.norm(eye_scene)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    corners = np.array([[a, b, c] for a in (0.0, 6.0) for b in (0.0, 6.0) for c in (0.0, 3.5)]) - target
    d = corners - eye_scene
    depth = d @ forward
    tan = np.tan(np.deg2rad(37.5))
    assert np.all(np.abs(d @ up) < depth * tan) and np.all(np.abs(d @ right) < depth * tan * 4 / 3)


# -- HTML -------------------------------------------------------------------------------------


def _html_commands(html: str) -> list[dict[str, Any]]:
    match = re.search(r"var commands = (\[.*?\]);", html, re.S)
    assert match is not None
    return [umsgpack.unpackb(base64.b64decode(b)) for b in json.loads(match.group(1))]


def test_html_is_standalone(tmp_path: Path, cell: Cell) -> None:
    vis = pv.StaticVisualizer()
    pv.draw_scene(vis, cell, verdict=_verdict(), robot=FakeRobot())
    out = pv.write_html(vis, tmp_path / "sub" / "scene.html", title="a <cell>")
    html = out.read_text(encoding="utf-8")
    assert "<title>a &lt;cell&gt;</title>" in html
    assert "new MeshCat.Viewer" in html and "handle_command_bytearray" in html
    assert len(html) > 500_000  # the three.js/meshcat bundle is inline
    # Nothing is fetched: no external scripts, styles, images or websocket connection.
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)\s*=", html, re.I)
    assert "viewer.connect(" not in html
    commands = _html_commands(html)
    paths = [c["path"] for c in commands if c["type"] == "set_object"]
    assert paths == vis.object_paths()
    # The distance line is HTML text over the view (escaped), with no timeline.
    assert vis.status is not None
    assert f'<span id="polyhull-text">{vis.status[0]}</span>' in html
    assert "var timeline = null;" in html
    assert {c["type"] for c in commands} == {"set_object", "set_property", "set_transform"}


def test_write_html_reports_unwritable_path(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(PolyhullError):
        pv.write_html(pv.StaticVisualizer(), blocker / "scene.html")


# -- demo recorder ----------------------------------------------------------------------------


def _track_value(track: dict[str, Any], time: float) -> Any:
    value = track["keys"][0]["value"]
    for key in track["keys"]:
        if key["time"] <= time + 1e-9:
            value = key["value"]
    return value


def _person(x: float) -> trimesh.Trimesh:
    person = trimesh.creation.capsule(height=1.4, radius=0.25)
    person.apply_translation([x, 1.0, 0.95])
    return person


def _record(cell: Cell, n: int, robot: FakeRobot, **kwargs: Any) -> pv.DemoRecorder:
    recorder = pv.DemoRecorder(cell, robot=robot, **kwargs)
    for k in range(n):
        t = 0.1 * k
        x = 0.5 + 0.02 * k
        region = _box([x - 0.3, 0.7, 0.0], [0.6, 0.6, 1.9])
        verdict = _verdict(region=region, speed=min(1.0, 0.02 * k))
        recorder.add_cycle(t, [0.02 * k, 0.0], [_person(x)], verdict)
    return recorder


def test_demo_animation_shows_one_cycle_at_a_time(cell: Cell) -> None:
    robot = FakeRobot()
    recorder = _record(cell, 12, robot)
    vis = recorder.build()
    paths = vis.object_paths()
    for k in range(12):
        assert f"/polyhull/anim/person/{k}" in paths
        assert f"/polyhull/anim/region/{k}" in paths
        assert f"/polyhull/anim/distance/{k}/segment" in paths
    animation = vis.animation
    assert animation is not None and animation["options"]["play"] is True
    clips = {a["path"]: a["clip"] for a in animation["animations"]}
    fps = recorder.fps
    for k in range(12):
        t_mid = (0.1 * k + 0.05) * fps  # middle of cycle k, in frames
        for kind in ("person", "region", "distance"):
            visible = [
                j
                for j in range(12)
                if _track_value(clips[f"/polyhull/anim/{kind}/{j}"]["tracks"][0], t_mid)
            ]
            assert visible == [k], (kind, k, visible)
    # Initially (before the animation runs) only cycle 0 shows.
    assert vis.node_info("/polyhull/anim/person/0")["properties"]["visible"] is True  # type: ignore[index]
    assert vis.node_info("/polyhull/anim/person/5")["properties"]["visible"] is False  # type: ignore[index]
    # The robot's links are animated rigidly: the key of cycle k maps the link at q_0 onto
    # the link at q_k.
    durations = set()
    for link in ("column", "arm"):
        tracks = {t["name"]: t for t in clips[f"/polyhull/robot/{link}"]["tracks"]}
        assert set(tracks) == {".position", ".quaternion"}
        key = tracks[".quaternion"]["keys"][7]
        x, y, z, w = key["value"]
        T = trimesh.transformations.quaternion_matrix([w, x, y, z])
        T[:3, 3] = tracks[".position"]["keys"][7]["value"]
        start = robot.visual_meshes([0.0, 0.0])[link].vertices
        at_7 = robot.visual_meshes([0.14, 0.0])[link].vertices
        np.testing.assert_allclose(trimesh.transform_points(start, T), at_7, atol=1e-6)
        durations.add(tracks[".position"]["keys"][-1]["time"])
    durations.update(c["tracks"][0]["keys"][-1]["time"] for c in clips.values())
    assert len(durations) == 1  # every clip ends together, so loops stay in step


def test_demo_keeps_at_most_max_cycles_and_small_meshes(cell: Cell, tmp_path: Path) -> None:
    recorder = _record(cell, 30, FakeRobot(), max_cycles=8, max_faces=60)
    assert recorder.cycle_count == 30
    kept = recorder.kept_cycles()
    assert len(kept) == 8 and kept[0] == 0 and kept[-1] == 29
    vis = recorder.build()
    people = [p for p in vis.object_paths() if p.startswith("/polyhull/anim/person/")]
    assert len(people) == 8
    geometry = _json(vis, people[3])["geometries"][0]
    faces = _decode(geometry["data"]["index"]["array"], np.uint32)
    assert len(faces) // 3 <= 60
    out = recorder.write_html(tmp_path / "demo.html")
    html = out.read_text(encoding="utf-8")
    assert any(c["type"] == "set_animation" for c in _html_commands(html))


def test_demo_falls_back_when_links_are_not_rigid(cell: Cell) -> None:
    vis = _record(cell, 4, RemeshingRobot()).build()
    paths = vis.object_paths()
    assert not any(p.startswith("/polyhull/robot/") for p in paths)
    for k in range(4):
        assert f"/polyhull/anim/robot/{k}/column" in paths
    clips = {a["path"]: a["clip"] for a in vis.animation["animations"]}  # type: ignore[index]
    assert "/polyhull/anim/robot/2" in clips


def test_demo_rejects_bad_input(cell: Cell) -> None:
    recorder = pv.DemoRecorder(cell, robot=FakeRobot())
    with pytest.raises(PolyhullError, match="no cycle"):
        recorder.build()
    recorder.add_cycle(1.0, [0.0, 0.0], [], _verdict())
    with pytest.raises(PolyhullError, match="must exceed"):
        recorder.add_cycle(1.0, [0.0, 0.0], [], _verdict())
    with pytest.raises(PolyhullError, match="finite"):
        recorder.add_cycle(2.0, [np.nan, 0.0], [], _verdict())
    with pytest.raises(PolyhullError, match="max_cycles"):
        pv.DemoRecorder(cell, robot=FakeRobot(), max_cycles=1)
    # One cycle without a person or distance still builds.
    vis = recorder.build()
    assert "/polyhull/anim/region/0" in vis.object_paths()


def test_demo_shares_the_static_region_and_follows_the_timeline(cell: Cell, tmp_path: Path) -> None:
    """The static region is sent once; each cycle sends only its dynamic region, within budget."""
    static = _box([3.4, 2.4, 0.0], [0.5, 0.5, 0.3]) + _box([0.0, 5.5, 3.0], [0.5, 0.5, 0.5])
    recorder = pv.DemoRecorder(cell, robot=FakeRobot(), static_region=static, face_budget=600, max_faces=400)
    person = m3.Manifold.sphere(0.4, 96)  # about 18,000 triangles
    for k in range(6):
        dyn = person.translate((1.0 + 0.1 * k, 1.0, 0.9))
        verdict = replace(_verdict(region=dyn + static, speed=0.2 * k), region_dynamic=dyn)
        recorder.add_cycle(0.5 * k, [0.1 * k, 0.0], [], verdict)
    vis = recorder.build()
    paths = vis.object_paths()
    assert [p for p in paths if "/static/" in p] == ["/polyhull/regions/static/near", "/polyhull/regions/static/far"]
    for k in range(6):
        geometry = _json(vis, f"/polyhull/anim/region/{k}")["geometries"][0]
        faces = _decode(geometry["data"]["index"]["array"], np.uint32)
        assert 0 < len(faces) // 3 <= 100  # 600 faces shared by 6 cycles
        centre = _decode(geometry["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3).mean(axis=0)
        np.testing.assert_allclose(centre, [1.0 + 0.1 * k, 1.0, 0.9], atol=0.05)  # only the dynamic part
    timeline = vis.timeline
    assert timeline is not None
    np.testing.assert_allclose(timeline["times"], [0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
    assert timeline["duration"] == pytest.approx(3.0)
    assert timeline["texts"][2].startswith("t = 1.0 s: ") and timeline["texts"][2].endswith("speed 40 %")
    assert timeline["colors"][0] == f"#{pv.speed_color_hex(0.0):06x}"
    html = recorder.write_html(tmp_path / "demo.html").read_text(encoding="utf-8")
    assert '"texts": [' in html and "viewer.animator" in html and "viewer.gui.open()" in html
    assert "animator.update = function" in html  # redraws at 20 Hz, not at every frame


def test_text_labels_have_a_screen_size() -> None:
    world = pv.TextLabel("a", height=0.8)
    screen = pv.TextLabel("a", screen_size=0.1)
    assert world.lower()["object"]["matrix"][0] == pytest.approx(0.8)
    assert world.lower()["materials"][0]["sizeAttenuation"] is True
    lowered = screen.lower()
    assert lowered["materials"][0]["sizeAttenuation"] is False
    # Without attenuation, a sprite of scale s spans s / (2 tan(37.5 deg)) of the view's height.
    assert lowered["object"]["matrix"][0] / (2 * np.tan(np.deg2rad(37.5))) == pytest.approx(0.1)


def test_set_timeline_rejects_bad_input() -> None:
    vis = pv.StaticVisualizer()
    with pytest.raises(ValueError, match="as many"):
        vis.set_timeline([0.0, 1.0], ["a"], [0, 0], 2.0)
    with pytest.raises(ValueError, match="increase"):
        vis.set_timeline([1.0, 1.0], ["a", "b"], [0, 0], 2.0)
    vis.set_timeline([0.0, 1.0], ["a </script>", "b"], [0xFF0000, 0], 2.0)
    html = vis.static_html()
    assert "a </script>" not in html and "a <\\/script>" in html


# -- packaging --------------------------------------------------------------------------------


def _run_python(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_missing_meshcat_gives_missing_extra_error() -> None:
    code = (
        "import sys\n"
        "sys.modules['meshcat'] = None\n"
        "from polyhull.errors import MissingExtraError\n"
        "try:\n"
        "    import polyhull_viewer\n"
        "except MissingExtraError as exc:\n"
        "    print('MISSING', exc)\n"
    )
    result = _run_python(code)
    assert result.returncode == 0, result.stderr
    assert "MISSING" in result.stdout and "pip install 'polyhull[viewer]'" in result.stdout


def test_core_never_imports_the_viewer() -> None:
    code = (
        "import importlib, pkgutil, sys\n"
        "import polyhull\n"
        "for m in pkgutil.walk_packages(polyhull.__path__, 'polyhull.'):\n"
        "    if m.name == 'polyhull.__main__':\n"
        "        continue\n"
        "    try:\n"
        "        importlib.import_module(m.name)\n"
        "    except Exception as exc:\n"
        "        print('SKIP', m.name, type(exc).__name__, file=sys.stderr)\n"
        "print(sorted(k for k in sys.modules if k.split('.')[0] in ('polyhull_viewer', 'meshcat')))\n"
    )
    result = _run_python(code)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_public_names_resolve() -> None:
    for name in pv.__all__:
        assert getattr(pv, name) is not None, name


@dataclass(frozen=True)
class _DrawingVerdict(FakeVerdict):
    """A verdict with the fast drawing of its dynamic region (the monitor's Verdict has it)."""

    drawing: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))

    def region_dynamic_drawing(self) -> tuple[np.ndarray, np.ndarray]:
        return self.drawing


def test_demo_draws_the_verdicts_fast_drawing_when_it_has_one(cell: Cell) -> None:
    """The recorder draws ``region_dynamic_drawing()`` as given (two overlapping boxes, not
    united, not cut by the static region), and never builds ``region_dynamic``."""
    boxes = [_box([1.0, 1.0, 0.0], [0.4, 0.4, 1.0]), _box([1.2, 1.2, 0.5], [0.4, 0.4, 1.0])]
    arrays = [(np.asarray(b.to_mesh().vert_properties)[:, :3], np.asarray(b.to_mesh().tri_verts)) for b in boxes]
    vertices = np.concatenate([a[0] for a in arrays])
    faces = np.concatenate([arrays[0][1], arrays[1][1] + len(arrays[0][0])])
    static = _box([1.0, 1.0, 0.0], [2.0, 2.0, 0.3])  # holds part of both boxes
    recorder = pv.DemoRecorder(cell, robot=FakeRobot(), static_region=static)
    base = _verdict(region=boxes[0] + boxes[1] + static)
    fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
    fields["region_dynamic"] = None  # were it read, the whole region would be drawn
    for k in range(2):
        recorder.add_cycle(0.5 * k, [0.1 * k, 0.0], [], _DrawingVerdict(**fields, drawing=(vertices, faces)))
    vis = recorder.build()
    geometry = _json(vis, "/polyhull/anim/region/1")["geometries"][0]
    drawn = _decode(geometry["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3)
    drawn_faces = _decode(geometry["data"]["index"]["array"], np.uint32).reshape(-1, 3)
    np.testing.assert_allclose(drawn, vertices.astype(np.float32))
    np.testing.assert_array_equal(drawn_faces, faces)


class _NoUnion:
    """A verdict whose ``region_dynamic`` (the monitor's: a union built when read) fails
    the test when read."""

    def __init__(self, verdict: Any) -> None:
        self._verdict = verdict

    def __getattr__(self, name: str) -> Any:
        return getattr(self._verdict, name)

    @property
    def region_dynamic(self) -> m3.Manifold:
        raise AssertionError("region_dynamic was built")


def test_draw_verdict_draws_the_verdicts_fast_drawing_given_the_static_region() -> None:
    """Given ``static_region``, ``draw_verdict`` draws ``region_dynamic_drawing()`` as given
    (two overlapping boxes, not united) and never builds ``region_dynamic``; without
    ``static_region`` it cannot split the region that way and uses the manifolds."""
    boxes = [_box([1.0, 1.0, 0.0], [0.4, 0.4, 1.0]), _box([1.2, 1.2, 0.5], [0.4, 0.4, 1.0])]
    arrays = [(np.asarray(b.to_mesh().vert_properties)[:, :3], np.asarray(b.to_mesh().tri_verts)) for b in boxes]
    vertices = np.concatenate([a[0] for a in arrays])
    faces = np.concatenate([arrays[0][1], arrays[1][1] + len(arrays[0][0])])
    static = _box([3.0, 3.0, 0.0], [0.5, 0.5, 0.3])
    base = _verdict(region=boxes[0] + boxes[1] + static)
    fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
    fields["region_dynamic"] = None  # None: the whole region would be drawn as dynamic
    verdict = _DrawingVerdict(**fields, drawing=(vertices, faces))
    vis = pv.StaticVisualizer()
    pv.draw_verdict(vis, _NoUnion(verdict), static_region=static)
    geometry = _json(vis, "/polyhull/regions/dynamic")["geometries"][0]
    drawn = _decode(geometry["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3)
    drawn_faces = _decode(geometry["data"]["index"]["array"], np.uint32).reshape(-1, 3)
    np.testing.assert_allclose(drawn, vertices.astype(np.float32))
    np.testing.assert_array_equal(drawn_faces, faces)
    # nothing to add: the path is deleted (not left from an earlier cycle)
    pv.draw_verdict(vis, _NoUnion(_DrawingVerdict(**fields)), static_region=static)
    assert "/polyhull/regions/dynamic" not in vis.object_paths()
    # without the static region: the whole region, as before (region_dynamic is None)
    vis = pv.StaticVisualizer()
    pv.draw_verdict(vis, verdict)
    whole = _decode(
        _json(vis, "/polyhull/regions/dynamic")["geometries"][0]["data"]["attributes"]["position"]["array"], np.float32
    ).reshape(-1, 3)
    assert whole[:, 0].max() == pytest.approx(3.5, abs=1e-6)  # the static box is part of it


@dataclass(frozen=True)
class _UnseenVerdict(_DrawingVerdict):
    """The monitor's verdict also draws its pieces that hold no reading apart."""

    unseen: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))

    def region_unseen_drawing(self) -> tuple[np.ndarray, np.ndarray]:
        return self.unseen


def test_pieces_without_a_reading_are_drawn_paler_and_with_the_region_in_the_demo(cell: Cell) -> None:
    """``region_unseen_drawing()`` (a dropout's rays) goes to ``regions/unseen`` in the
    style's paler colour, apart from the dynamic region's saturated one; the demo's
    animation draws both as the cycle's region; with nothing unseen the path is deleted."""
    seen_box, unseen_box = _box([1.0, 1.0, 0.0], [0.4, 0.4, 1.0]), _box([2.0, 2.0, 0.2], [0.05, 0.05, 0.3])
    (sv, sf), (uv, uf) = (
        (np.asarray(b.to_mesh().vert_properties)[:, :3], np.asarray(b.to_mesh().tri_verts)) for b in (seen_box, unseen_box)
    )
    static = _box([3.0, 3.0, 0.0], [0.5, 0.5, 0.3])
    base = _verdict(region=seen_box + unseen_box + static)
    fields = {f: getattr(base, f) for f in base.__dataclass_fields__}
    fields["region_dynamic"] = None
    verdict = _UnseenVerdict(**fields, drawing=(sv, sf), unseen=(uv, uf))
    vis = pv.StaticVisualizer()
    pv.draw_verdict(vis, _NoUnion(verdict), static_region=static)
    unseen = _json(vis, "/polyhull/regions/unseen")
    drawn = _decode(unseen["geometries"][0]["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3)
    np.testing.assert_allclose(drawn, uv.astype(np.float32))
    colour = unseen["materials"][0]["color"]
    assert colour == pv.STYLE.region_unseen != pv.STYLE.region == _json(vis, "/polyhull/regions/dynamic")["materials"][0]["color"]
    pv.draw_verdict(vis, _NoUnion(_UnseenVerdict(**fields, drawing=(sv, sf))), static_region=static)
    assert "/polyhull/regions/unseen" not in vis.object_paths()
    recorder = pv.DemoRecorder(cell, robot=FakeRobot(), static_region=static)
    for k in range(2):
        recorder.add_cycle(0.5 * k, [0.1 * k, 0.0], [], verdict)
    geometry = _json(recorder.build(), "/polyhull/anim/region/1")["geometries"][0]
    drawn = _decode(geometry["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3)
    np.testing.assert_allclose(drawn, np.concatenate([sv, uv]).astype(np.float32))


def test_removed_components_of_pieces_are_drawn_from_their_pieces() -> None:
    """A removed component made of pieces (the monitor's) is drawn from its hexahedra as they
    are, without building its union; one given as a manifold, from the manifold."""
    from polyhull.distance import hexahedra_triangles
    from polyhull.engine.dynamic_rules import LazyMesh
    from polyhull.plausibility import RemovedComponent

    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    # a box in the pieces' vertex order: the near face (z = 0) 0-3 around, the far face 4-7
    box = corners[[0, 2, 6, 4, 1, 3, 7, 5]]
    pieces = np.stack([box * 0.2 + [1.0, 1.0, 0.0], box * 0.2 + [1.1, 1.1, 0.1], box * 0.2 + [3.0, 3.0, 0.0]])

    def never(idx: np.ndarray) -> m3.Manifold:
        raise AssertionError("the union was built")

    lazy = RemovedComponent("too small", 0.016, np.zeros(3), LazyMesh(never, np.array([0, 1]), pieces))
    whole = RemovedComponent("flying", 0.008, np.zeros(3), _box([4.0, 4.0, 2.0], [0.2, 0.2, 0.2]))
    verdict = replace(_verdict(), removed=(lazy, whole))
    vis = pv.StaticVisualizer()
    pv.draw_verdict(vis, verdict)
    geometry = _json(vis, "/polyhull/regions/removed/0_too small")["geometries"][0]
    drawn = _decode(geometry["data"]["attributes"]["position"]["array"], np.float32).reshape(-1, 3)
    want_v, want_f = hexahedra_triangles(pieces[:2])
    np.testing.assert_allclose(drawn, want_v.astype(np.float32))
    np.testing.assert_array_equal(_decode(geometry["data"]["index"]["array"], np.uint32).reshape(-1, 3), want_f)
    # each hexahedron's triangles close its surface
    tm = trimesh.Trimesh(*hexahedra_triangles(pieces[:1]), process=False)
    assert tm.is_watertight and abs(tm.volume) == pytest.approx(0.008)
    other = _decode(_json(vis, "/polyhull/regions/removed/1_flying")["geometries"][0]["data"]["attributes"]["position"]["array"], np.float32)
    assert len(other) == 3 * 8  # the manifold's box: 8 vertices
