"""Readers and writers of ROS CameraInfo YAML and Open3D PinholeCameraIntrinsic JSON."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.camera import Intrinsics
from polyhull.errors import CameraError
from polyhull.intrinsics_io import (
    parse_open3d_intrinsics,
    parse_ros_camera_info,
    read_intrinsics_file,
    read_open3d_intrinsics,
    read_ros_camera_info,
    write_open3d_intrinsics,
    write_ros_camera_info,
)

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "cameras"

# A calibration file as `camera_calibration` (ROS) writes it, with round values.
ROS_YAML = """\
image_width: 640
image_height: 480
camera_name: head_camera
camera_matrix:
  rows: 3
  cols: 3
  data: [525, 0, 319.5, 0, 520.25, 239.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0, 0, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [525, 0, 319.5, 0, 0, 520.25, 239.5, 0, 0, 0, 1, 0]
"""


def test_ros_yaml_round_values(tmp_path: Path) -> None:
    path = tmp_path / "head_camera.yaml"
    path.write_text(ROS_YAML)
    k = read_ros_camera_info(path)
    assert k == Intrinsics(width=640, height=480, fx=525.0, fy=520.25, cx=319.5, cy=239.5)
    assert isinstance(k.width, int) and isinstance(k.height, int)
    assert read_intrinsics_file(path) == k


def test_ros_message_dump_forms() -> None:
    """`rostopic echo` (ROS 1: K, D, width, height) and ROS 2 (k, d) dumps are read too."""
    ros1 = {
        "header": {"frame_id": "cam"},
        "height": 240,
        "width": 320,
        "distortion_model": "plumb_bob",
        "D": [0.0, 0.0, 0.0, 0.0, 0.0],
        "K": [262.5, 0.0, 159.5, 0.0, 262.5, 119.5, 0.0, 0.0, 1.0],
        "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    }
    ros2 = {
        "height": 240,
        "width": 320,
        "distortion_model": "",
        "d": [],
        "k": [262.5, 0.0, 159.5, 0.0, 262.5, 119.5, 0.0, 0.0, 1.0],
    }
    expected = Intrinsics(width=320, height=240, fx=262.5, fy=262.5, cx=159.5, cy=119.5)
    assert parse_ros_camera_info(ros1) == expected
    assert parse_ros_camera_info(ros2) == expected


def test_ros_yaml_distortion_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "distorted.yaml"
    path.write_text(ROS_YAML.replace("data: [0, 0, 0, 0, 0]", "data: [-0.28, 0.07, 0.0, 0.0, 0.0]"))
    with pytest.raises(CameraError) as info:
        read_ros_camera_info(path)
    message = str(info.value)
    assert "distorted.yaml" in message
    assert "distortion_coefficients" in message
    assert "Brown-Conrady" in message and "rectify" in message
    assert "-0.28" in message


def test_ros_yaml_fisheye_model_is_rejected() -> None:
    data = {
        "width": 320,
        "height": 240,
        "K": [262.5, 0.0, 159.5, 0.0, 262.5, 119.5, 0.0, 0.0, 1.0],
        "distortion_model": "equidistant",
        "D": [0.0, 0.0, 0.0, 0.0],
    }
    with pytest.raises(CameraError, match="equidistant"):
        parse_ros_camera_info(data, "fisheye.yaml")


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"image_width": 0}, "image_width"),
        ({"image_height": 480.5}, "image_height"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 0, 319.5, 0, 525, 239.5]}}, "6 data"),
        ({"camera_matrix": [525, 0, 319.5, 0, 525, 239.5]}, "9 values"),
        ({"camera_matrix": {"rows": 3, "cols": 4, "data": [1.0] * 9}}, "rows x cols"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [0, 0, 319.5, 0, 525, 239.5, 0, 0, 1]}}, "fx"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 0, 319.5, 0, -525, 239.5, 0, 0, 1]}}, "fy"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 2, 319.5, 0, 525, 239.5, 0, 0, 1]}}, "skew"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 0, 319.5, 0, 525, 239.5, 0, 0, 2]}}, "pinhole"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 0, float("nan"), 0, 525, 239.5, 0, 0, 1]}}, "finite"),
        ({"camera_matrix": {"rows": 3, "cols": 3, "data": [525, 0, "x", 0, 525, 239.5, 0, 0, 1]}}, "number"),
    ],
)
def test_ros_invalid_fields(change: dict[str, object], fragment: str) -> None:
    import yaml

    data = yaml.safe_load(ROS_YAML)
    data.update(change)
    with pytest.raises(CameraError, match=fragment) as info:
        parse_ros_camera_info(data, "cam.yaml")
    assert str(info.value).startswith("cam.yaml: ")


def test_ros_missing_fields_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="image_width"):
        parse_ros_camera_info({"camera_matrix": {"data": [1] * 9}}, "cam.yaml")
    with pytest.raises(CameraError, match="camera_matrix"):
        parse_ros_camera_info({"image_width": 640, "image_height": 480}, "cam.yaml")
    with pytest.raises(CameraError, match="mapping"):
        parse_ros_camera_info([1, 2, 3], "cam.yaml")
    opencv = tmp_path / "opencv.yaml"
    opencv.write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n")
    with pytest.raises(CameraError, match="opencv.yaml"):
        read_ros_camera_info(opencv)
    with pytest.raises(CameraError, match="not found"):
        read_ros_camera_info(tmp_path / "absent.yaml")


def test_open3d_column_major(tmp_path: Path) -> None:
    """fx = m[0], fy = m[4], cx = m[6], cy = m[7]; a row-major reading gives cx = cy = 0."""
    path = tmp_path / "o3d.json"
    path.write_text(
        json.dumps(
            {
                "width": 640,
                "height": 480,
                "intrinsic_matrix": [600.0, 0.0, 0.0, 0.0, 500.0, 0.0, 320.5, 240.25, 1.0],
            }
        )
    )
    k = read_open3d_intrinsics(path)
    assert (k.fx, k.fy, k.cx, k.cy) == (600.0, 500.0, 320.5, 240.25)
    assert (k.width, k.height) == (640, 480)
    assert read_intrinsics_file(path) == k


def test_open3d_row_major_file_is_named(tmp_path: Path) -> None:
    path = tmp_path / "rowmajor.json"
    path.write_text(
        json.dumps(
            {
                "width": 640,
                "height": 480,
                "intrinsic_matrix": [600.0, 0.0, 320.5, 0.0, 500.0, 240.25, 0.0, 0.0, 1.0],
            }
        )
    )
    with pytest.raises(CameraError) as info:
        read_open3d_intrinsics(path)
    assert "rowmajor.json" in str(info.value)
    assert "row-major" in str(info.value) and "column-major" in str(info.value)


def test_open3d_nested_parameters_and_errors() -> None:
    nested = {
        "class_name": "PinholeCameraParameters",
        "extrinsic": [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0],
        "intrinsic": {
            "width": 320,
            "height": 240,
            "intrinsic_matrix": [262.5, 0.0, 0.0, 0.0, 262.5, 0.0, 159.5, 119.5, 1.0],
        },
    }
    assert parse_open3d_intrinsics(nested) == Intrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
    with pytest.raises(CameraError, match="intrinsic_matrix"):
        parse_open3d_intrinsics({"width": 320, "height": 240}, "x.json")
    with pytest.raises(CameraError, match="9 values"):
        parse_open3d_intrinsics(
            {"width": 320, "height": 240, "intrinsic_matrix": [1.0, 0.0]}, "x.json"
        )
    with pytest.raises(CameraError, match="fx"):
        parse_open3d_intrinsics(
            {"width": 320, "height": 240, "intrinsic_matrix": [0.0, 0, 0, 0, 262.5, 0, 159.5, 119.5, 1]},
            "x.json",
        )
    with pytest.raises(CameraError, match="width"):
        parse_open3d_intrinsics(
            {"width": -1, "height": 240, "intrinsic_matrix": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1]},
            "x.json",
        )


def test_unknown_suffix_and_bad_json(tmp_path: Path) -> None:
    txt = tmp_path / "cam.txt"
    txt.write_text("525 525 319.5 239.5")
    with pytest.raises(CameraError, match=r"\.yaml"):
        read_intrinsics_file(txt)
    bad = tmp_path / "cam.json"
    bad.write_text("{not json")
    with pytest.raises(CameraError, match="cam.json"):
        read_intrinsics_file(bad)


def test_fixture_files_describe_the_same_camera() -> None:
    ros = read_intrinsics_file(FIXTURES / "small_sw.yaml")
    o3d = read_intrinsics_file(FIXTURES / "small_ne.json")
    assert ros == o3d == Intrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)


@st.composite
def intrinsics(draw: st.DrawFn) -> Intrinsics:
    width = draw(st.integers(1, 8192))
    height = draw(st.integers(1, 8192))
    focal = st.floats(0.5, 1e5, allow_nan=False, allow_infinity=False)
    return Intrinsics(
        width=width,
        height=height,
        fx=draw(focal),
        fy=draw(focal),
        cx=draw(st.floats(-0.5, width - 0.5)),
        cy=draw(st.floats(-0.5, height - 0.5)),
    )


@settings(max_examples=60, deadline=None)
@given(k=intrinsics())
def test_round_trip_both_formats(k: Intrinsics) -> None:
    with tempfile.TemporaryDirectory() as directory:
        ros = write_ros_camera_info(k, Path(directory) / "cam.yaml")
        o3d = write_open3d_intrinsics(k, Path(directory) / "cam.json")
        assert read_intrinsics_file(ros) == k
        assert read_intrinsics_file(o3d) == k
