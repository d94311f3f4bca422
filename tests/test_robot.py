"""Tests of polyhull.robot and of the fixture arm (fixtures/robots/make_arm6.py)."""

from __future__ import annotations

import importlib.util
import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yourdfpy
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.cell import RobotSpec
from polyhull.errors import GeometryError, PolyhullError, RobotError
from polyhull.robot import CYLINDER_SECTIONS, LIMIT_TOLERANCE, Robot, resolve_mesh_filename

REPO = Path(__file__).resolve().parents[1]
ARM6 = REPO / "fixtures" / "robots" / "arm6.urdf"
ARM6_DATA = REPO / "polyhull" / "data" / "robots" / "arm6.urdf"
GENERATOR = REPO / "fixtures" / "robots" / "make_arm6.py"

# The offsets designed in make_arm6.py [m], summed by hand.
FLANGE_AT_ZERO = np.array([0.25 + 0.30 + 0.45 + 0.13, 0.0, 0.30 + 0.375 + 0.70 + 0.035])
TCP_AT_ZERO = FLANGE_AT_ZERO + [0.15, 0.0, 0.0]
J2_AT_ZERO = np.array([0.25, 0.0, 0.675])


_ARM = Robot.from_urdf(ARM6)
_ARM_YOURDFPY = yourdfpy.URDF.load(str(ARM6), build_scene_graph=True, load_meshes=False)


@pytest.fixture(scope="module")
def arm() -> Robot:
    return _ARM


def _generator():
    spec = importlib.util.spec_from_file_location("make_arm6", GENERATOR)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through it
    spec.loader.exec_module(module)
    return module


def _yaw_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, z]
    return T


# The arm's limits, known before the fixture is built (hypothesis needs them at import).
_ARM_LIMITS = [(-185, 185), (-95, 155), (-175, 70), (-350, 350), (-125, 125), (-350, 350)]
arm_q = st.tuples(
    *(st.floats(math.radians(lo), math.radians(hi), allow_nan=False) for lo, hi in _ARM_LIMITS)
).map(np.array)


def _write_urdf(tmp_path: Path, body: str, name: str = "robot.urdf") -> Path:
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?>\n<robot name="test">\n{body}\n</robot>\n')
    return path


_TWO_LINKS = """
  <link name="base"><collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <link name="tip"><collision><geometry><sphere radius="0.1"/></geometry></collision></link>
  <joint name="j" type="revolute"><parent link="base"/><child link="tip"/>
    <origin xyz="0 0 0.5"/><axis xyz="0 0 1"/>
    <limit lower="{lower}" upper="{upper}" velocity="1" effort="1"/></joint>
"""


# ----------------------------------------------------------------------------------------
# The fixture arm and its generator
# ----------------------------------------------------------------------------------------


def test_arm_structure(arm: Robot) -> None:
    assert arm.name == "arm6"
    assert arm.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert arm.dof == 6
    # Links without geometry (flange, tcp) are frames, not collision links.
    assert arm.link_names == (
        "base_link",
        "link_1",
        "link_2",
        "link_3",
        "link_4",
        "link_5",
        "link_6",
        "gripper",
    )
    assert {"flange", "tcp"} <= set(arm.frame_names)
    np.testing.assert_allclose(np.degrees(arm.lower), [lo for lo, _ in _ARM_LIMITS], atol=1e-7)
    np.testing.assert_allclose(np.degrees(arm.upper), [hi for _, hi in _ARM_LIMITS], atol=1e-7)
    np.testing.assert_allclose(np.degrees(arm.velocity), [156, 156, 156, 335, 355, 647], atol=1e-6)
    assert not arm.lower.flags.writeable


