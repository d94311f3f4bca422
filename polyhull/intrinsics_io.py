"""Read and write camera intrinsics in the formats of the ROS and Open3D ecosystems.

Two formats are supported, both for undistorted (rectified) pinhole cameras:

- **ROS** ``sensor_msgs/CameraInfo`` as YAML, in the layout of ``camera_calibration_parsers``
  (``image_width``, ``image_height``, ``camera_matrix: {rows, cols, data}``,
  ``distortion_model``, ``distortion_coefficients: {rows, cols, data}``) or as a message dump
  (``width``, ``height``, ``K``/``k``, ``D``/``d``). The camera matrix is **row-major**:
  ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]``.
- **Open3D** ``PinholeCameraIntrinsic`` as JSON (``width``, ``height``, ``intrinsic_matrix``),
  also nested under ``intrinsic`` as in ``PinholeCameraParameters``. The matrix is stored
  **column-major** (Eigen's order): ``[fx, 0, 0, 0, fy, 0, cx, cy, 1]``.

polyhull has no lens distortion model: a file with non-zero Brown-Conrady coefficients is
rejected with a :class:`~polyhull.errors.CameraError` that says to rectify the images first.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .camera import Intrinsics
from .errors import CameraError

__all__ = [
    "INTRINSICS_SUFFIXES",
    "read_intrinsics_file",
    "read_ros_camera_info",
    "read_open3d_intrinsics",
    "parse_ros_camera_info",
    "parse_open3d_intrinsics",
    "write_ros_camera_info",
    "write_open3d_intrinsics",
]

#: File suffixes understood by :func:`read_intrinsics_file`, with the format they select.
INTRINSICS_SUFFIXES: dict[str, str] = {".yaml": "ros", ".yml": "ros", ".json": "open3d"}

# Distortion models of the Brown-Conrady family; all-zero coefficients make them pinhole.
_PINHOLE_COMPATIBLE_MODELS = ("", "none", "plumb_bob", "rational_polynomial")

# Relative tolerance on the structural zeros and the trailing 1 of a camera matrix.
_MATRIX_ATOL = 1e-9


def _number(value: object, source: str, field: str) -> float:
    """A finite number from a parsed file (numeric strings such as ``1e-05`` accepted)."""
    if isinstance(value, bool):
        raise CameraError(f"{source}: {field}: expected a number, got {value!r}")
    if isinstance(value, int | float):
        result = float(value)
    elif isinstance(value, str):
        try:
            result = float(value)
        except ValueError:
            raise CameraError(f"{source}: {field}: expected a number, got {value!r}") from None
    else:
        raise CameraError(f"{source}: {field}: expected a number, got {value!r}")
    if not math.isfinite(result):
        raise CameraError(f"{source}: {field}: expected a finite number, got {value!r}")
    return result


def _size(value: object, source: str, field: str) -> int:
    """A positive integer image size [px]; integral floats (``640.0``) are accepted."""
    number = _number(value, source, field)
    if not number.is_integer() or number <= 0:
        raise CameraError(f"{source}: {field}: expected a positive integer [px], got {value!r}")
    return int(number)


def _numbers(value: object, source: str, field: str) -> list[float]:
    if not isinstance(value, Sequence) or isinstance(value, str | bytes):
        raise CameraError(f"{source}: {field}: expected a list of numbers, got {value!r}")
    return [_number(v, source, f"{field}[{i}]") for i, v in enumerate(value)]


def _first_key(data: Mapping[str, Any], keys: Sequence[str]) -> str | None:
    for key in keys:
        if key in data:
            return key
    return None


def _ros_matrix(data: Mapping[str, Any], keys: Sequence[str], source: str) -> tuple[str, list[float]] | None:
    """The ``data`` list of a ROS matrix entry (``{rows, cols, data}`` or a flat list)."""
    key = _first_key(data, keys)
    if key is None:
        return None
    entry = data[key]
    if isinstance(entry, Mapping):
        if "data" not in entry:
            raise CameraError(f"{source}: {key}: expected a mapping with 'data', got {dict(entry)!r}")
        values = _numbers(entry["data"], source, f"{key}.data")
        rows, cols = entry.get("rows"), entry.get("cols")
        if rows is not None and cols is not None:
            n_rows = _size(rows, source, f"{key}.rows")
            n_cols = _size(cols, source, f"{key}.cols")
            if n_rows * n_cols != len(values):
                raise CameraError(
                    f"{source}: {key}: rows x cols = {n_rows} x {n_cols} does not match "
                    f"{len(values)} data values"
                )
        return f"{key}.data", values
    if entry is None:
        return key, []
    return key, _numbers(entry, source, key)


def _intrinsics(
    width: int, height: int, fx: float, fy: float, cx: float, cy: float, source: str
) -> Intrinsics:
    try:
        return Intrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)
    except CameraError as exc:
        raise CameraError(f"{source}: {exc}") from None


def parse_ros_camera_info(data: object, source: str = "<camera info>") -> Intrinsics:
    """Intrinsics from a parsed ROS ``CameraInfo`` mapping.

    Args:
        data: The mapping loaded from the YAML file.
        source: Name of the file, used in error messages.

    Raises:
        CameraError: A field is missing or malformed, the camera matrix is not a pinhole
            matrix ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]`` (row-major), or the distortion is
            not zero.
    """
    if not isinstance(data, Mapping):
        raise CameraError(
            f"{source}: expected a ROS CameraInfo mapping (image_width, image_height, "
            f"camera_matrix, ...), got {type(data).__name__}"
        )
    width_key = _first_key(data, ("image_width", "width"))
    height_key = _first_key(data, ("image_height", "height"))
    if width_key is None or height_key is None:
        raise CameraError(
            f"{source}: expected keys image_width and image_height (or width and height), "
            f"got keys {sorted(map(str, data))}"
        )
    width = _size(data[width_key], source, width_key)
    height = _size(data[height_key], source, height_key)

    matrix = _ros_matrix(data, ("camera_matrix", "K", "k"), source)
    if matrix is None:
        raise CameraError(
            f"{source}: expected camera_matrix (or K) with 9 values, got keys {sorted(map(str, data))}"
        )
    field, K = matrix
    if len(K) != 9:
        raise CameraError(f"{source}: {field}: expected 9 values (row-major 3x3), got {K!r}")
    fx, skew, cx, _, fy, cy = K[:6]
    structural = (K[3], K[6], K[7], K[8] - 1.0)
    if any(abs(v) > _MATRIX_ATOL for v in structural):
        raise CameraError(
            f"{source}: {field}: expected a row-major pinhole matrix [fx, 0, cx, 0, fy, cy, 0, 0, 1], "
            f"got {K!r}"
        )
    if abs(skew) > _MATRIX_ATOL:
        raise CameraError(f"{source}: {field}: expected zero skew (element [0][1]), got {K!r}")

    model = data.get("distortion_model", "")
    model_name = "" if model is None else str(model).strip().lower()
    if model_name not in _PINHOLE_COMPATIBLE_MODELS:
        raise CameraError(
            f"{source}: distortion_model: expected plumb_bob or rational_polynomial with zero "
            f"coefficients (polyhull models pinhole cameras only), got {model!r}; rectify the "
            "images and give the rectified camera's intrinsics"
        )
    distortion = _ros_matrix(data, ("distortion_coefficients", "D", "d"), source)
    if distortion is not None:
        dfield, coefficients = distortion
        if any(c != 0.0 for c in coefficients):
            raise CameraError(
                f"{source}: {dfield}: Brown-Conrady distortion is not supported, got "
                f"{coefficients!r}; rectify the images (e.g. ROS image_proc) and give the "
                "rectified camera's intrinsics with zero distortion"
            )
    return _intrinsics(width, height, fx, fy, cx, cy, source)


def parse_open3d_intrinsics(data: object, source: str = "<open3d intrinsics>") -> Intrinsics:
    """Intrinsics from a parsed Open3D ``PinholeCameraIntrinsic`` mapping.

    ``intrinsic_matrix`` holds the 3x3 camera matrix in **column-major** order:
    ``fx = m[0]``, ``fy = m[4]``, ``cx = m[6]``, ``cy = m[7]``.

    Args:
        data: The mapping loaded from the JSON file (a ``PinholeCameraParameters`` mapping
            with the intrinsics under ``intrinsic`` is accepted too).
        source: Name of the file, used in error messages.

    Raises:
        CameraError: A field is missing or malformed, or the matrix is not a pinhole matrix
            (a row-major matrix is recognised and named as such).
    """
    if isinstance(data, Mapping) and "intrinsic_matrix" not in data and "intrinsic" in data:
        data = data["intrinsic"]
    if not isinstance(data, Mapping) or not {"width", "height", "intrinsic_matrix"} <= set(data):
        keys = sorted(map(str, data)) if isinstance(data, Mapping) else type(data).__name__
        raise CameraError(
            f"{source}: expected an Open3D PinholeCameraIntrinsic with keys width, height, "
            f"intrinsic_matrix, got {keys}"
        )
    width = _size(data["width"], source, "width")
    height = _size(data["height"], source, "height")
    m = _numbers(data["intrinsic_matrix"], source, "intrinsic_matrix")
    if len(m) != 9:
        raise CameraError(
            f"{source}: intrinsic_matrix: expected 9 values (column-major 3x3), got {m!r}"
        )
    fx, skew_lower, zero_a, skew, fy, zero_b, cx, cy, one = m
    if abs(zero_a) > _MATRIX_ATOL or abs(zero_b) > _MATRIX_ATOL or abs(one - 1.0) > _MATRIX_ATOL:
        hint = (
            " (this looks row-major; Open3D stores the matrix column-major: "
            "[fx, 0, 0, 0, fy, 0, cx, cy, 1])"
            if abs(m[6]) <= _MATRIX_ATOL and abs(m[7]) <= _MATRIX_ATOL
            else ""
        )
        raise CameraError(
            f"{source}: intrinsic_matrix: expected a column-major pinhole matrix "
            f"[fx, 0, 0, 0, fy, 0, cx, cy, 1], got {m!r}{hint}"
        )
    if abs(skew) > _MATRIX_ATOL or abs(skew_lower) > _MATRIX_ATOL:
        raise CameraError(f"{source}: intrinsic_matrix: expected zero skew, got {m!r}")
    return _intrinsics(width, height, fx, fy, cx, cy, source)


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CameraError(f"{path}: intrinsics file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraError(f"{path}: cannot read the intrinsics file: {exc}") from None


def _load_yaml(text: str, source: str) -> object:
    try:
        import yaml
    except ImportError:  # pragma: no cover - pyyaml is a core dependency
        raise CameraError(
            f"{source}: reading ROS CameraInfo YAML needs PyYAML: pip install pyyaml"
        ) from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise CameraError(
            f"{source}: not a valid ROS CameraInfo YAML file (OpenCV FileStorage YAML is not "
            f"supported): {exc}"
        ) from None


def read_ros_camera_info(path: str | os.PathLike[str]) -> Intrinsics:
    """Read a ROS ``CameraInfo`` YAML file (as written by ``camera_calibration_parsers``).

    Args:
        path: The ``.yaml`` file.

    Returns:
        The pinhole intrinsics.

    Raises:
        CameraError: The file is missing or invalid, or has non-zero distortion.
    """
    p = Path(path)
    return parse_ros_camera_info(_load_yaml(_read_text(p), str(p)), str(p))


def read_open3d_intrinsics(path: str | os.PathLike[str]) -> Intrinsics:
    """Read an Open3D ``PinholeCameraIntrinsic`` JSON file (column-major matrix).

    Args:
        path: The ``.json`` file, as written by ``open3d.io.write_pinhole_camera_intrinsic``.

    Returns:
        The pinhole intrinsics.

    Raises:
        CameraError: The file is missing or invalid.
    """
    p = Path(path)
    try:
        data = json.loads(_read_text(p))
    except json.JSONDecodeError as exc:
        raise CameraError(f"{p}: not a valid JSON file: {exc}") from None
    return parse_open3d_intrinsics(data, str(p))


def read_intrinsics_file(path: str | os.PathLike[str]) -> Intrinsics:
    """Read intrinsics from a ROS YAML (``.yaml``, ``.yml``) or Open3D JSON (``.json``) file.

    Raises:
        CameraError: Unknown suffix, missing or invalid file.
    """
    p = Path(path)
    kind = INTRINSICS_SUFFIXES.get(p.suffix.lower())
    if kind == "ros":
        return read_ros_camera_info(p)
    if kind == "open3d":
        return read_open3d_intrinsics(p)
    raise CameraError(
        f"{p}: expected an intrinsics file ending in {', '.join(INTRINSICS_SUFFIXES)} "
        f"(ROS CameraInfo YAML or Open3D JSON), got suffix {p.suffix!r}"
    )


def write_ros_camera_info(
    intrinsics: Intrinsics, path: str | os.PathLike[str], camera_name: str = "camera"
) -> Path:
    """Write ``intrinsics`` as a ROS ``CameraInfo`` YAML file with zero distortion.

    The layout is that of ``camera_calibration_parsers`` (readable by ROS 1 and ROS 2
    camera drivers); floats are written so they read back bit-exactly.

    Returns:
        The path written.
    """
    import yaml

    k = intrinsics
    data = {
        "image_width": int(k.width),
        "image_height": int(k.height),
        "camera_name": camera_name,
        "camera_matrix": {
            "rows": 3,
            "cols": 3,
            "data": [float(k.fx), 0.0, float(k.cx), 0.0, float(k.fy), float(k.cy), 0.0, 0.0, 1.0],
        },
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [0.0] * 5},
        "rectification_matrix": {
            "rows": 3,
            "cols": 3,
            "data": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        },
        "projection_matrix": {
            "rows": 3,
            "cols": 4,
            "data": [
                float(k.fx), 0.0, float(k.cx), 0.0,
                0.0, float(k.fy), float(k.cy), 0.0,
                0.0, 0.0, 1.0, 0.0,
            ],
        },
    }
    p = Path(path)
    p.write_text(
        yaml.safe_dump(data, sort_keys=False, default_flow_style=None), encoding="utf-8"
    )
    return p


def write_open3d_intrinsics(intrinsics: Intrinsics, path: str | os.PathLike[str]) -> Path:
    """Write ``intrinsics`` as an Open3D ``PinholeCameraIntrinsic`` JSON file (column-major).

    Returns:
        The path written.
    """
    k = intrinsics
    data = {
        "width": int(k.width),
        "height": int(k.height),
        "intrinsic_matrix": [
            float(k.fx), 0.0, 0.0,
            0.0, float(k.fy), 0.0,
            float(k.cx), float(k.cy), 1.0,
        ],
    }
    p = Path(path)
    p.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return p
