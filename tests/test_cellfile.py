"""Loading TOML cell files: the fixture cells, every key, and every validation error path."""

from __future__ import annotations

import dataclasses
import math
import shutil
import typing
from pathlib import Path

import numpy as np
import pytest
import trimesh

from polyhull.camera import Intrinsics, look_at_rotation
from polyhull.cell import (
    Cell,
    EntryArea,
    PlausibilityParams,
    ReconstructionParams,
    SafetyParams,
)
from polyhull.cellfile import (
    CAMERA_KEYS,
    cell_from_mapping,
    default_cell_path,
    load_cell,
    rpy_to_rotation,
)
from polyhull.errors import CellError, PolyhullError
from polyhull.intrinsics_io import write_open3d_intrinsics, write_ros_camera_info

ROOT = Path(__file__).resolve().parents[1]
CELLS = ROOT / "fixtures" / "cells"
ARM6 = ROOT / "fixtures" / "robots" / "arm6.urdf"

# A valid cell touching every section; each error case below breaks one entry of it.
BASE = """\
name = "test cell"

[zone]
min = [0.0, 0.0, 0.0]
max = [4.0, 4.0, 3.0]

[[cameras]]
name = "a"
type = "depth"
resolution = [64, 48]
intrinsics = [50.0, 50.0, 31.5, 23.5]
position = [0.2, 0.2, 2.8]
look_at = [2.0, 2.0, 0.5]
range = [0.3, 8.0]
noise = 0.003

[[cameras]]
name = "b"
type = "color"
intrinsics_file = "cam_b.json"
position = [3.8, 3.8, 2.8]
quaternion = [0.0, 1.0, 0.0, 0.0]
range = [0.2, 6.0]

[[obstacles]]
name = "table"
box = { center = [1.0, 3.0, 0.4], size = [1.2, 0.6, 0.8] }

[[obstacles]]
name = "part"
mesh = "part.stl"
pose = { position = [3.0, 1.0, 0.0], rpy = [0.0, 0.0, 0.5] }
solid = false

[safety]
reaction_time = 0.1
profile = "iso"

[reconstruction]
block = 8
k_of_n = 1

[plausibility]
min_volume = 0.001

[[plausibility.entry_areas]]
name = "door"
min = [0.0, 0.0, 0.0]
max = [1.0, 0.2, 2.0]

[[mounting]]
name = "ceiling"
origin = [0.0, 0.0, 2.9]
edge_u = [4.0, 0.0, 0.0]
edge_v = [0.0, 4.0, 0.0]
"""

ROBOT = f"""
[robot]
urdf = "{ARM6.as_posix()}"
base = [2.0, 2.0, 0.0]
q = [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]
"""


@pytest.fixture
def cell_dir(tmp_path: Path) -> Path:
    """A directory with the base cell's side files: intrinsics and a mesh."""
    write_open3d_intrinsics(Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5), tmp_path / "cam_b.json")
    write_ros_camera_info(Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5), tmp_path / "cam_b.yaml")
    distorted = (tmp_path / "cam_b.yaml").read_text().replace(
        "data: [0.0, 0.0, 0.0, 0.0, 0.0]", "data: [-0.2, 0.05, 0.0, 0.0, 0.0]"
    )
    (tmp_path / "cam_distorted.yaml").write_text(distorted)
    (tmp_path / "notes.txt").write_text("not intrinsics")
    trimesh.creation.box(extents=[0.4, 0.4, 0.4]).export(tmp_path / "part.stl")
    open_mesh = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) != 0)
    open_mesh.export(tmp_path / "open.stl")
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\n")
    (tmp_path / "part.xyz123").write_text("not a mesh")
    return tmp_path


def write_cell(directory: Path, text: str, name: str = "cell.toml") -> Path:
    path = directory / name
    path.write_text(text)
    return path


# -- the fixture cells ----------------------------------------------------------------------