def test_generator_is_deterministic_and_committed_files_match(tmp_path: Path) -> None:
    gen = _generator()
    a, b = tmp_path / "a", tmp_path / "b"
    gen.write(a)
    gen.write(b)
    for rel in ("arm6.urdf", "meshes/gripper.stl"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
        fixture = (ARM6.parent / rel).read_bytes()
        assert fixture == (a / rel).read_bytes(), f"re-run {GENERATOR.name}: {rel} is stale"
        assert fixture == (ARM6_DATA.parent / rel).read_bytes(), f"data copy of {rel} differs"
    assert (ARM6.parent / "arm6.urdf").read_text() == gen.build_urdf()
    assert len(gen.build_gripper_stl()) < 50_000
    # The script's own command line writes into --out.
    assert gen.main(["--out", str(tmp_path / "c")]) == 0
    assert (tmp_path / "c" / "arm6.urdf").read_text() == gen.build_urdf()


def test_gripper_stl_is_a_closed_binary_mesh_in_millimetres() -> None:
    data = (ARM6.parent / "meshes" / "gripper.stl").read_bytes()
    assert not data.startswith(b"solid")  # binary, not ASCII
    (count,) = struct.unpack("<I", data[80:84])
    assert len(data) == 84 + 50 * count
    mesh = trimesh.load(ARM6.parent / "meshes" / "gripper.stl", force="mesh")
    assert mesh.is_watertight and mesh.is_winding_consistent
    # U-shaped profile: palm 120 x 60 mm, two 20 x 100 mm fingers, 80 mm wide.
    assert mesh.volume == pytest.approx((120 * 60 + 2 * 20 * 100) * 80)
    np.testing.assert_allclose(mesh.bounds, [[-60, -40, 0], [60, 40, 160]])


def test_every_urdf_shape_kind_is_used() -> None:
    urdf = yourdfpy.URDF.load(str(ARM6), build_scene_graph=False, load_meshes=False)
    kinds = set()
    for link in urdf.robot.links:
        for c in link.collisions:
            kinds |= {k for k in ("box", "cylinder", "sphere", "mesh") if getattr(c.geometry, k)}
    assert kinds == {"box", "cylinder", "sphere", "mesh"}


def test_data_copy_loads_with_its_mesh() -> None:
    robot = Robot.from_urdf(ARM6_DATA)
    assert robot.link_names[-1] == "gripper"
    assert robot.link_geometry()["gripper"].volume == pytest.approx(0.000896)


# ----------------------------------------------------------------------------------------
# Forward kinematics
# ----------------------------------------------------------------------------------------


def test_fk_at_zero_is_the_sum_of_the_offsets(arm: Robot) -> None:
    frames = arm.frame_transforms(np.zeros(6))
    np.testing.assert_allclose(frames["base_link"], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(frames["link_2"][:3, 3], J2_AT_ZERO, atol=1e-12)
    np.testing.assert_allclose(frames["link_6"][:3, 3], FLANGE_AT_ZERO, atol=1e-12)
    np.testing.assert_allclose(frames["flange"][:3, 3], FLANGE_AT_ZERO, atol=1e-12)
    np.testing.assert_allclose(frames["tcp"][:3, 3], TCP_AT_ZERO, atol=1e-9)
    # tool0 convention: the flange frame's z axis points out of the flange (+x at q = 0).
    np.testing.assert_allclose(frames["flange"][:3, 2], [1, 0, 0], atol=1e-9)


@pytest.mark.parametrize(
    ("q_deg", "flange"),
    [
        # joint_1 by 90 deg rotates the flange about z: (x, y) -> (-y, x).
        ((90, 0, 0, 0, 0, 0), (0.0, 1.13, 1.41)),
        ((-90, 0, 0, 0, 0, 0), (0.0, -1.13, 1.41)),
        # Upper arm forward-horizontal, forearm straight: everything at J2 height + 0.035.
        ((0, 90, -90, 0, 0, 0), (0.25 + 0.70 + 0.88, 0.0, 0.675 + 0.035)),
        # Forearm straight up over the upper arm.
        ((0, 0, -90, 0, 0, 0), (0.25 - 0.035, 0.0, 0.675 + 0.70 + 0.88)),
        # Wrist bent down by 90 deg: the flange hangs 0.13 below the wrist centre.
        ((0, 0, 0, 0, 90, 0), (1.0, 0.0, 1.41 - 0.13)),
        # Forearm roll by 90 deg turns that bend sideways (about the forearm axis x).
        ((0, 0, 0, 90, 90, 0), (1.0, 0.13, 1.41)),
    ],
)
def test_fk_hand_computed_poses(arm: Robot, q_deg: tuple, flange: tuple) -> None:
    frames = arm.frame_transforms(np.radians(q_deg))
    np.testing.assert_allclose(frames["flange"][:3, 3], flange, atol=1e-12)


@given(q=arm_q, x=st.floats(-5, 5), y=st.floats(-5, 5), z=st.floats(0, 2), yaw=st.floats(-4, 4))
@settings(max_examples=40, deadline=None)
def test_base_pose_moves_everything(
    q: np.ndarray, x: float, y: float, z: float, yaw: float
) -> None:
    robot = _ARM.with_base(_yaw_pose(x, y, z, yaw))
    T_world_base = robot.T_world_base
    base_frames = _ARM.frame_transforms(q)
    world_frames = robot.frame_transforms(q)
    for name, T_base_frame in base_frames.items():
        np.testing.assert_allclose(world_frames[name], T_world_base @ T_base_frame, atol=1e-12)
    # The world-frame geometry follows.
    for (name_w, piece_w), (name_b, piece_b) in zip(
        robot.convex_pieces_world(q), _ARM.convex_pieces_world(q), strict=True
    ):
        assert name_w == name_b
        np.testing.assert_allclose(
            piece_w, piece_b @ T_world_base[:3, :3].T + T_world_base[:3, 3], atol=1e-12
        )


def test_joint_1_rotates_every_link_about_z(arm: Robot) -> None:
    q = np.array([0.0, 0.3, -0.5, 0.7, 0.4, -1.0])
    turned = q + [np.pi / 2, 0, 0, 0, 0, 0]
    Rz = _yaw_pose(0, 0, 0, np.pi / 2)
    a, b = arm.frame_transforms(q), arm.frame_transforms(turned)
    for name in arm.frame_names:
        if name != "base_link":
            np.testing.assert_allclose(b[name], Rz @ a[name], atol=1e-12)


@given(q=arm_q)
@settings(max_examples=60, deadline=None)
def test_fk_matches_yourdfpy(q: np.ndarray) -> None:
    _ARM_YOURDFPY.update_cfg(q)
    frames = _ARM.frame_transforms(q)
    for name in _ARM.frame_names:
        expected = _ARM_YOURDFPY.get_transform(name, _ARM_YOURDFPY.base_link)
        np.testing.assert_allclose(frames[name], expected, atol=1e-7, rtol=0)


@given(qs=st.lists(arm_q, min_size=1, max_size=5))
@settings(max_examples=20, deadline=None)
def test_batch_fk_equals_single_fk(qs: list[np.ndarray]) -> None:
    batch = _ARM.frame_transforms(np.stack(qs))
    for i, q in enumerate(qs):
        single = _ARM.frame_transforms(q)
        for name in _ARM.frame_names:
            np.testing.assert_allclose(batch[name][i], single[name], atol=1e-14)


_MIXED = """
  <link name="base"><collision><geometry><box size="0.3 0.3 0.1"/></geometry></collision></link>
  <link name="slider"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <link name="spinner"><visual><geometry><cylinder radius="0.05" length="0.2"/></geometry></visual></link>
  <link name="finger_a"><collision><geometry><box size="0.02 0.02 0.1"/></geometry></collision></link>
  <link name="finger_b"><collision><geometry><box size="0.02 0.02 0.1"/></geometry></collision></link>
  <link name="marker"/>
  <joint name="slide" type="prismatic"><parent link="base"/><child link="slider"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.3 -0.2 0.9"/><axis xyz="0 0.6 0.8"/>
    <limit lower="-0.5" upper="0.7" velocity="0.5" effort="10"/></joint>
  <joint name="spin" type="continuous"><parent link="slider"/><child link="spinner"/>
    <origin xyz="0 0 0.1" rpy="1.1 0.4 -0.3"/><axis xyz="0.48 0.6 0.64"/></joint>
  <joint name="grip" type="revolute"><parent link="spinner"/><child link="finger_a"/>
    <origin xyz="0.03 0 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-0.4" upper="0.4" velocity="1" effort="1"/></joint>
  <joint name="grip_mimic" type="revolute"><parent link="spinner"/><child link="finger_b"/>
    <origin xyz="-0.03 0 0.1" rpy="0 0 3.14159"/><axis xyz="0 1 0"/>
    <limit lower="-0.4" upper="0.4" velocity="1" effort="1"/>
    <mimic joint="grip" multiplier="-0.5" offset="0.1"/></joint>
  <joint name="mark" type="fixed"><parent link="base"/><child link="marker"/>
    <origin xyz="1 2 3" rpy="0.1 0.2 0.3"/></joint>
"""


@given(
    slide=st.floats(-0.5, 0.7),
    spin=st.floats(-20, 20),
    grip=st.floats(-0.4, 0.4),
)
@settings(max_examples=30, deadline=None)
def test_fk_matches_yourdfpy_for_prismatic_continuous_mimic_and_fixed(
    tmp_path_factory: pytest.TempPathFactory, slide: float, spin: float, grip: float
) -> None:
    path = tmp_path_factory.getbasetemp() / "mixed.urdf"
    if not path.exists():
        _write_urdf(path.parent, _MIXED, "mixed.urdf")
    robot = Robot.from_urdf(path)
    reference = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
    assert robot.joint_names == tuple(reference.actuated_joint_names) == ("slide", "spin", "grip")
    q = np.array([slide, spin, grip])
    reference.update_cfg(q)
    frames = robot.frame_transforms(q)
    for name in robot.frame_names:
        np.testing.assert_allclose(
            frames[name], reference.get_transform(name, reference.base_link), atol=1e-7, rtol=0
        )


def test_mixed_joint_types(tmp_path: Path) -> None:
    robot = Robot.from_urdf(_write_urdf(tmp_path, _MIXED))
    assert robot.lower[1] == -np.inf and robot.upper[1] == np.inf  # continuous
    assert robot.velocity[1] == np.inf  # no <limit>
    # Links without collision fall back to their visual geometry; marker has none.
    assert "spinner" in robot.link_names and "marker" not in robot.link_names
    # The prismatic joint moves along its (unit) axis, expressed in the joint frame.
    a = robot.frame_transforms([0.0, 0.0, 0.0])["slider"]
    b = robot.frame_transforms([0.5, 0.0, 0.0])["slider"]
    np.testing.assert_allclose(b[:3, 3] - a[:3, 3], a[:3, :3] @ [0, 0.3, 0.4], atol=1e-12)


def test_reach_is_about_1_6_m() -> None:
    rng = np.random.default_rng(7)
    q = rng.uniform(_ARM.lower, _ARM.upper, size=(20_000, 6))
    # Include the straight arm, where the reach is largest.
    q[0] = [0.0, 0.0, -np.pi / 2 + math.atan2(0.035, 0.88), 0.0, 0.0, 0.0]
    frames = _ARM.frame_transforms(q)
    point = frames["link_2"][:, :3, 3]
    axis = frames["link_2"][:, :3, 1]  # joint_2 turns about link_2's y axis
    rel = frames["flange"][:, :3, 3] - point
    distance = np.linalg.norm(rel - np.einsum("ni,ni->n", rel, axis)[:, None] * axis, axis=1)
    reach = distance.max()
    # About 1.58 m: at least the straight arm; at most upper arm + forearm + wrist, each at full length.
    assert reach >= 0.70 + math.hypot(0.88, 0.035) - 1e-9
    assert reach <= 0.70 + math.hypot(0.75, 0.035) + 0.13 + 1e-9


# ----------------------------------------------------------------------------------------
# Joint vectors
# ----------------------------------------------------------------------------------------


def test_check_q_accepts_limits_and_returns_float64(arm: Robot) -> None:
    q = arm.check_q([0, 0, 0, 0, 0, 0])
    assert q.dtype == np.float64 and q.shape == (6,)
    arm.check_q(arm.lower)
    arm.check_q(arm.upper + LIMIT_TOLERANCE / 2)
    assert arm.check_q(np.zeros((3, 6))).shape == (3, 6)


def test_check_q_outside_limits_names_joint_value_and_limits(arm: Robot) -> None:
    q = np.zeros(6)
    q[2] = 1.5
    with pytest.raises(
        RobotError, match=r"joint_3 = 1\.5 is outside its limits \[-3\.05433, 1\.22173\]"
    ):
        arm.check_q(q)
    with pytest.raises(RobotError, match="joint_1"):
        arm.frame_transforms(arm.lower - [1e-3, 0, 0, 0, 0, 0])
    batch = np.zeros((4, 6))
    batch[3, 4] = -3.0
    with pytest.raises(RobotError, match=r"joint_5 = -3\.0 \(row 3\)"):
        arm.check_q(batch)


@pytest.mark.parametrize(
    "q", [np.zeros(5), np.zeros(7), np.zeros((2, 5)), np.zeros((1, 1, 6)), 0.0]
)
def test_check_q_wrong_length(arm: Robot, q: object) -> None:
    with pytest.raises(RobotError, match="q must have 6 values"):
        arm.check_q(q)  # type: ignore[arg-type]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_check_q_non_finite(arm: Robot, bad: float) -> None:
    q = np.zeros(6)
    q[3] = bad
    with pytest.raises(RobotError, match="joint_4 = .* is not finite"):
        arm.check_q(q)
    with pytest.raises(RobotError, match="joint_4"):
        arm.link_meshes(q)


def test_check_q_rejects_text(arm: Robot) -> None:
    with pytest.raises(RobotError, match="q must be numbers"):
        arm.check_q(["a"] * 6)


def test_world_queries_need_one_joint_vector(arm: Robot) -> None:
    with pytest.raises(RobotError, match="one joint vector"):
        arm.mesh(np.zeros((2, 6)))


# ----------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------


def test_link_geometry_is_watertight_with_positive_volume(arm: Robot) -> None:
    geometry = arm.link_geometry()
    assert tuple(geometry) == arm.link_names
    for name, mesh in geometry.items():
        assert mesh.is_watertight and mesh.is_winding_consistent, name
        assert mesh.volume > 0, name
    # Copies: changing one does not change the robot.
    geometry["link_1"].apply_translation([1, 0, 0])
    np.testing.assert_allclose(
        arm.link_geometry()["link_1"].bounds[0, 0], -0.21 / math.cos(math.pi / 16), atol=1e-9
    )


def _exact_surface_points(
    kind: str, size: tuple, rng: np.random.Generator, n: int = 400
) -> np.ndarray:
    """Points on the surface of the exact URDF primitive (shape frame), incl. its extremes."""
    if kind == "box":
        half = np.asarray(size) / 2
        p = rng.uniform(-half, half, size=(n, 3))
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n)) * half[axis]
        corners = (
            np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        )
        return np.vstack([p, corners])
    if kind == "cylinder":
        radius, length = size
        angle = np.concatenate([rng.uniform(0, 2 * np.pi, n), np.pi * np.arange(64) / 32])
        z = np.concatenate([rng.uniform(-length / 2, length / 2, n), np.full(64, length / 2)])
        rim = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), z])
        disc_r = radius * np.sqrt(rng.uniform(0, 1, n))
        disc_a = rng.uniform(0, 2 * np.pi, n)
        cap = np.column_stack(
            [disc_r * np.cos(disc_a), disc_r * np.sin(disc_a), np.full(n, -length / 2)]
        )
        return np.vstack([rim, cap])
    if kind == "sphere":
        d = rng.normal(size=(4 * n, 3))
        return size[0] * d / np.linalg.norm(d, axis=1, keepdims=True)
    raise AssertionError(kind)


