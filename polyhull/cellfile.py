"""Read a work cell from a TOML cell file (README, "Your own cell").

A cell file describes the zone Z, the cameras, the static obstacles, the robot, the
parameter sections and the camera mounting surfaces; ``fixtures/cells/paper_cell.toml`` is a
commented example of every key. :func:`load_cell` turns it into the frozen values of
:mod:`polyhull.cell`.

Every problem raises a :class:`~polyhull.errors.CellError` whose message reads
``"<file>: <entry>: expected <what>, got <value>"``, with entries spelled as in the file
(``cameras[2].intrinsics``, ``obstacles[0].box.size``, ``safety.reaction_time``). Unknown
keys are errors (typo protection) and name the valid keys. Loading is pure: it reads files
and builds values, so a bad file changes nothing.

The parameter sections (``[safety]``, ``[reconstruction]``, ``[plausibility]``), the zone,
the robot and the mounting surfaces are read generically from the fields of their
dataclasses: a field added to one of them is a valid key at once, with its default.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
import trimesh

from .background import load_background
from .camera import Camera, Intrinsics, look_at_rotation, quaternion_to_rotation
from .cell import (
    Cell,
    MountingSurface,
    Obstacle,
    PlausibilityParams,
    ReconstructionParams,
    RobotSpec,
    SafetyParams,
    Zone,
)
from .errors import CellError, PolyhullError
from .intrinsics_io import INTRINSICS_SUFFIXES, read_intrinsics_file
from .typed import ArrayF64, Transform

__all__ = [
    "load_cell",
    "default_cell_path",
    "cell_from_mapping",
    "rpy_to_rotation",
    "CELL_KEYS",
    "CAMERA_KEYS",
    "OBSTACLE_KEYS",
]

_T = TypeVar("_T")

#: Top-level keys of a cell file.
CELL_KEYS = (
    "name",
    "zone",
    "cameras",
    "obstacles",
    "robot",
    "safety",
    "reconstruction",
    "plausibility",
    "mounting",
    "background",
)

# Camera dataclass fields that a [[cameras]] entry spells differently (type, range, the
# intrinsics and the pose); every other init field of Camera is a key of the same name.
_CAMERA_SPECIAL_FIELDS = ("name", "kind", "intrinsics", "T_world_camera", "near", "far")
_CAMERA_OWN_KEYS = (
    "name",
    "type",
    "resolution",
    "intrinsics",
    "intrinsics_file",
    "position",
    "look_at",
    "quaternion",
    "range",
)


def _camera_generic_fields() -> tuple[dataclasses.Field[Any], ...]:
    return tuple(
        f
        for f in dataclasses.fields(Camera)
        if f.init and not f.name.startswith("_") and f.name not in _CAMERA_SPECIAL_FIELDS
    )


#: Keys of a ``[[cameras]]`` entry.
CAMERA_KEYS = _CAMERA_OWN_KEYS + tuple(f.name for f in _camera_generic_fields())
#: Keys of an ``[[obstacles]]`` entry.
OBSTACLE_KEYS = ("name", "box", "mesh", "pose", "scale", "solid")
_BOX_KEYS = ("center", "size")
_POSE_KEYS = ("position", "rpy", "quaternion")

# How a value of a section is described in "expected ..." messages.
_KIND_WORDS = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def default_cell_path() -> Path:
    """Path of the embedded default cell (the paper's cell), ``polyhull/data/paper_cell.toml``."""
    return Path(__file__).resolve().parent / "data" / "paper_cell.toml"


def _show(value: object) -> str:
    """A value as it appears in messages (strings quoted, containers as Python literals)."""
    if isinstance(value, Path):
        return repr(str(value))
    return repr(value)


@dataclasses.dataclass(frozen=True)
class _Source:
    """The cell file being read: how to name it in messages and where relative paths start."""

    display: str
    directory: Path

    def expected(self, entry: str, what: str, value: object) -> CellError:
        return CellError(f"{self.display}: {entry}: expected {what}, got {_show(value)}")

    def fail(self, entry: str, message: str) -> CellError:
        return CellError(f"{self.display}: {entry}: {message}")

    def file(self, entry: str, value: object, what: str) -> Path:
        """Resolve a path relative to the cell file; it must name an existing file."""
        if not isinstance(value, str) or not value.strip():
            raise self.expected(entry, f"the path of the {what} (a string)", value)
        path = (self.directory / Path(value).expanduser()).resolve()
        if not path.is_file():
            raise self.fail(
                entry,
                f"expected an existing {what}, relative to the cell file, got {_show(value)} "
                f"(resolved: {path})",
            )
        return path


def _join(entry: str, key: str) -> str:
    return f"{entry}.{key}" if entry else key


def _check_keys(table: Mapping[str, Any], valid: typing.Iterable[str], entry: str, src: _Source) -> None:
    valid = tuple(valid)
    for key in table:
        if key not in valid:
            close = difflib.get_close_matches(str(key), valid, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise CellError(
                f"{src.display}: {_join(entry, str(key))}: unknown key ({hint}valid keys"
                f"{' of ' + entry if entry else ''} are {', '.join(valid)}), got "
                f"{_show(table[key])}"
            )


def _table(value: object, entry: str, src: _Source) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise src.expected(entry, "a table", value)
    return value


def _tables(value: object, entry: str, src: _Source) -> list[Mapping[str, Any]]:
    if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
        raise src.expected(entry, f"an array of tables ([[{entry}]] entries)", value)
    return value


def _number(value: object, entry: str, src: _Source, what: str = "a finite number") -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise src.expected(entry, what, value)
    return float(value)


def _vector(value: object, n: int, entry: str, src: _Source, what: str) -> ArrayF64:
    if (
        not isinstance(value, list)
        or len(value) != n
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        or not all(math.isfinite(v) for v in value)
    ):
        raise src.expected(entry, what, value)
    return np.array(value, dtype=np.float64)


# -- generic dataclass sections -------------------------------------------------------------


def _describe(tp: Any) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp in _KIND_WORDS:
        return _KIND_WORDS[tp]
    if tp is Path:
        return "a file path (relative to the cell file)"
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        arms = [a for a in args if a is not type(None)]
        text = " or ".join(_describe(a) for a in arms)
        return text + " (omit the key for none)" if len(arms) < len(args) else text
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            if dataclasses.is_dataclass(args[0]):
                return "an array of tables"
            return f"a list of {_describe(args[0]).removeprefix('a ').removeprefix('an ')}s"
        if args and all(a is float for a in args):
            return f"a list of {len(args)} finite numbers"
        return f"a list of {len(args)} values"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return "a value"


def _convert(tp: Any, value: object, entry: str, src: _Source) -> Any:
    """Convert a TOML value to the annotated type ``tp`` of a dataclass field."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise src.expected(entry, "true or false", value)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise src.expected(entry, "an integer", value)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise src.expected(entry, "a number", value)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise src.expected(entry, "a string", value)
        return value
    if tp is Path:
        return src.file(entry, value, "file")
    if origin is Literal:
        if value not in args or isinstance(value, bool):
            raise src.expected(entry, _describe(tp), value)
        return value
    if origin in (typing.Union, types.UnionType):
        for arm in (a for a in args if a is not type(None)):
            try:
                return _convert(arm, value, entry, src)
            except CellError:
                continue
        raise src.expected(entry, _describe(tp), value)
    if origin is tuple:
        if not isinstance(value, list):
            raise src.expected(entry, _describe(tp), value)
        if len(args) == 2 and args[1] is Ellipsis:
            if dataclasses.is_dataclass(args[0]):
                return tuple(
                    _convert(args[0], item, f"{entry}[{i}]", src) for i, item in enumerate(value)
                )
            element_types: tuple[Any, ...] = (args[0],) * len(value)
        else:
            element_types = args
            if len(value) != len(args):
                raise src.expected(entry, _describe(tp), value)
        try:
            return tuple(
                _convert(t, item, f"{entry}[{i}]", src)
                for i, (t, item) in enumerate(zip(element_types, value, strict=True))
            )
        except CellError:
            raise src.expected(entry, _describe(tp), value) from None
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return _build(tp, _table(value, entry, src), entry, src)
    return value


def _wrap(
    exc: PolyhullError, entry: str, names: typing.Iterable[str], src: _Source, table: Mapping[str, Any]
) -> CellError:
    """Turn a constructor's error into a CellError naming the most specific entry.

    A message about one field (``safety.reaction_time must be ...``) is filed under that
    field; a message relating several fields stays with the table and shows it.
    """
    message = str(exc)
    mentioned = [
        name for name in names if re.search(rf"(?<![\w]){re.escape(name)}(?![\w])", message)
    ]
    if len(mentioned) == 1:
        name = mentioned[0]
        where, value = _join(entry, name), table.get(name)
        # "safety.reaction_time must be ..." -> "must be ..." (the entry is already named).
        message = re.sub(rf"^\S*(?<![\w]){re.escape(name)}\s+", "", message)
    else:
        where, value = entry, dict(table)
    if "got" not in message and _show(value) not in message:
        message = f"{message}, got {_show(value)}"
    return src.fail(where, message)


def _build(cls: type[_T], table: Mapping[str, Any], entry: str, src: _Source) -> _T:
    """Build dataclass ``cls`` from a TOML table using the fields' annotations and defaults."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.init and not f.name.startswith("_")]
    _check_keys(table, [f.name for f in fields], entry, src)
    kwargs: dict[str, Any] = {}
    for f in fields:
        if f.name in table:
            kwargs[f.name] = _convert(hints[f.name], table[f.name], _join(entry, f.name), src)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise src.fail(
                _join(entry, f.name), f"missing key: expected {_describe(hints[f.name])}"
            )
    try:
        return cls(**kwargs)
    except PolyhullError as exc:
        raise _wrap(exc, entry, [f.name for f in fields], src, table) from None


# -- cameras ------------------------------------------------------------------------------


def _resolution(value: object, entry: str, src: _Source) -> tuple[int, int]:
    if (
        not isinstance(value, list)
        or len(value) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)
    ):
        raise src.expected(entry, "[width, height], two positive integers [px]", value)
    return int(value[0]), int(value[1])


def _check_principal_point(k: Intrinsics, entry: str, src: _Source, value: object) -> None:
    if not (-0.5 <= k.cx <= k.width - 0.5 and -0.5 <= k.cy <= k.height - 0.5):
        raise src.expected(
            entry,
            f"a principal point (cx, cy) inside the {k.width} x {k.height} image "
            f"([-0.5, {k.width - 0.5}] x [-0.5, {k.height - 0.5}] px)",
            value,
        )


def _camera_intrinsics(table: Mapping[str, Any], entry: str, src: _Source) -> Intrinsics:
    has_matrix, has_file = "intrinsics" in table, "intrinsics_file" in table
    if has_matrix == has_file:
        raise src.expected(
            entry,
            "exactly one of intrinsics = [fx, fy, cx, cy] or intrinsics_file = \"path\"",
            "both" if has_matrix else "neither",
        )
    resolution = (
        _resolution(table["resolution"], f"{entry}.resolution", src) if "resolution" in table else None
    )
    if has_matrix:
        key = f"{entry}.intrinsics"
        value = table["intrinsics"]
        if resolution is None:
            raise src.fail(
                f"{entry}.resolution",
                "missing key: expected [width, height] [px] (needed with intrinsics)",
            )
        what = "[fx, fy, cx, cy], four finite numbers with fx, fy > 0 [px]"
        fx, fy, cx, cy = _vector(value, 4, key, src, what)
        if fx <= 0 or fy <= 0:
            raise src.expected(key, what, value)
        k = Intrinsics(width=resolution[0], height=resolution[1], fx=fx, fy=fy, cx=cx, cy=cy)
        _check_principal_point(k, key, src, value)
        return k
    key = f"{entry}.intrinsics_file"
    value = table["intrinsics_file"]
    path = src.file(key, value, "intrinsics file (ROS CameraInfo .yaml or Open3D .json)")
    if path.suffix.lower() not in INTRINSICS_SUFFIXES:
        raise src.expected(
            key, f"a file ending in {', '.join(INTRINSICS_SUFFIXES)} (ROS YAML or Open3D JSON)", value
        )
    try:
        k = read_intrinsics_file(path)
    except PolyhullError as exc:
        raise src.fail(key, str(exc)) from None
    if resolution is not None and resolution != (k.width, k.height):
        raise src.expected(
            f"{entry}.resolution",
            f"the resolution of {value} ({[k.width, k.height]}) or no resolution key",
            list(resolution),
        )
    _check_principal_point(k, key, src, value)
    return k


def _camera_rotation(table: Mapping[str, Any], position: ArrayF64, entry: str, src: _Source) -> ArrayF64:
    has_look_at, has_quaternion = "look_at" in table, "quaternion" in table
    if has_look_at == has_quaternion:
        got = {k: table[k] for k in ("look_at", "quaternion") if k in table}
        raise src.expected(
            entry, "exactly one of look_at = [x, y, z] or quaternion = [w, x, y, z]", got or "neither"
        )
    if has_look_at:
        key, value = f"{entry}.look_at", table["look_at"]
        target = _vector(value, 3, key, src, "a point [x, y, z] of 3 finite numbers [m]")
        try:
            return look_at_rotation(position, target)
        except PolyhullError as exc:
            message = str(exc).removeprefix("look_at: ")
            raise src.fail(key, f"{message}, got {_show(value)}") from None
    return _rotation_of_quaternion(table["quaternion"], f"{entry}.quaternion", src)


def _rotation_of_quaternion(value: object, entry: str, src: _Source) -> ArrayF64:
    """Rotation (3, 3) of a ``[w, x, y, z]`` entry, which must have unit norm."""
    what = "a unit quaternion [w, x, y, z] (4 finite numbers, norm 1 within 1e-3)"
    q = _vector(value, 4, entry, src, what)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > 1e-3:
        raise src.fail(entry, f"expected {what}, got {_show(value)} (norm {norm:.6g})")
    try:
        return quaternion_to_rotation(q)
    except PolyhullError as exc:
        raise src.fail(entry, f"{exc}, got {_show(value)}") from None


def _entry_name(table: Mapping[str, Any], entry: str, src: _Source, what: str) -> str:
    """The required, non-empty ``name`` of an entry (``what``: "a camera", "an obstacle")."""
    if "name" not in table:
        raise src.fail(f"{entry}.name", f"missing key: expected {what} name (a string)")
    name = table["name"]
    if not isinstance(name, str) or not name.strip():
        raise src.expected(f"{entry}.name", "a non-empty string", name)
    return name


def _camera(table: Mapping[str, Any], entry: str, src: _Source) -> Camera:
    _check_keys(table, CAMERA_KEYS, entry, src)
    name = _entry_name(table, entry, src, "a camera")
    kind = table.get("type", "depth")
    if kind not in ("depth", "color") or isinstance(kind, bool):
        raise src.expected(f"{entry}.type", "'depth' or 'color'", kind)
    intrinsics = _camera_intrinsics(table, entry, src)
    if "position" not in table:
        raise src.fail(f"{entry}.position", "missing key: expected [x, y, z] [m]")
    position = _vector(
        table["position"], 3, f"{entry}.position", src, "a point [x, y, z] of 3 finite numbers [m]"
    )
    T_world_camera = np.eye(4)
    T_world_camera[:3, :3] = _camera_rotation(table, position, entry, src)
    T_world_camera[:3, 3] = position

    kwargs: dict[str, Any] = {}
    if "range" in table:
        what = "[near, far], two finite numbers with 0 < near < far [m]"
        near, far = _vector(table["range"], 2, f"{entry}.range", src, what)
        if not 0 < near < far:
            raise src.expected(f"{entry}.range", what, table["range"])
        kwargs.update(near=float(near), far=float(far))
    hints = typing.get_type_hints(Camera)
    for f in _camera_generic_fields():
        if f.name in table:
            key = f"{entry}.{f.name}"
            value = _convert(hints[f.name], table[f.name], key, src)
            if isinstance(value, float) and not (math.isfinite(value) and value >= 0):
                raise src.expected(key, "a finite number >= 0", table[f.name])
            kwargs[f.name] = value
    try:
        return Camera(
            name=name, kind=kind, intrinsics=intrinsics, T_world_camera=T_world_camera, **kwargs
        )
    except PolyhullError as exc:
        raise src.fail(entry, f"{exc}, got {_show(dict(table))}") from None


# -- obstacles ----------------------------------------------------------------------------


def rpy_to_rotation(rpy: ArrayF64) -> ArrayF64:
    """Rotation (3, 3) of URDF roll-pitch-yaw angles [rad]: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Roll about x, then pitch about y, then yaw about z, all about the fixed parent axes
    (the convention of URDF ``<origin rpy="...">``).
    """
    roll, pitch, yaw = (float(a) for a in np.asarray(rpy, dtype=np.float64))
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def _pose(value: object, entry: str, src: _Source) -> Transform:
    """``T_world_object`` of a ``pose = {position, rpy | quaternion}`` table."""
    table = _table(value, entry, src)
    _check_keys(table, _POSE_KEYS, entry, src)
    T = np.eye(4)
    if "position" in table:
        T[:3, 3] = _vector(
            table["position"], 3, f"{entry}.position", src, "[x, y, z], 3 finite numbers [m]"
        )
    if "rpy" in table and "quaternion" in table:
        raise src.expected(
            entry, "at most one of rpy or quaternion", {k: table[k] for k in ("rpy", "quaternion")}
        )
    if "rpy" in table:
        T[:3, :3] = rpy_to_rotation(
            _vector(table["rpy"], 3, f"{entry}.rpy", src, "[roll, pitch, yaw], 3 finite numbers [rad]")
        )
    elif "quaternion" in table:
        T[:3, :3] = _rotation_of_quaternion(table["quaternion"], f"{entry}.quaternion", src)
    return T


def _load_mesh(path: Path, value: object, entry: str, src: _Source) -> trimesh.Trimesh:
    try:
        mesh = trimesh.load_mesh(path)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types; wrap them all
        raise src.fail(entry, f"trimesh could not read {path}: {exc}") from None
    if isinstance(mesh, trimesh.Scene):
        mesh = mesh.to_mesh()
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        problem = "a mesh file with at least one triangle"
    elif not np.all(np.isfinite(mesh.vertices)):
        problem = "a mesh with finite vertices"
    else:
        return mesh
    raise src.fail(entry, f"expected {problem}, got {_show(value)} (resolved: {path})")


def _obstacle(table: Mapping[str, Any], entry: str, src: _Source) -> Obstacle:
    _check_keys(table, OBSTACLE_KEYS, entry, src)
    name = _entry_name(table, entry, src, "an obstacle")
    solid = table.get("solid", True)
    if not isinstance(solid, bool):
        raise src.expected(f"{entry}.solid", "true or false", solid)
    has_box, has_mesh = "box" in table, "mesh" in table
    if has_box == has_mesh:
        raise src.expected(
            entry,
            'exactly one of box = {center, size} or mesh = "path"',
            "both" if has_box else "neither",
        )
    T_world_object = _pose(table["pose"], f"{entry}.pose", src) if "pose" in table else None

    if has_box:
        if "scale" in table:
            raise src.fail(
                f"{entry}.scale", "scale applies to mesh obstacles; give the box size instead"
            )
        box_entry = f"{entry}.box"
        box = _table(table["box"], box_entry, src)
        _check_keys(box, _BOX_KEYS, box_entry, src)
        for key in _BOX_KEYS:
            if key not in box:
                raise src.fail(f"{box_entry}.{key}", "missing key: expected [x, y, z] [m]")
        center = _vector(box["center"], 3, f"{box_entry}.center", src, "[x, y, z], 3 finite numbers [m]")
        size_what = "[x, y, z], 3 finite numbers > 0 [m]"
        size = _vector(box["size"], 3, f"{box_entry}.size", src, size_what)
        if np.any(size <= 0):
            raise src.expected(f"{box_entry}.size", size_what, box["size"])
        mesh = trimesh.creation.box(extents=size)
        mesh.apply_translation(center)
        where = box_entry
    else:
        where = f"{entry}.mesh"
        path = src.file(where, table["mesh"], "mesh file")
        mesh = _load_mesh(path, table["mesh"], where, src)
        if "scale" in table:
            scale_value = table["scale"]
            scale_what = "a number > 0 or [sx, sy, sz], 3 numbers > 0"
            if isinstance(scale_value, list):
                scale = _vector(scale_value, 3, f"{entry}.scale", src, scale_what)
            else:
                scale = np.full(3, _number(scale_value, f"{entry}.scale", src, scale_what))
            if np.any(scale <= 0):
                raise src.expected(f"{entry}.scale", scale_what, scale_value)
            mesh.apply_transform(np.diag([*scale, 1.0]))
    if T_world_object is not None:
        mesh.apply_transform(T_world_object)
    try:
        return Obstacle(name=name, mesh=mesh, solid=solid)
    except PolyhullError as exc:
        got = _show(table["box"] if has_box else table["mesh"])
        raise src.fail(where, f"{exc}, got {got}") from None


# -- robot --------------------------------------------------------------------------------


def _robot(table: Mapping[str, Any], src: _Source) -> RobotSpec:
    """The robot spec; the URDF is loaded once to check it and ``q`` against the limits.

    Without a ``q`` key the default joint vector is zeros (clipped into the limits).
    """
    from .robot import Robot

    spec = _build(RobotSpec, table, "robot", src)
    try:
        robot = Robot.from_spec(dataclasses.replace(spec, q=()))
    except Exception as exc:  # noqa: BLE001 - URDF parsers raise many types; wrap them all
        raise src.fail("robot.urdf", f"cannot build the robot from {spec.urdf}: {exc}") from None
    if "q" not in table:
        q_default = np.clip(np.zeros(robot.dof), robot.lower, robot.upper)
        return dataclasses.replace(spec, q=tuple(float(x) for x in q_default))
    try:
        q = robot.check_q(spec.q)
    except PolyhullError as exc:
        message = str(exc)
        given = _show(table["q"])
        suffix = f" (q = {given})" if "got" in message else f", got {given}"
        raise src.fail("robot.q", message + suffix) from None
    return dataclasses.replace(spec, q=tuple(float(x) for x in q))


# -- the cell ------------------------------------------------------------------------------


def _unique_names(items: typing.Sequence[Any], section: str, src: _Source) -> None:
    seen: dict[str, int] = {}
    for i, item in enumerate(items):
        if item.name in seen:
            raise src.expected(
                f"{section}[{i}].name",
                f"a name not used before (also {section}[{seen[item.name]}].name)",
                item.name,
            )
        seen[item.name] = i


def cell_from_mapping(data: Mapping[str, Any], path: str | os.PathLike[str]) -> Cell:
    """Build a :class:`~polyhull.cell.Cell` from a parsed cell file.

    Args:
        data: The TOML document as a mapping (as returned by ``tomllib``).
        path: The cell file: relative paths in it start at its directory, and messages
            name it as given here.

    Raises:
        CellError: An entry is missing, unknown or invalid; the message names the entry.
    """
    file = Path(path)
    src = _Source(display=str(path), directory=file.resolve().parent)
    _check_keys(data, CELL_KEYS, "", src)

    name = data.get("name", file.stem)
    if not isinstance(name, str) or not name.strip():
        raise src.expected("name", "a non-empty string", name)
    if "zone" not in data:
        raise src.fail("zone", "missing table: expected [zone] with min and max [m]")
    zone = _build(Zone, _table(data["zone"], "zone", src), "zone", src)

    cameras = tuple(
        _camera(t, f"cameras[{i}]", src)
        for i, t in enumerate(_tables(data.get("cameras", []), "cameras", src))
    )
    _unique_names(cameras, "cameras", src)
    obstacles = tuple(
        _obstacle(t, f"obstacles[{i}]", src)
        for i, t in enumerate(_tables(data.get("obstacles", []), "obstacles", src))
    )
    _unique_names(obstacles, "obstacles", src)
    robot = _robot(_table(data["robot"], "robot", src), src) if "robot" in data else None

    safety = _build(SafetyParams, _table(data.get("safety", {}), "safety", src), "safety", src)
    reconstruction = _build(
        ReconstructionParams,
        _table(data.get("reconstruction", {}), "reconstruction", src),
        "reconstruction",
        src,
    )
    if reconstruction.k_of_n > max(1, len(cameras)):
        raise src.expected(
            "reconstruction.k_of_n",
            f"at most the number of cameras ({len(cameras)})",
            reconstruction.k_of_n,
        )
    plausibility = _build(
        PlausibilityParams,
        _table(data.get("plausibility", {}), "plausibility", src),
        "plausibility",
        src,
    )
    mounting = tuple(
        _build(MountingSurface, t, f"mounting[{i}]", src)
        for i, t in enumerate(_tables(data.get("mounting", []), "mounting", src))
    )
    _unique_names(mounting, "mounting", src)
    background = None
    if "background" in data:
        bg_path = src.file("background", data["background"], "taught background (.npz from polyhull teach)")
        try:
            background = load_background(bg_path, cameras)
        except PolyhullError as exc:
            raise src.fail("background", str(exc)) from None
    try:
        return Cell(
            name=name,
            zone=zone,
            cameras=cameras,
            obstacles=obstacles,
            robot=robot,
            safety=safety,
            reconstruction=reconstruction,
            plausibility=plausibility,
            mounting=mounting,
            path=file.resolve(),
            background=background,
        )
    except PolyhullError as exc:
        raise src.fail("cell", str(exc)) from None


def load_cell(path: str | os.PathLike[str]) -> Cell:
    """Read a TOML cell file into a :class:`~polyhull.cell.Cell`.

    Relative paths in the file (robot URDF, obstacle meshes, intrinsics files) start at the
    file's directory. Loading is pure: a bad file raises and changes nothing.

    Args:
        path: The ``.toml`` cell file; see ``fixtures/cells/paper_cell.toml`` for every key.

    Returns:
        The validated cell.

    Raises:
        CellError: The file is missing, is not TOML, or an entry is missing, unknown or
            invalid. The message reads ``"<file>: <entry>: expected <what>, got <value>"``.
    """
    file = Path(path)
    try:
        text = file.read_bytes()
    except FileNotFoundError:
        raise CellError(f"{path}: cell file not found (resolved: {file.resolve()})") from None
    except OSError as exc:
        raise CellError(f"{path}: cannot read the cell file: {exc}") from None
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise CellError(f"{path}: expected a UTF-8 TOML file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise CellError(f"{path}: invalid TOML: {exc}") from None
    return cell_from_mapping(data, path)