def test_paper_cell() -> None:
    cell = load_cell(CELLS / "paper_cell.toml")
    assert isinstance(cell, Cell)
    assert cell.name == "paper cell"
    assert cell.zone.volume == pytest.approx(126.0)
    assert len(cell.cameras) == 4
    for cam in cell.cameras:
        assert cam.kind == "depth"
        assert (cam.intrinsics.width, cam.intrinsics.height) == (640, 480)
        assert cam.intrinsics == Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
        assert (cam.near, cam.far, cam.noise, cam.tolerance_sigmas) == (0.3, 10.0, 0.0015, 3.0)
        # Ceiling corner, looking down at a point 1.6 m over the robot's base.
        assert cam.center[2] == pytest.approx(3.3)
        optical_axis = cam.T_world_camera[:3, 2]
        assert optical_axis[2] == pytest.approx(-1.7 / np.hypot(1.7, 2.8 * np.sqrt(2.0)))
        _, z = cam.project(np.array([[3.0, 3.0, 0.6]]))
        assert z[0] > 0
    # two tables, a rack and the four walls just outside the zone
    assert [o.name for o in cell.obstacles] == [
        "table_south", "table_east", "rack", "wall_south", "wall_north", "wall_west", "wall_east"
    ]
    assert all(o.solid for o in cell.obstacles)
    for wall in cell.obstacles[3:]:
        lo, hi = wall.mesh.bounds
        inside = np.minimum(hi, cell.zone.max) - np.maximum(lo, cell.zone.min)
        assert np.any(inside <= 1e-9)  # touches the zone at most on a face
    assert cell.robot is not None
    assert cell.robot.urdf == ARM6.resolve()
    assert cell.robot.base == (3.0, 3.0, 0.0)
    assert cell.robot.q == (0.0, -0.6, 1.2, 0.0, 0.8, 0.0)
    # Tables are at least 1.5 m from the robot base.
    for obstacle in cell.obstacles[:3]:
        lo, hi = obstacle.mesh.bounds
        nearest = np.clip([3.0, 3.0], lo[:2], hi[:2])
        assert np.hypot(*(nearest - [3.0, 3.0])) >= 1.5
    assert cell.safety == SafetyParams()
    assert cell.reconstruction == ReconstructionParams()
    assert [m.name for m in cell.mounting] == [
        "ceiling", "wall_south", "wall_east", "wall_north", "wall_west",
    ]
    assert cell.plausibility.entry_areas[0].name == "door_south"
    assert cell.path == (CELLS / "paper_cell.toml").resolve()


def test_paper_cell_cameras_see_around_and_over_the_robot() -> None:
    """The floor within 1 m of the robot's base is in at least three cameras' images and
    ranges, and the space over the base up to 3 m in all four (no blind cap over the arm)."""
    cell = load_cell(CELLS / "paper_cell.toml")
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    ring = np.column_stack([3 + np.cos(angles), 3 + np.sin(angles), np.zeros_like(angles)])
    column = np.column_stack([np.full(26, 3.0), np.full(26, 3.0), np.linspace(0.5, 3.0, 26)])

    def seen(points: np.ndarray) -> np.ndarray:
        n = np.zeros(len(points), dtype=int)
        for cam in cell.cameras:
            uv, z = cam.project(points)
            w, h = cam.intrinsics.width, cam.intrinsics.height
            n += (uv[:, 0] > 0) & (uv[:, 0] < w - 1) & (uv[:, 1] > 0) & (uv[:, 1] < h - 1) & (z > cam.near) & (z < cam.far)
        return n

    assert seen(ring).min() >= 3
    assert seen(column).min() == 4


def test_small_cell_reads_both_intrinsics_formats() -> None:
    cell = load_cell(CELLS / "small_cell.toml")
    assert cell.zone.volume == pytest.approx(22.5)
    assert [c.name for c in cell.cameras] == ["sw", "ne"]
    expected = Intrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
    assert all(c.intrinsics == expected for c in cell.cameras)
    assert len(cell.obstacles) == 1
    assert cell.robot is not None and cell.robot.base == (1.5, 1.5, 0.0)
    assert cell.safety.profile == "ramp"
    assert cell.safety.reaction_time == SafetyParams().reaction_time


def test_color8_cell() -> None:
    cell = load_cell(CELLS / "color8_cell.toml")
    assert cell.zone.volume == pytest.approx(126.0)
    assert len(cell.cameras) == 8
    assert all(c.kind == "color" and c.shape == (480, 640) for c in cell.cameras)
    assert len(cell.obstacles) == 7  # two tables, a rack and four walls
    assert cell.robot is not None
    assert cell.reconstruction.k_of_n == 2
    # Every camera sees the robot base.
    for cam in cell.cameras:
        uv, z = cam.project(np.array([[3.0, 3.0, 0.0]]))
        assert z[0] > 0 and 0 < uv[0, 0] < 639 and 0 < uv[0, 1] < 479


def test_embedded_default_cell_is_the_paper_cell() -> None:
    path = default_cell_path()
    assert path.is_file() and path.name == "paper_cell.toml"
    default = load_cell(path)
    paper = load_cell(CELLS / "paper_cell.toml")
    assert default.robot is not None and paper.robot is not None
    assert default.robot.urdf == (path.parent / "robots" / "arm6.urdf").resolve()
    assert dataclasses.replace(default.robot, urdf=paper.robot.urdf) == paper.robot
    assert default.zone == paper.zone and default.name == paper.name
    for a, b in zip(default.cameras, paper.cameras, strict=True):
        assert a.name == b.name and a.intrinsics == b.intrinsics
        np.testing.assert_array_equal(a.T_world_camera, b.T_world_camera)
    # The two files differ only in the robot path.
    fixture_lines = (CELLS / "paper_cell.toml").read_text().splitlines()
    default_lines = path.read_text().splitlines()
    differing = [(a, b) for a, b in zip(fixture_lines, default_lines, strict=True) if a != b]
    assert differing == [('urdf = "../robots/arm6.urdf"', 'urdf = "robots/arm6.urdf"')]


# -- the base cell, every key -------------------------------------------------------------