def _inside_hull(vertices: np.ndarray, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    hull = trimesh.convex.convex_hull(vertices)
    offset = np.einsum("fi,fi->f", hull.face_normals, hull.triangles[:, 0])
    return np.all(points @ hull.face_normals.T - offset <= tol, axis=1)


def test_convex_pieces_contain_the_exact_shapes(arm: Robot) -> None:
    rng = np.random.default_rng(3)
    pieces = arm.link_convex_pieces()
    geometry = arm.link_geometry()
    for name in arm.link_names:
        shapes = arm._collision[name]  # the parsed URDF shapes
        assert len(pieces[name]) == len(shapes)
        for shape, piece in zip(shapes, pieces[name], strict=True):
            if shape.kind == "mesh":
                points = np.asarray(shape.mesh.vertices)
            else:
                points = _exact_surface_points(shape.kind, shape.size, rng)
            points = points @ shape.T_link_shape[:3, :3].T + shape.T_link_shape[:3, 3]
            assert np.all(_inside_hull(piece, points)), (name, shape.kind)
            # The link's merged mesh contains them too (signed distance >= 0 inside).
            sd = trimesh.proximity.signed_distance(geometry[name], points)
            assert sd.min() >= -1e-9, (name, shape.kind, sd.min())


def test_circumscribed_shapes_are_tight(arm: Robot) -> None:
    """Conservative, but not wastefully: each piece stays within 2 % of the exact shape."""
    for name in arm.link_names:
        for shape, piece in zip(arm._collision[name], arm.link_convex_pieces()[name], strict=True):
            local = (piece - shape.T_link_shape[:3, 3]) @ shape.T_link_shape[:3, :3]
            if shape.kind == "cylinder":
                r = np.linalg.norm(local[:, :2], axis=1)
                np.testing.assert_allclose(r, shape.size[0] / math.cos(math.pi / CYLINDER_SECTIONS))
                assert len(piece) == 2 * CYLINDER_SECTIONS
            elif shape.kind == "sphere":
                r = np.linalg.norm(local, axis=1)
                assert np.all(r >= shape.size[0]) and np.all(r <= 1.02 * shape.size[0])
            elif shape.kind == "box":
                assert len(piece) == 8
                np.testing.assert_allclose(
                    np.abs(local), np.broadcast_to(np.asarray(shape.size) / 2, (8, 3))
                )


@given(
    kind=st.sampled_from(["box", "cylinder", "sphere"]),
    dims=st.tuples(st.floats(0.01, 2.0), st.floats(0.01, 2.0), st.floats(0.01, 2.0)),
    xyz=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)),
    rpy=st.tuples(st.floats(-3.2, 3.2), st.floats(-3.2, 3.2), st.floats(-3.2, 3.2)),
)
@settings(max_examples=25, deadline=None)
def test_pieces_contain_random_primitives(
    tmp_path_factory: pytest.TempPathFactory, kind: str, dims: tuple, xyz: tuple, rpy: tuple
) -> None:
    size = {"box": dims, "cylinder": dims[:2], "sphere": dims[:1]}[kind]
    attrs = {
        "box": f'size="{dims[0]!r} {dims[1]!r} {dims[2]!r}"',
        "cylinder": f'radius="{dims[0]!r}" length="{dims[1]!r}"',
        "sphere": f'radius="{dims[0]!r}"',
    }[kind]
    body = f"""
  <link name="a"><collision><origin xyz="{" ".join(map(repr, xyz))}" rpy="{" ".join(map(repr, rpy))}"/>
    <geometry><{kind} {attrs}/></geometry></collision></link>
  <link name="b"/>
  <joint name="j" type="continuous"><parent link="a"/><child link="b"/></joint>"""
    path = _write_urdf(tmp_path_factory.mktemp("prim"), body)
    robot = Robot.from_urdf(path)
    (shape,) = robot._collision["a"]
    points = _exact_surface_points(kind, size, np.random.default_rng(0), n=200)
    points = points @ shape.T_link_shape[:3, :3].T + shape.T_link_shape[:3, 3]
    (piece,) = robot.link_convex_pieces()["a"]
    assert np.all(_inside_hull(piece, points, tol=1e-9 * max(dims)))
    mesh = robot.link_geometry()["a"]
    assert mesh.is_watertight
    assert trimesh.proximity.signed_distance(mesh, points).min() >= -1e-9 * max(dims)