def test_base_cell_every_key(cell_dir: Path) -> None:
    cell = load_cell(write_cell(cell_dir, BASE))
    a, b = cell.cameras
    assert a.kind == "depth" and b.kind == "color"
    assert b.intrinsics == Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)
    # quaternion [0, 1, 0, 0]: 180 deg about x, the camera looks straight down.
    np.testing.assert_allclose(b.T_world_camera[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(b.center, [3.8, 3.8, 2.8])
    np.testing.assert_allclose(
        a.T_world_camera[:3, :3], look_at_rotation(np.array([0.2, 0.2, 2.8]), np.array([2.0, 2.0, 0.5]))
    )
    assert (b.near, b.far) == (0.2, 6.0)
    assert b.noise == 0.003  # the Camera default
    table, part = cell.obstacles
    np.testing.assert_allclose(table.mesh.bounds, [[0.4, 2.7, 0.0], [1.6, 3.3, 0.8]])
    assert table.solid and not part.solid
    assert cell.robot is None
    assert cell.plausibility.entry_areas[0].max == (1.0, 0.2, 2.0)
    assert cell.mounting[0].edge_u == (4.0, 0.0, 0.0)


def test_parameter_sections_default_when_omitted(tmp_path: Path) -> None:
    text = '[zone]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n'
    cell = load_cell(write_cell(tmp_path, text, "minimal_cell.toml"))
    assert cell.name == "minimal_cell"
    assert cell.zone.min == (0.0, 0.0, 0.0)
    assert cell.cameras == () and cell.obstacles == () and cell.robot is None
    assert cell.safety == SafetyParams()
    assert cell.reconstruction == ReconstructionParams()
    assert cell.plausibility == PlausibilityParams()


def test_every_parameter_field_is_a_key(tmp_path: Path) -> None:
    """Sections are read from the dataclass fields: every field can be set from the file."""
    text = """
[zone]
min = [0, 0, 0]
max = [1, 1, 1]
[safety]
profile = "ramp"
human_speed = 1.7
human_speed_close = 2.1
close_distance = 0.4
reaction_time = 0.15
stopping_time = 0.35
robot_speed_max = 1.0
stopping_distance = 0.2
intrusion_distance = 0.1
sensor_uncertainty = 0.06
robot_uncertainty = 0.03
ramp_stop_distance = 0.6
ramp_full_distance = 2.5
max_frame_age = 0.3
cycle_deadline = 0.06
min_free_share = 0.3
invalid_jump = 0.2
background_mismatch = 0.1
joint_state_max_age = 0.2
[reconstruction]
block = 4
tile = 4
k_of_n = 1
shadow_memory = false
[plausibility]
flying = false
too_small = false
too_thin = false
entry = true
teleport = true
support_eps = 0.02
min_volume = 0.002
shell_thickness = 0.03
human_speed_max = 2.5
floor_shell = false
keep_at_boundary = false
floor_shell_height = 0.3
floor_shell_margin = 0.4
standing_depth = 0.2
small_gaps = false
detection_size = 0.05
"""
    cell = load_cell(write_cell(tmp_path, text))
    for section, params in (
        ("safety", cell.safety),
        ("reconstruction", cell.reconstruction),
        ("plausibility", cell.plausibility),
    ):
        defaults = type(params)()
        for f in dataclasses.fields(params):
            if f.name in ("entry_areas", "k_of_n"):  # k_of_n > 1 needs cameras
                continue
            assert getattr(params, f.name) != getattr(defaults, f.name), f"{section}.{f.name}"
    assert cell.safety.stopping_distance == 0.2
    assert isinstance(cell.reconstruction.block, int)


def test_a_field_added_later_is_a_key(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A new parameter field works without loader changes, with its default when omitted."""
    import polyhull.cellfile as cellfile

    @dataclasses.dataclass(frozen=True)
    class ExtendedSafety(SafetyParams):
        brake_test_period: float = 3600.0

    @dataclasses.dataclass(frozen=True)
    class ExtendedPlausibility(PlausibilityParams):
        mode: typing.Literal["collaborative", "fenced"] = "collaborative"
        zones: tuple[EntryArea, ...] = ()
        max_parts: int | None = None

    monkeypatch.setattr(cellfile, "SafetyParams", ExtendedSafety)
    monkeypatch.setattr(cellfile, "PlausibilityParams", ExtendedPlausibility)
    zone = "[zone]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n"
    cell = load_cell(write_cell(tmp_path, zone))
    assert isinstance(cell.safety, ExtendedSafety)
    assert isinstance(cell.plausibility, ExtendedPlausibility)
    assert cell.safety.brake_test_period == 3600.0
    assert (cell.plausibility.mode, cell.plausibility.zones) == ("collaborative", ())
    assert cell.plausibility.max_parts is None
    text = zone + (
        "[safety]\nbrake_test_period = 60\n"
        '[plausibility]\nmode = "fenced"\nmax_parts = 4\n'
        '[[plausibility.zones]]\nname = "z"\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n'
    )
    cell = load_cell(write_cell(tmp_path, text))
    assert isinstance(cell.safety, ExtendedSafety)
    assert cell.safety.brake_test_period == 60.0
    assert isinstance(cell.plausibility, ExtendedPlausibility)
    assert (cell.plausibility.mode, cell.plausibility.max_parts) == ("fenced", 4)
    assert cell.plausibility.zones == (EntryArea("z", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)),)
    broken = [
        ("[safety]\nbrake_test_period = 'daily'\n", r"safety\.brake_test_period: expected a number, got 'daily'"),
        ('[plausibility]\nmode = "open"\n', r"plausibility\.mode: expected one of 'collaborative', 'fenced', got 'open'"),
        ("[plausibility]\nmax_parts = 2.5\n", r"plausibility\.max_parts: expected an integer .*, got 2\.5"),
        (
            '[[plausibility.zones]]\nname = "z"\nmin = [0]\nmax = [1, 1, 1]\n',
            r"plausibility\.zones\[0\]\.min: expected a list of 3 finite numbers, got \[0\]",
        ),
    ]
    for section, pattern in broken:
        with pytest.raises(CellError, match=pattern):
            load_cell(write_cell(tmp_path, zone + section))


def test_mesh_obstacle_with_pose(tmp_path: Path) -> None:
    """A mesh placed by position + rpy (and the same by quaternion) has the right world bounds."""
    mesh = trimesh.creation.box(extents=[1.0, 0.4, 0.2])
    mesh.apply_translation([0.5, 0.2, 0.1])  # local bounds [0, 1] x [0, 0.4] x [0, 0.2]
    (tmp_path / "meshes").mkdir()
    mesh.export(tmp_path / "meshes" / "bar.stl")
    half = math.sqrt(0.5)
    text = """
[zone]
min = [0, 0, 0]
max = [4, 4, 3]
[[obstacles]]
name = "bar_rpy"
mesh = "meshes/bar.stl"
pose = { position = [2.0, 1.0, 0.5], rpy = [0.0, 0.0, 1.5707963267948966] }
[[obstacles]]
name = "bar_quaternion"
mesh = "meshes/bar.stl"
pose = { position = [2.0, 1.0, 0.5], quaternion = [QUATERNION] }
[[obstacles]]
name = "bar_scaled"
mesh = "meshes/bar.stl"
scale = [2.0, 1.0, 3.0]
pose = { position = [0.5, 0.5, 0.0] }
[[obstacles]]
name = "bar_rotated_box"
box = { center = [0.5, 0.2, 0.1], size = [1.0, 0.4, 0.2] }
pose = { position = [2.0, 1.0, 0.5], rpy = [0.0, 0.0, 1.5707963267948966] }
""".replace("QUATERNION", f"{half!r}, 0.0, 0.0, {half!r}")
    cell = load_cell(write_cell(tmp_path, text))
    # Yaw 90 deg: local x -> world y, local y -> world -x.
    expected = [[2.0 - 0.4, 1.0, 0.5], [2.0, 2.0, 0.7]]
    for name in ("bar_rpy", "bar_quaternion", "bar_rotated_box"):
        obstacle = next(o for o in cell.obstacles if o.name == name)
        np.testing.assert_allclose(obstacle.mesh.bounds, expected, atol=1e-9)
        assert obstacle.manifold().volume() == pytest.approx(0.08, rel=1e-5)
    scaled = cell.obstacles[2]
    np.testing.assert_allclose(scaled.mesh.bounds, [[0.5, 0.5, 0.0], [2.5, 0.9, 0.6]], atol=1e-9)


def test_rpy_matches_urdf_convention() -> None:
    roll, pitch, yaw = 0.3, -0.4, 1.1
    rx = trimesh.transformations.rotation_matrix(roll, [1, 0, 0])[:3, :3]
    ry = trimesh.transformations.rotation_matrix(pitch, [0, 1, 0])[:3, :3]
    rz = trimesh.transformations.rotation_matrix(yaw, [0, 0, 1])[:3, :3]
    np.testing.assert_allclose(rpy_to_rotation(np.array([roll, pitch, yaw])), rz @ ry @ rx)


def test_cell_from_mapping_and_purity(cell_dir: Path) -> None:
    """Loading the same file twice gives equal values; a failed load leaves nothing behind."""
    path = write_cell(cell_dir, BASE)
    first = load_cell(path)
    broken = write_cell(cell_dir, BASE.replace("block = 8", "block = 0"), "broken.toml")
    with pytest.raises(CellError):
        load_cell(broken)
    second = load_cell(path)
    assert first.zone == second.zone and first.safety == second.safety
    np.testing.assert_array_equal(first.cameras[0].T_world_camera, second.cameras[0].T_world_camera)
    import tomllib

    data = tomllib.loads(BASE)
    third = cell_from_mapping(data, path)
    assert [c.name for c in third.cameras] == ["a", "b"]
    assert tomllib.loads(BASE) == data  # the mapping was not modified


# -- every validation error path ----------------------------------------------------------

# (id, text replaced in BASE, replacement, entry named in the message, fragment of the value)
CASES = [
    ("top-level-unknown", 'name = "test cell"', 'nmae = "test cell"', "nmae", "'test cell'"),
    ("name-type", 'name = "test cell"', "name = 5", "name", "5"),
    ("zone-missing", "[zone]\nmin = [0.0, 0.0, 0.0]\nmax = [4.0, 4.0, 3.0]\n", "", "zone", "[zone]"),
    ("zone-min-length", "min = [0.0, 0.0, 0.0]\nmax = [4.0", "min = [0.0, 0.0]\nmax = [4.0", "zone.min", "[0.0, 0.0]"),
    ("zone-max-below-min", "max = [4.0, 4.0, 3.0]", "max = [4.0, 4.0, -3.0]", "zone", "[4.0, 4.0, -3.0]"),
    ("zone-nan", "max = [4.0, 4.0, 3.0]", "max = [4.0, nan, 3.0]", "zone.max", "nan"),
    ("zone-unknown", "max = [4.0, 4.0, 3.0]", "max = [4.0, 4.0, 3.0]\nmid = 1", "zone.mid", "1"),
    ("camera-unknown-key", "position = [0.2, 0.2, 2.8]", "positon = [0.2, 0.2, 2.8]", "cameras[0].positon", "[0.2, 0.2, 2.8]"),
    ("camera-name-missing", 'name = "a"\n', "", "cameras[0].name", "missing"),
    ("camera-name-duplicate", 'name = "b"', 'name = "a"', "cameras[1].name", "'a'"),
    ("camera-type", 'type = "depth"', 'type = "infrared"', "cameras[0].type", "'infrared'"),
    ("intrinsics-zero-fx", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [0.0, 50.0, 31.5, 23.5]", "cameras[0].intrinsics", "[0.0, 50.0, 31.5, 23.5]"),
    ("intrinsics-negative-fy", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [50.0, -50.0, 31.5, 23.5]", "cameras[0].intrinsics", "-50.0"),
    ("intrinsics-inf", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [inf, 50.0, 31.5, 23.5]", "cameras[0].intrinsics", "inf"),
    ("intrinsics-nan", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [50.0, 50.0, nan, 23.5]", "cameras[0].intrinsics", "nan"),
    ("intrinsics-length", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [50.0, 31.5, 23.5]", "cameras[0].intrinsics", "[50.0, 31.5, 23.5]"),
    ("intrinsics-principal-point", "intrinsics = [50.0, 50.0, 31.5, 23.5]", "intrinsics = [50.0, 50.0, 319.5, 23.5]", "cameras[0].intrinsics", "319.5"),
    ("intrinsics-and-file", "intrinsics = [50.0, 50.0, 31.5, 23.5]", 'intrinsics = [50.0, 50.0, 31.5, 23.5]\nintrinsics_file = "cam_b.json"', "cameras[0]", "both"),
    ("intrinsics-neither", 'intrinsics_file = "cam_b.json"\n', "", "cameras[1]", "neither"),
    ("resolution-zero", "resolution = [64, 48]", "resolution = [64, 0]", "cameras[0].resolution", "[64, 0]"),
    ("resolution-float", "resolution = [64, 48]", "resolution = [64.0, 48.0]", "cameras[0].resolution", "[64.0, 48.0]"),
    ("resolution-missing", "resolution = [64, 48]\n", "", "cameras[0].resolution", "missing"),
    ("intrinsics-file-missing", '"cam_b.json"', '"cameras/nope.json"', "cameras[1].intrinsics_file", "nope.json"),
    ("intrinsics-file-suffix", '"cam_b.json"', '"notes.txt"', "cameras[1].intrinsics_file", "notes.txt"),
    ("intrinsics-file-distortion", '"cam_b.json"', '"cam_distorted.yaml"', "cameras[1].intrinsics_file", "-0.2"),
    ("intrinsics-file-resolution", 'intrinsics_file = "cam_b.json"', 'intrinsics_file = "cam_b.json"\nresolution = [640, 480]', "cameras[1].resolution", "[640, 480]"),
    ("position-length", "position = [0.2, 0.2, 2.8]", "position = [0.2, 2.8]", "cameras[0].position", "[0.2, 2.8]"),
    ("position-string", "position = [0.2, 0.2, 2.8]", 'position = "corner"', "cameras[0].position", "'corner'"),
    ("position-missing", "position = [0.2, 0.2, 2.8]\n", "", "cameras[0].position", "missing"),
    ("look-at-parallel-z", "look_at = [2.0, 2.0, 0.5]", "look_at = [0.2, 0.2, 0.5]", "cameras[0].look_at", "[0.2, 0.2, 0.5]"),
    ("look-at-at-position", "look_at = [2.0, 2.0, 0.5]", "look_at = [0.2, 0.2, 2.8]", "cameras[0].look_at", "[0.2, 0.2, 2.8]"),
    ("look-at-and-quaternion", "look_at = [2.0, 2.0, 0.5]", "look_at = [2.0, 2.0, 0.5]\nquaternion = [1.0, 0.0, 0.0, 0.0]", "cameras[0]", "'quaternion': [1.0, 0.0, 0.0, 0.0]"),
    ("look-at-neither", "look_at = [2.0, 2.0, 0.5]\n", "", "cameras[0]", "neither"),
    ("quaternion-not-unit", "quaternion = [0.0, 1.0, 0.0, 0.0]", "quaternion = [0.0, 2.0, 0.0, 0.0]", "cameras[1].quaternion", "[0.0, 2.0, 0.0, 0.0]"),
    ("quaternion-zero", "quaternion = [0.0, 1.0, 0.0, 0.0]", "quaternion = [0.0, 0.0, 0.0, 0.0]", "cameras[1].quaternion", "[0.0, 0.0, 0.0, 0.0]"),
    ("quaternion-length", "quaternion = [0.0, 1.0, 0.0, 0.0]", "quaternion = [1.0, 0.0, 0.0]", "cameras[1].quaternion", "[1.0, 0.0, 0.0]"),
    ("range-near-above-far", "range = [0.3, 8.0]", "range = [8.0, 0.3]", "cameras[0].range", "[8.0, 0.3]"),
    ("range-near-equals-far", "range = [0.3, 8.0]", "range = [2.0, 2.0]", "cameras[0].range", "[2.0, 2.0]"),
    ("range-near-zero", "range = [0.3, 8.0]", "range = [0.0, 8.0]", "cameras[0].range", "[0.0, 8.0]"),
    ("range-far-inf", "range = [0.3, 8.0]", "range = [0.3, inf]", "cameras[0].range", "inf"),
    ("noise-negative", "noise = 0.003", "noise = -0.01", "cameras[0].noise", "-0.01"),
    ("tolerance-sigmas-string", "noise = 0.003", 'noise = 0.003\ntolerance_sigmas = "three"', "cameras[0].tolerance_sigmas", "'three'"),
    ("tolerance-min-negative", "noise = 0.003", "noise = 0.003\ntolerance_min = -0.01", "cameras[0].tolerance_min", "-0.01"),
    ("obstacle-unknown-key", 'name = "part"', 'name = "part"\ncolour = "red"', "obstacles[1].colour", "'red'"),
    ("obstacle-name-duplicate", 'name = "part"', 'name = "table"', "obstacles[1].name", "'table'"),
    ("box-size-zero", "size = [1.2, 0.6, 0.8]", "size = [1.2, 0.0, 0.8]", "obstacles[0].box.size", "[1.2, 0.0, 0.8]"),
    ("box-size-negative", "size = [1.2, 0.6, 0.8]", "size = [1.2, -0.6, 0.8]", "obstacles[0].box.size", "-0.6"),
    ("box-center-length", "center = [1.0, 3.0, 0.4]", "center = [1.0, 3.0]", "obstacles[0].box.center", "[1.0, 3.0]"),
    ("box-unknown-key", "size = [1.2, 0.6, 0.8]", "sise = [1.2, 0.6, 0.8]", "obstacles[0].box.sise", "[1.2, 0.6, 0.8]"),
    ("box-and-mesh", 'mesh = "part.stl"', 'mesh = "part.stl"\nbox = { center = [0, 0, 0], size = [1, 1, 1] }', "obstacles[1]", "both"),
    ("box-scale", "size = [1.2, 0.6, 0.8] }", "size = [1.2, 0.6, 0.8] }\nscale = 2.0", "obstacles[0].scale", "mesh"),
    ("mesh-missing", 'mesh = "part.stl"', 'mesh = "meshes/absent.stl"', "obstacles[1].mesh", "absent.stl"),
    ("mesh-no-triangles", 'mesh = "part.stl"', 'mesh = "empty.obj"', "obstacles[1].mesh", "empty.obj"),
    ("mesh-unreadable", 'mesh = "part.stl"', 'mesh = "part.xyz123"', "obstacles[1].mesh", "part.xyz123"),
    ("mesh-not-closed", 'mesh = "part.stl"', 'mesh = "open.stl"', "obstacles[1].mesh", "closed"),
    ("mesh-scale-negative", 'mesh = "part.stl"', 'mesh = "part.stl"\nscale = -1.0', "obstacles[1].scale", "-1.0"),
    ("pose-rpy-length", "rpy = [0.0, 0.0, 0.5]", "rpy = [0.0, 0.5]", "obstacles[1].pose.rpy", "[0.0, 0.5]"),
    ("pose-rpy-and-quaternion", "rpy = [0.0, 0.0, 0.5]", "rpy = [0.0, 0.0, 0.5], quaternion = [1.0, 0.0, 0.0, 0.0]", "obstacles[1].pose", "quaternion"),
    ("pose-quaternion-not-unit", "rpy = [0.0, 0.0, 0.5]", "quaternion = [1.0, 1.0, 0.0, 0.0]", "obstacles[1].pose.quaternion", "[1.0, 1.0, 0.0, 0.0]"),
    ("pose-unknown-key", "rpy = [0.0, 0.0, 0.5]", "yaw = 0.5", "obstacles[1].pose.yaw", "0.5"),
    ("solid-string", "solid = false", 'solid = "no"', "obstacles[1].solid", "'no'"),
    ("safety-negative", "reaction_time = 0.1", "reaction_time = -0.5", "safety.reaction_time", "-0.5"),
    ("safety-nan", "reaction_time = 0.1", "reaction_time = nan", "safety.reaction_time", "nan"),
    ("safety-string", "reaction_time = 0.1", 'reaction_time = "fast"', "safety.reaction_time", "'fast'"),
    ("safety-profile", 'profile = "iso"', 'profile = "linear"', "safety.profile", "'linear'"),
    ("safety-ramp-order", "reaction_time = 0.1", "ramp_full_distance = 0.3", "safety", "ramp_full_distance"),
    ("safety-optional-type", "reaction_time = 0.1", "stopping_distance = true", "safety.stopping_distance", "True"),
    ("safety-unknown", "reaction_time = 0.1", "reaction_tme = 0.1", "safety.reaction_tme", "0.1"),
    ("reconstruction-block-zero", "block = 8", "block = 0", "reconstruction.block", "0"),
    ("reconstruction-block-float", "block = 8", "block = 8.5", "reconstruction.block", "8.5"),
    ("reconstruction-bool", "block = 8", "shadow_memory = 1", "reconstruction.shadow_memory", "1"),
    ("reconstruction-k-of-n", "k_of_n = 1", "k_of_n = 3", "reconstruction.k_of_n", "3"),
    ("plausibility-negative", "min_volume = 0.001", "min_volume = -0.001", "plausibility.min_volume", "-0.001"),
    ("entry-area-max-below-min", "max = [1.0, 0.2, 2.0]", "max = [1.0, -0.2, 2.0]", "plausibility.entry_areas[0]", "-0.2"),
    ("entry-area-length", "max = [1.0, 0.2, 2.0]", "max = [1.0, 0.2]", "plausibility.entry_areas[0].max", "[1.0, 0.2]"),
    ("entry-area-unknown", 'name = "door"', 'name = "door"\nsize = 1', "plausibility.entry_areas[0].size", "1"),
    ("mounting-degenerate", "edge_v = [0.0, 4.0, 0.0]", "edge_v = [8.0, 0.0, 0.0]", "mounting[0]", "[8.0, 0.0, 0.0]"),
    ("mounting-missing-key", "edge_v = [0.0, 4.0, 0.0]\n", "", "mounting[0].edge_v", "missing"),
]


@pytest.mark.parametrize(
    ("old", "new", "entry", "value"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_broken_entry_is_named(cell_dir: Path, old: str, new: str, entry: str, value: str) -> None:
    assert BASE.count(old) == 1, f"ambiguous or absent replacement {old!r}"
    path = write_cell(cell_dir, BASE.replace(old, new), "broken_cell.toml")
    with pytest.raises(CellError) as info:
        load_cell(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    assert f": {entry}: " in message or f": {entry}." in message, message
    assert value in message, message


@pytest.mark.parametrize(
    ("text", "entry", "value"),
    [
        ("cameras = 3\n", "cameras", "3"),
        ('[cameras]\nname = "a"\n', "cameras", "{'name': 'a'}"),
        ("obstacles = [1, 2]\n", "obstacles", "[1, 2]"),
        ("safety = 3\n", "safety", "3"),
        ("mounting = { name = 'x' }\n", "mounting", "{'name': 'x'}"),
        ("robot = [1]\n", "robot", "[1]"),
    ],
)
def test_section_of_the_wrong_kind(tmp_path: Path, text: str, entry: str, value: str) -> None:
    path = write_cell(tmp_path, text + "[zone]\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n")
    with pytest.raises(CellError) as info:
        load_cell(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {entry}: expected "), message
    assert value in message, message


def test_unknown_key_lists_valid_keys(cell_dir: Path) -> None:
    path = write_cell(cell_dir, BASE.replace('type = "depth"', 'kind = "depth"'))
    with pytest.raises(CellError) as info:
        load_cell(path)
    message = str(info.value)
    assert "cameras[0].kind" in message
    assert all(key in message for key in CAMERA_KEYS)


def test_unknown_key_suggests_the_closest(cell_dir: Path) -> None:
    path = write_cell(cell_dir, BASE.replace("look_at =", "lookat ="))
    with pytest.raises(CellError, match="did you mean 'look_at'"):
        load_cell(path)


def test_look_at_parallel_to_z_explains(cell_dir: Path) -> None:
    path = write_cell(cell_dir, BASE.replace("look_at = [2.0, 2.0, 0.5]", "look_at = [0.2, 0.2, 0.0]"))
    with pytest.raises(CellError, match="parallel to world z"):
        load_cell(path)


def test_missing_mesh_names_the_resolved_path(cell_dir: Path) -> None:
    path = write_cell(cell_dir, BASE.replace('"part.stl"', '"meshes/absent.stl"'))
    with pytest.raises(CellError) as info:
        load_cell(path)
    assert str((cell_dir / "meshes" / "absent.stl").resolve()) in str(info.value)


def test_distortion_in_ros_yaml(cell_dir: Path) -> None:
    path = write_cell(cell_dir, BASE.replace('"cam_b.json"', '"cam_distorted.yaml"'))
    with pytest.raises(CellError) as info:
        load_cell(path)
    message = str(info.value)
    assert "cameras[1].intrinsics_file" in message
    assert "Brown-Conrady" in message and "rectify" in message
    assert "cam_distorted.yaml" in message


def test_missing_and_invalid_files(tmp_path: Path) -> None:
    with pytest.raises(CellError, match="not found") as info:
        load_cell(tmp_path / "absent.toml")
    assert str((tmp_path / "absent.toml").resolve()) in str(info.value)
    bad = write_cell(tmp_path, "name = \n[zone", "bad.toml")
    with pytest.raises(CellError, match="invalid TOML") as info:
        load_cell(bad)
    assert "bad.toml" in str(info.value)


def test_every_error_is_a_cell_error(cell_dir: Path) -> None:
    """Errors of the constructors below (CameraError, GeometryError) never leak unwrapped."""
    for old, new, *_ in [c[1:] for c in CASES]:
        path = write_cell(cell_dir, BASE.replace(old, new), "any.toml")
        try:
            load_cell(path)
        except PolyhullError as exc:
            assert type(exc) is CellError


# -- robot ----------------------------------------------------------------------------------


def test_robot_section(cell_dir: Path) -> None:
    cell = load_cell(write_cell(cell_dir, BASE + ROBOT))
    assert cell.robot is not None
    assert cell.robot.urdf == ARM6.resolve()
    assert cell.robot.base == (2.0, 2.0, 0.0)
    assert cell.robot.padding == 0.05
    assert cell.robot.q == (0.0, -0.6, 1.2, 0.0, 0.8, 0.0)


def test_robot_urdf_relative_to_cell_file(tmp_path: Path) -> None:
    robots = tmp_path / "robots"
    shutil.copytree(ARM6.parent, robots)
    cells = tmp_path / "cells"
    cells.mkdir()
    text = '[zone]\nmin = [0, 0, 0]\nmax = [4, 4, 3]\n[robot]\nurdf = "../robots/arm6.urdf"\n'
    cell = load_cell(write_cell(cells, text))
    assert cell.robot is not None
    assert cell.robot.urdf == (robots / "arm6.urdf").resolve()
    # q omitted: zeros of the robot's joint count.
    assert cell.robot.q == (0.0,) * 6


ROBOT_CASES = [
    ("urdf-missing", f'urdf = "{ARM6.as_posix()}"', 'urdf = "robots/absent.urdf"', "robot.urdf", "absent.urdf"),
    ("urdf-type", f'urdf = "{ARM6.as_posix()}"', "urdf = 3", "robot.urdf", "3"),
    ("base-length", "base = [2.0, 2.0, 0.0]", "base = [2.0, 2.0]", "robot.base", "[2.0, 2.0]"),
    ("padding", "base = [2.0, 2.0, 0.0]", "base = [2.0, 2.0, 0.0]\npadding = 2.0", "robot.padding", "2.0"),
    ("unknown", "base = [2.0, 2.0, 0.0]", "bsae = [2.0, 2.0, 0.0]", "robot.bsae", "[2.0, 2.0, 0.0]"),
    ("q-nan", "q = [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]", "q = [0.0, -0.6, nan, 0.0, 0.8, 0.0]", "robot.q", "nan"),
    ("q-length", "q = [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]", "q = [0.0, -0.6, 1.2]", "robot.q", "[0.0, -0.6, 1.2]"),
    ("q-limit", "q = [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]", "q = [0.0, -0.6, 1.2, 0.0, 3.0, 0.0]", "robot.q", "joint_5"),
]


@pytest.mark.parametrize(
    ("old", "new", "entry", "value"), [c[1:] for c in ROBOT_CASES], ids=[c[0] for c in ROBOT_CASES]
)
def test_broken_robot_entry_is_named(cell_dir: Path, old: str, new: str, entry: str, value: str) -> None:
    text = BASE + ROBOT
    assert text.count(old) == 1
    path = write_cell(cell_dir, text.replace(old, new), "robot_cell.toml")
    with pytest.raises(CellError) as info:
        load_cell(path)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    assert f": {entry}: " in message, message
    assert value in message, message


def test_invalid_urdf_is_named(cell_dir: Path) -> None:
    (cell_dir / "broken.urdf").write_text("<robot name='x'><link name=")
    text = BASE + ROBOT.replace(f'"{ARM6.as_posix()}"', '"broken.urdf"')
    with pytest.raises(CellError) as info:
        load_cell(write_cell(cell_dir, text))
    assert ": robot.urdf: " in str(info.value)
    assert "broken.urdf" in str(info.value)