def test_nonconvex_mesh_is_over_approximated_by_its_hull(arm: Robot) -> None:
    (piece,) = arm.link_convex_pieces()["gripper"]
    hull = trimesh.convex.convex_hull(piece)
    # The U-shaped gripper (0.000896 m^3) becomes its 0.12 x 0.08 x 0.16 m bounding hull.
    assert hull.volume == pytest.approx(0.12 * 0.08 * 0.16)
    assert arm.link_geometry()["gripper"].volume == pytest.approx(0.000896)  # closed: kept exact


def test_pieces_are_read_only(arm: Robot) -> None:
    piece = arm.link_convex_pieces()["link_2"][0]
    with pytest.raises(ValueError, match="read-only"):
        piece[0, 0] = 1.0


@given(q=arm_q)
@settings(max_examples=20, deadline=None)
def test_world_geometry_follows_link_transforms(q: np.ndarray) -> None:
    robot = _ARM.with_base(_yaw_pose(3.0, 3.0, 0.0, 0.4))
    transforms = robot.link_transforms(q)
    geometry = robot.link_geometry()
    meshes = robot.link_meshes(q)
    assert tuple(meshes) == robot.link_names
    for name, mesh in meshes.items():
        T = transforms[name]
        np.testing.assert_allclose(
            mesh.vertices, geometry[name].vertices @ T[:3, :3].T + T[:3, 3], atol=1e-12
        )
        assert mesh.volume == pytest.approx(geometry[name].volume)
    world_pieces = robot.convex_pieces_world(q)
    expected = [
        (name, piece @ transforms[name][:3, :3].T + transforms[name][:3, 3])
        for name, pieces in robot.link_convex_pieces().items()
        for piece in pieces
    ]
    assert [n for n, _ in world_pieces] == [n for n, _ in expected]
    for (_, got), (_, want) in zip(world_pieces, expected, strict=True):
        np.testing.assert_allclose(got, want, atol=1e-12)
    whole = robot.mesh(q)
    np.testing.assert_allclose(
        whole.vertices, np.vstack([m.vertices for m in meshes.values()]), atol=1e-12
    )
    assert whole.volume == pytest.approx(sum(m.volume for m in meshes.values()))


def test_visual_meshes_are_coloured_and_placed(arm: Robot) -> None:
    q = np.array([0.4, 0.1, -0.3, 0.0, 0.5, 0.0])
    visuals = arm.visual_meshes(q)
    assert tuple(visuals) == arm.link_names
    # Visual equals collision geometry here, so the bounds agree with the collision meshes.
    collision = arm.link_meshes(q)
    for name in arm.link_names:
        np.testing.assert_allclose(visuals[name].bounds, collision[name].bounds, atol=1e-9)
    orange = visuals["link_2"].visual.face_colors[0]
    np.testing.assert_array_equal(orange, [255, 107, 0, 255])


def test_from_spec_places_the_base_and_checks_q() -> None:
    spec = RobotSpec(
        urdf=ARM6, base=(3.0, 2.0, 0.1), base_yaw=0.5, q=(0.0, -0.6, 1.2, 0.0, 0.8, 0.0)
    )
    robot = Robot.from_spec(spec)
    np.testing.assert_allclose(robot.T_world_base, spec.T_world_base)
    np.testing.assert_allclose(
        robot.frame_transforms(np.zeros(6))["flange"][:3, 3],
        _yaw_pose(3.0, 2.0, 0.1, 0.5)[:3, :3] @ FLANGE_AT_ZERO + [3.0, 2.0, 0.1],
        atol=1e-12,
    )
    with pytest.raises(RobotError, match=r"robot\.q: .*joint_3 = 2\.0"):
        Robot.from_spec(RobotSpec(urdf=ARM6, q=(0, 0, 2.0, 0, 0, 0)))
    with pytest.raises(RobotError, match=r"robot\.q: .*6 values"):
        Robot.from_spec(RobotSpec(urdf=ARM6, q=(0, 0, 0)))


def test_with_base_shares_geometry(arm: Robot) -> None:
    moved = arm.with_base(_yaw_pose(1, 2, 0, 0))
    assert moved._geometry is arm._geometry
    assert arm.T_world_base[0, 3] == 0.0 and moved.T_world_base[0, 3] == 1.0
    assert not moved.T_world_base.flags.writeable


# ----------------------------------------------------------------------------------------
# Validation
# ----------------------------------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RobotError, match="nothere.urdf' does not exist"):
        Robot.from_urdf(tmp_path / "nothere.urdf")


def test_unparsable_xml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.urdf"
    path.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(RobotError, match=r"broken\.urdf: not a valid XML file"):
        Robot.from_urdf(path)


def test_root_must_be_robot(tmp_path: Path) -> None:
    path = tmp_path / "sdf.urdf"
    path.write_text("<sdf><model name='x'/></sdf>")
    with pytest.raises(RobotError, match=r"sdf\.urdf: the root element must be <robot>"):
        Robot.from_urdf(path)


def test_structurally_broken_urdf(tmp_path: Path) -> None:
    path = _write_urdf(
        tmp_path,
        '<link name="a"/><link name="b"/><joint name="j" type="fixed"><child link="b"/></joint>',
    )
    with pytest.raises(RobotError, match=r"robot\.urdf: cannot parse the URDF"):
        Robot.from_urdf(path)


def test_no_actuated_joints(tmp_path: Path) -> None:
    body = """<link name="a"><collision><geometry><box size="1 1 1"/></geometry></collision></link>
    <link name="b"/><joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>"""
    with pytest.raises(RobotError, match=r"robot\.urdf: the URDF has no actuated joint"):
        Robot.from_urdf(_write_urdf(tmp_path, body))


def test_lower_above_upper(tmp_path: Path) -> None:
    path = _write_urdf(tmp_path, _TWO_LINKS.format(lower=1.0, upper=-1.0))
    with pytest.raises(
        RobotError, match=r"robot\.urdf: joint 'j' <limit>: lower 1\.0 > upper -1\.0"
    ):
        Robot.from_urdf(path)


def test_revolute_without_limits(tmp_path: Path) -> None:
    body = _TWO_LINKS.format(lower=0, upper=0).replace(
        '<limit lower="0" upper="0" velocity="1" effort="1"/>', ""
    )
    with pytest.raises(
        RobotError, match="joint 'j' <limit>: a revolute joint needs lower and upper"
    ):
        Robot.from_urdf(_write_urdf(tmp_path, body))


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('velocity="1"', 'velocity="0"', "velocity must be > 0"),
        ('upper="1"', 'upper="inf"', "lower and upper must be finite"),
        ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>', r"joint 'j' <axis xyz>"),
        ('type="revolute"', 'type="floating"', "type 'floating' is not supported"),
        (
            '<child link="tip"/>',
            '<child link="nope"/>',
            r"joint 'j' <child link='nope'>: no such link",
        ),
        ('<origin xyz="0 0 0.5"/>', '<origin xyz="0 nan 0.5"/>', r"joint 'j' <origin>"),
        (
            '<sphere radius="0.1"/>',
            '<sphere radius="-0.1"/>',
            r"link 'tip' collision\[0\] <sphere radius>",
        ),
        (
            '<box size="0.2 0.2 0.2"/>',
            '<box size="0.2 0.2"/>',
            r"link 'base' collision\[0\] <box size>",
        ),
    ],
)
def test_invalid_fields_are_named(tmp_path: Path, old: str, new: str, message: str) -> None:
    body = _TWO_LINKS.format(lower=-1, upper=1)
    assert old in body
    with pytest.raises(RobotError, match=message):
        Robot.from_urdf(_write_urdf(tmp_path, body.replace(old, new)))


def test_tree_errors(tmp_path: Path) -> None:
    body = _TWO_LINKS.format(lower=-1, upper=1)
    extra = '<link name="stray"/>'
    with pytest.raises(RobotError, match=r"exactly one root link, found \['base', 'stray'\]"):
        Robot.from_urdf(_write_urdf(tmp_path, body + extra))
    twice = body + '<joint name="k" type="fixed"><parent link="base"/><child link="tip"/></joint>'
    with pytest.raises(RobotError, match="link 'tip' is already the child of joint 'j'"):
        Robot.from_urdf(_write_urdf(tmp_path, twice))
    dup = body + '<link name="tip"/>'
    with pytest.raises(RobotError, match=r"link names must be unique, repeated: \['tip'\]"):
        Robot.from_urdf(_write_urdf(tmp_path, dup))


def test_bad_mimic(tmp_path: Path) -> None:
    body = _MIXED.replace('<mimic joint="grip"', '<mimic joint="mark"')
    with pytest.raises(RobotError, match=r"joint 'grip_mimic' <mimic joint='mark'>"):
        Robot.from_urdf(_write_urdf(tmp_path, body))


def test_no_geometry(tmp_path: Path) -> None:
    body = _TWO_LINKS.format(lower=-1, upper=1)
    body = body.replace('<collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision>', "")
    body = body.replace('<collision><geometry><sphere radius="0.1"/></geometry></collision>', "")
    with pytest.raises(RobotError, match="no link has collision or visual geometry"):
        Robot.from_urdf(_write_urdf(tmp_path, body))


def test_bad_base_pose(tmp_path: Path) -> None:
    T = np.eye(4)
    T[0, 0] = 2.0
    with pytest.raises(RobotError, match="T_world_base rotation is not orthonormal"):
        Robot.from_urdf(ARM6, T)
    with pytest.raises(RobotError, match="T_world_base must be a"):
        Robot.from_urdf(ARM6, np.eye(3))


def _mesh_urdf(tmp_path: Path, filename: str, name: str = "robot.urdf") -> Path:
    body = f"""
  <link name="base"><collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <link name="tool"><collision><geometry><mesh filename="{filename}" scale="0.001 0.001 0.001"/></geometry></collision></link>
  <joint name="j" type="continuous"><parent link="base"/><child link="tool"/></joint>"""
    return _write_urdf(tmp_path, body, name)


def test_mesh_filenames_resolve_relative_and_package(tmp_path: Path) -> None:
    # A ROS package layout: pkg/urdf/robot.urdf and pkg/meshes/gripper.stl.
    (tmp_path / "arm_description" / "meshes").mkdir(parents=True)
    (tmp_path / "arm_description" / "urdf").mkdir()
    stl = tmp_path / "arm_description" / "meshes" / "gripper.stl"
    stl.write_bytes((ARM6.parent / "meshes" / "gripper.stl").read_bytes())
    urdf_dir = tmp_path / "arm_description" / "urdf"
    for filename in (
        "package://arm_description/meshes/gripper.stl",
        "../meshes/gripper.stl",
        f"file://{stl}",
        str(stl),
    ):
        path = _mesh_urdf(urdf_dir, filename)
        assert resolve_mesh_filename(filename, path).resolve() == stl.resolve()
        robot = Robot.from_urdf(path)
        assert robot.link_geometry()["tool"].volume == pytest.approx(0.000896)


def test_missing_mesh_names_link_and_file(tmp_path: Path) -> None:
    with pytest.raises(RobotError, match=r"link 'tool'.*mesh file 'meshes/none\.stl' not found"):
        Robot.from_urdf(_mesh_urdf(tmp_path, "meshes/none.stl"))
    with pytest.raises(RobotError, match="unsupported scheme"):
        Robot.from_urdf(_mesh_urdf(tmp_path, "http://example.com/a.stl"))


def test_empty_and_non_finite_meshes_name_link_and_file(tmp_path: Path) -> None:
    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(PolyhullError, match=r"link 'tool'.*empty\.obj"):
        Robot.from_urdf(_mesh_urdf(tmp_path, "empty.obj"))
    (tmp_path / "nan.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
    )
    with pytest.raises(GeometryError, match=r"link 'tool'.*nan\.obj.*non-finite"):
        Robot.from_urdf(_mesh_urdf(tmp_path, "nan.obj"))
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    with pytest.raises(GeometryError, match=r"link 'tool'.*flat\.obj.*no volume"):
        Robot.from_urdf(_mesh_urdf(tmp_path, "flat.obj"))
