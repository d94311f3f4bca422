"""The robot: URDF model, fast forward kinematics, and conservative collision geometry.

A :class:`Robot` is read from a URDF with yourdfpy. Every link with a ``<collision>``
element (or, failing that, a ``<visual>`` one) contributes collision geometry, in two forms
that both **contain** the true shapes, so the robot body may only grow:

* :meth:`Robot.link_geometry`: one watertight mesh per link (the pieces of a link are
  united with manifold3d), for ray casting, volumes and mesh booleans;
* :meth:`Robot.link_convex_pieces`: the vertices of convex pieces per link, for convex
  distance queries (FCL) and for the convex shadows of the robot occlusion M.

How each URDF shape is made conservative:

============  ==========================================================================
box           exact (its 8 corners)
cylinder      circumscribed regular prism of :data:`CYLINDER_SECTIONS` sides, polygon
              radius ``r / cos(pi / n)``
sphere        circumscribed icosphere (:data:`SPHERE_SUBDIVISIONS` subdivisions) scaled
              so that its *inscribed* radius equals ``r``
mesh          the mesh itself in :meth:`Robot.link_geometry` if it is a closed volume,
              else its convex hull; always its convex hull as a convex piece, so a
              non-convex mesh (a gripper with open fingers) is over-approximated by its hull
============  ==========================================================================

Forward kinematics is on the monitor's per-cycle hot path: the kinematic tree is sorted
once, every joint's origin, axis and mimic coupling are precomputed, and
:meth:`Robot.frame_transforms` evaluates all joints with a handful of vectorised numpy
operations (also for a batch of configurations). Joint types: fixed, revolute, continuous
and prismatic, with mimic joints.

Mesh file names are resolved relative to the URDF file; ``package://pkg/path`` is
stripped to ``path`` and looked up next to the URDF and in its parent directories (with
and without the package directory), ``file://`` URIs and absolute paths are used as they
are.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import manifold3d as m3
import numpy as np
import trimesh

from .camera import check_rigid_transform
from .errors import CameraError, GeometryError, RobotError
from .typed import ArrayF64, Transform

if TYPE_CHECKING:
    from .cell import RobotSpec

__all__ = [
    "Robot",
    "CYLINDER_SECTIONS",
    "SPHERE_SUBDIVISIONS",
    "LIMIT_TOLERANCE",
    "resolve_mesh_filename",
]

CYLINDER_SECTIONS = 16
"""Sides of the regular prism that circumscribes a URDF cylinder."""

SPHERE_SUBDIVISIONS = 2
"""Subdivisions of the icosphere that circumscribes a URDF sphere (162 vertices; the
polyhedron reaches at most 1.9 % beyond the sphere)."""

LIMIT_TOLERANCE = 1e-6
"""A joint value may exceed its URDF limits by this much [rad or m] (encoder rounding)."""

_FIXED, _REVOLUTE, _PRISMATIC = 0, 1, 2
_JOINT_KINDS = {
    "fixed": _FIXED,
    "revolute": _REVOLUTE,
    "continuous": _REVOLUTE,
    "prismatic": _PRISMATIC,
}

ShapeKind = Literal["box", "cylinder", "sphere", "mesh"]


# ---------------------------------------------------------------------------------------
# Conservative shapes
# ---------------------------------------------------------------------------------------


@functools.cache
def _unit_circumscribed_sphere() -> tuple[ArrayF64, np.ndarray]:
    """Vertices (K, 3) and faces (F, 3) of an icosphere whose inscribed radius is 1."""
    ico = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=1.0)
    plane_distance = np.einsum("ij,ij->i", ico.face_normals, ico.triangles[:, 0])
    vertices = np.asarray(ico.vertices, dtype=np.float64) / float(plane_distance.min())
    vertices.setflags(write=False)
    faces = np.asarray(ico.faces, dtype=np.int64)
    faces.setflags(write=False)
    return vertices, faces


def _apply(T: ArrayF64, points: ArrayF64) -> ArrayF64:
    """Points (K, 3) mapped by the (4, 4) transform T."""
    return points @ T[:3, :3].T + T[:3, 3]


@dataclass(frozen=True, eq=False)
class _Shape:
    """One collision or visual element of a link, in the link frame.

    Attributes:
        kind: URDF shape.
        T_link_shape: (4, 4) pose of the element's origin in the link frame.
        size: box: (x, y, z) edge lengths; cylinder: (radius, length); sphere: (radius,) [m].
        mesh: mesh shapes: the loaded, scaled mesh in the element frame.
        where: Where it comes from, for error messages.
    """

    kind: ShapeKind
    T_link_shape: Transform
    size: tuple[float, ...] = ()
    mesh: trimesh.Trimesh | None = None
    where: str = ""

    def convex_vertices(self) -> ArrayF64:
        """Vertices (K, 3) of a convex polytope containing the shape, link frame [m]."""
        if self.kind == "box":
            half = np.asarray(self.size) / 2.0
            signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
            local = signs * half
        elif self.kind == "cylinder":
            radius, length = self.size
            n = CYLINDER_SECTIONS
            angle = 2.0 * np.pi * np.arange(n) / n
            ring = radius / math.cos(math.pi / n) * np.column_stack([np.cos(angle), np.sin(angle)])
            local = np.vstack(
                [
                    np.column_stack([ring, np.full(n, -length / 2)]),
                    np.column_stack([ring, np.full(n, length / 2)]),
                ]
            )
        elif self.kind == "sphere":
            local = _unit_circumscribed_sphere()[0] * self.size[0]
        else:
            local = np.asarray(self._hull().vertices, dtype=np.float64)
        return _apply(self.T_link_shape, np.asarray(local, dtype=np.float64))

    def solid(self) -> trimesh.Trimesh:
        """A watertight mesh containing the shape, link frame [m]."""
        if self.kind == "box":
            mesh = trimesh.creation.box(extents=self.size)
        elif self.kind == "cylinder":
            radius, length = self.size
            n = CYLINDER_SECTIONS
            mesh = trimesh.creation.cylinder(
                radius=radius / math.cos(math.pi / n), height=length, sections=n
            )
        elif self.kind == "sphere":
            vertices, faces = _unit_circumscribed_sphere()
            mesh = trimesh.Trimesh(vertices * self.size[0], faces, process=False)
        else:
            assert self.mesh is not None
            mesh = self.mesh.copy() if self.mesh.is_volume else self._hull()
        mesh.apply_transform(self.T_link_shape)
        return mesh

    def _hull(self) -> trimesh.Trimesh:
        """Convex hull of a mesh shape (element frame)."""
        assert self.mesh is not None
        try:
            with np.errstate(divide="ignore", invalid="ignore"):  # a flat hull has no volume
                hull = self.mesh.convex_hull
                is_volume = bool(hull.is_volume and hull.volume > 0)
        except Exception as exc:  # qhull fails on flat or degenerate meshes
            raise GeometryError(
                f"{self.where}: the mesh has no volume (its convex hull failed: {exc}); "
                "a collision mesh must enclose a volume"
            ) from exc
        if not is_volume:
            raise GeometryError(f"{self.where}: the mesh has no volume (flat or degenerate)")
        return hull

    def visual(self) -> trimesh.Trimesh:
        """A mesh of the shape for display, link frame [m] (need not be watertight)."""
        if self.kind == "mesh":
            assert self.mesh is not None
            mesh = self.mesh.copy()
            mesh.apply_transform(self.T_link_shape)
            return mesh
        return self.solid()


def _union(meshes: Sequence[trimesh.Trimesh], what: str) -> trimesh.Trimesh:
    """The union of watertight meshes as one watertight mesh (manifold3d, float64)."""
    if len(meshes) == 1:
        return meshes[0]
    manifolds = []
    for mesh in meshes:
        manifold = m3.Manifold(
            m3.Mesh64(
                vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float64),
                tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint64),
            )
        )
        if manifold.status() != m3.Error.NoError:
            raise GeometryError(
                f"{what}: a piece is not a closed manifold (manifold3d status "
                f"{manifold.status().name})"
            )
        manifolds.append(manifold)
    result = m3.Manifold.batch_boolean(manifolds, m3.OpType.Add)
    if result.status() != m3.Error.NoError or result.is_empty():
        raise GeometryError(
            f"{what}: the union of its pieces failed (manifold3d status {result.status().name})"
        )
    out = result.to_mesh64()
    return trimesh.Trimesh(
        np.asarray(out.vert_properties, dtype=np.float64)[:, :3],
        np.asarray(out.tri_verts, dtype=np.int64),
        process=False,
    )


def _transformed(mesh: trimesh.Trimesh, T: Transform) -> trimesh.Trimesh:
    """A new mesh: ``mesh`` mapped by the rigid transform T (faces shared, not copied)."""
    return trimesh.Trimesh(_apply(T, mesh.vertices), mesh.faces, process=False)


# ---------------------------------------------------------------------------------------
# URDF parsing
# ---------------------------------------------------------------------------------------


def resolve_mesh_filename(filename: str, urdf_path: str | Path, where: str | None = None) -> Path:
    """The file a URDF ``<mesh filename=...>`` refers to.

    Args:
        filename: The attribute as written in the URDF: a relative path (to the URDF's
            directory), an absolute path, ``file://PATH`` or ``package://PKG/PATH``.
        urdf_path: The URDF file.
        where: Prefix of error messages (default: the URDF path), e.g. naming the link.

    Returns:
        The existing file.

    Raises:
        RobotError: The scheme is not supported or no candidate file exists.
    """
    urdf_dir = Path(urdf_path).resolve().parent
    where = str(urdf_path) if where is None else where
    if filename.startswith("package://"):
        package, _, rel = filename[len("package://") :].partition("/")
        if not rel:
            raise RobotError(f"{where}: mesh filename {filename!r} has no path after the package")
        candidates = []
        for directory in (urdf_dir, *urdf_dir.parents):
            candidates += [directory / rel, directory / package / rel]
    elif filename.startswith("file://"):
        candidates = [Path(filename[len("file://") :])]
    elif "://" in filename:
        raise RobotError(
            f"{where}: mesh filename {filename!r} uses an unsupported scheme; "
            "use a path relative to the URDF, file:// or package://"
        )
    else:
        path = Path(filename)
        candidates = [path if path.is_absolute() else urdf_dir / path]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    tried = ", ".join(str(c) for c in candidates[:4]) + (" ..." if len(candidates) > 4 else "")
    raise RobotError(f"{where}: mesh file {filename!r} not found (looked for {tried})")


def _load_yourdfpy(path: Path):  # -> yourdfpy.URDF
    """Parse the URDF with yourdfpy (no meshes loaded), wrapping every failure."""
    from lxml import etree

    try:
        root = etree.parse(str(path)).getroot()
    except (etree.XMLSyntaxError, OSError) as exc:
        raise RobotError(f"{path}: not a valid XML file: {exc}") from exc
    if root.tag != "robot":
        raise RobotError(f"{path}: the root element must be <robot>, got <{root.tag}>")

    import yourdfpy

    try:
        return yourdfpy.URDF.load(
            str(path), build_scene_graph=False, load_meshes=False, load_collision_meshes=False
        )
    except Exception as exc:
        raise RobotError(
            f"{path}: cannot parse the URDF ({type(exc).__name__}: {exc}); every <link> and "
            "<joint> needs a name, every joint a <parent> and <child>, every <visual> and "
            "<collision> a <geometry> with one of box, cylinder, sphere or mesh"
        ) from exc


def _finite(value: object, n: int | None) -> ArrayF64 | None:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None
    if (n is not None and arr.shape != (n,)) or not np.all(np.isfinite(arr)):
        return None
    return arr


def _origin(T: object, where: str) -> Transform:
    if T is None:
        return np.eye(4)
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
        raise RobotError(f"{where} <origin> must have finite xyz and rpy")
    return arr


def _parse_shape(element, path: Path, where: str) -> _Shape:
    """A collision or visual element as a validated :class:`_Shape`."""
    geometry = element.geometry
    T = _origin(element.origin, where)
    if geometry is None:
        raise RobotError(f"{where}: no <geometry>")
    if geometry.box is not None:
        size = _finite(geometry.box.size, 3)
        if size is None or np.any(size <= 0):
            raise RobotError(
                f"{where} <box size>: expected 3 positive numbers [m], got {geometry.box.size!r}"
            )
        return _Shape("box", T, tuple(float(s) for s in size), where=where)
    if geometry.cylinder is not None:
        dims = _finite([geometry.cylinder.radius, geometry.cylinder.length], 2)
        if dims is None or np.any(dims <= 0):
            raise RobotError(
                f"{where} <cylinder>: radius and length must be positive [m], got "
                f"radius={geometry.cylinder.radius!r}, length={geometry.cylinder.length!r}"
            )
        return _Shape("cylinder", T, (float(dims[0]), float(dims[1])), where=where)
    if geometry.sphere is not None:
        radius = _finite([geometry.sphere.radius], 1)
        if radius is None or radius[0] <= 0:
            raise RobotError(
                f"{where} <sphere radius>: expected a positive number [m], got {geometry.sphere.radius!r}"
            )
        return _Shape("sphere", T, (float(radius[0]),), where=where)
    if geometry.mesh is not None:
        mesh, filename = _load_mesh(geometry.mesh, path, where)
        return _Shape("mesh", T, mesh=mesh, where=f"{where} mesh '{filename}'")
    raise RobotError(f"{where}: <geometry> holds no box, cylinder, sphere or mesh")


def _load_mesh(mesh_element, path: Path, where: str) -> tuple[trimesh.Trimesh, Path]:
    """Load, validate and scale a ``<mesh>`` (element frame); returns it and its file."""
    filename = resolve_mesh_filename(str(mesh_element.filename or ""), path, where)
    where = f"{where} mesh {str(filename)!r}"
    try:
        # process=False: trimesh would silently drop non-finite vertices.
        mesh = trimesh.load(str(filename), force="mesh", process=False)
    except Exception as exc:
        raise RobotError(f"{where}: cannot read the mesh ({type(exc).__name__}: {exc})") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise GeometryError(f"{where}: the file holds no triangle mesh")
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise GeometryError(f"{where}: the mesh is empty")
    if not np.all(np.isfinite(mesh.vertices)):
        raise GeometryError(f"{where}: the mesh has non-finite vertices")
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # merge duplicate vertices
    if mesh_element.scale is not None:
        scale = _finite(mesh_element.scale, None)
        if scale is None or scale.size not in (1, 3) or np.any(scale == 0):
            raise RobotError(
                f"{where} <mesh scale>: expected 1 or 3 finite non-zero numbers, got {mesh_element.scale!r}"
            )
        S = np.eye(4)
        S[:3, :3] = np.diag(np.broadcast_to(scale, (3,)))
        mesh.apply_transform(S)
    return mesh, filename


@dataclass(frozen=True)
class _Kinematics:
    """The kinematic tree, sorted root first, with everything static precomputed.

    Frame 0 is the root link; joint j (in this sorted order) moves frame j + 1 relative to
    frame ``parent[j]`` (< j + 1).
    """

    frame_names: tuple[str, ...]
    parent: tuple[int, ...]  # (J,)
    origin_R: ArrayF64  # (J, 3, 3)
    origin_t: ArrayF64  # (J, 3)
    kind: np.ndarray  # (J,) _FIXED, _REVOLUTE or _PRISMATIC
    axis: ArrayF64  # (J, 3) unit axes (zero for fixed joints)
    K: ArrayF64  # (J, 3, 3) cross-product matrix of the axis (revolute only)
    K2: ArrayF64  # (J, 3, 3) K @ K
    source: np.ndarray  # (J,) index into q of the driving joint (0 for fixed joints)
    multiplier: ArrayF64  # (J,) 1, or the mimic multiplier, 0 for fixed joints
    offset: ArrayF64  # (J,) 0, or the mimic offset

    def transforms(self, T_world_base: Transform, q: ArrayF64) -> ArrayF64:
        """T_world_frame (N, F, 4, 4) for a batch of joint vectors q (N, dof)."""
        n = q.shape[0]
        value = q[:, self.source] * self.multiplier + self.offset  # (N, J)
        s = np.sin(value)[..., None, None]
        c = np.cos(value)[..., None, None]
        R = np.eye(3) + s * self.K + (1.0 - c) * self.K2  # (N, J, 3, 3)
        prismatic = (self.kind == _PRISMATIC).astype(np.float64)
        A = np.zeros((n, len(self.parent), 4, 4))
        A[..., :3, :3] = self.origin_R @ R
        A[..., :3, 3] = self.origin_t + np.einsum(
            "jab,njb->nja", self.origin_R, self.axis * (value * prismatic)[..., None]
        )
        A[..., 3, 3] = 1.0
        T = np.empty((n, len(self.frame_names), 4, 4))
        T[:, 0] = T_world_base
        for j, p in enumerate(self.parent):
            T[:, j + 1] = T[:, p] @ A[:, j]
        return T


def _cross_matrix(a: ArrayF64) -> ArrayF64:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _parse_kinematics(urdf, path: Path) -> tuple[_Kinematics, list, ArrayF64, ArrayF64, ArrayF64]:
    """Validate the tree and the joints; returns kinematics, actuated joints, limits."""
    robot = urdf.robot
    link_names, root = _check_tree(robot, path)
    # Actuated joints in URDF order (as yourdfpy), then their limits.
    actuated = [j for j in robot.joints if j.type != "fixed" and j.mimic is None]
    if not actuated:
        raise RobotError(f"{path}: the URDF has no actuated joint (all joints are fixed or mimic)")
    lower, upper, velocity = _joint_limits(actuated, path)
    frames, ordered = _tree_order(robot, link_names, root, path)
    index = {j.name: i for i, j in enumerate(actuated)}
    joints_by_name = {joint.name: joint for joint in robot.joints}

    def drive(joint, seen: tuple[str, ...] = ()) -> tuple[int, float, float]:
        """(index into q, multiplier, offset) of a moving joint, following mimic chains."""
        if joint.mimic is None:
            return index[joint.name], 1.0, 0.0
        where = f"{path}: joint '{joint.name}' <mimic joint={joint.mimic.joint!r}>"
        target = joints_by_name.get(joint.mimic.joint)
        if target is None or target.type == "fixed" or joint.mimic.joint in seen:
            raise RobotError(f"{where}: must name a moving, non-circular joint")
        mult = 1.0 if joint.mimic.multiplier is None else float(joint.mimic.multiplier)
        off = 0.0 if joint.mimic.offset is None else float(joint.mimic.offset)
        if not (np.isfinite(mult) and np.isfinite(off)):
            raise RobotError(f"{where}: multiplier and offset must be finite")
        src, m, o = drive(target, (*seen, joint.name))
        return src, mult * m, mult * o + off

    n = len(ordered)
    origin_R = np.zeros((n, 3, 3))
    origin_t = np.zeros((n, 3))
    kind = np.zeros(n, dtype=np.int64)
    axis = np.zeros((n, 3))
    K = np.zeros((n, 3, 3))
    source = np.zeros(n, dtype=np.int64)
    multiplier = np.zeros(n)
    offset = np.zeros(n)
    for j, joint in enumerate(ordered):
        where = f"{path}: joint '{joint.name}'"
        origin = _origin(joint.origin, where)
        origin_R[j], origin_t[j] = origin[:3, :3], origin[:3, 3]
        kind[j] = _JOINT_KINDS[joint.type]
        if kind[j] == _FIXED:
            continue
        a = _finite(joint.axis, 3)
        if a is None or np.linalg.norm(a) < 1e-12:
            raise RobotError(
                f"{where} <axis xyz>: expected a finite non-zero vector, got {joint.axis!r}"
            )
        axis[j] = a / np.linalg.norm(a)
        if kind[j] == _REVOLUTE:
            K[j] = _cross_matrix(axis[j])
        source[j], multiplier[j], offset[j] = drive(joint)
    frame_index = {name: i for i, name in enumerate(frames)}
    kin = _Kinematics(
        frame_names=tuple(frames),
        parent=tuple(frame_index[joint.parent] for joint in ordered),
        origin_R=origin_R,
        origin_t=origin_t,
        kind=kind,
        axis=axis,
        K=K,
        K2=K @ K,
        source=source,
        multiplier=multiplier,
        offset=offset,
    )
    return kin, actuated, lower, upper, velocity


def _check_tree(robot, path: Path) -> tuple[list[str], str]:  # noqa: ANN001 - a yourdfpy Robot
    """The link names and the root link of a URDF whose names are unique, whose joints
    are of a supported type between existing links, and which is one tree."""
    link_names = [link.name for link in robot.links]
    joint_names = [joint.name for joint in robot.joints]
    for what, names in (("link", link_names), ("joint", joint_names)):
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise RobotError(f"{path}: {what} names must be unique, repeated: {dup}")
    if not link_names:
        raise RobotError(f"{path}: the URDF has no <link>")
    child_of: dict[str, str] = {}
    for joint in robot.joints:
        where = f"{path}: joint '{joint.name}'"
        if joint.type not in _JOINT_KINDS:
            raise RobotError(
                f"{where}: type {joint.type!r} is not supported; expected one of "
                f"{sorted(_JOINT_KINDS)}"
            )
        for role, link in (("parent", joint.parent), ("child", joint.child)):
            if link not in link_names:
                raise RobotError(f"{where} <{role} link={link!r}>: no such link")
        if joint.child in child_of:
            raise RobotError(
                f"{where}: link '{joint.child}' is already the child of joint "
                f"'{child_of[joint.child]}'; a URDF is a tree"
            )
        child_of[joint.child] = joint.name
    roots = [name for name in link_names if name not in child_of]
    if len(roots) != 1:
        raise RobotError(
            f"{path}: the URDF must have exactly one root link, found {roots or 'none (a cycle)'}"
        )
    return link_names, roots[0]


def _joint_limits(actuated: list, path: Path) -> tuple[ArrayF64, ArrayF64, ArrayF64]:
    """(lower, upper, velocity) limits of the actuated joints (a continuous joint's
    position limits are infinite; a missing velocity limit is infinite)."""
    lower, upper, velocity = [], [], []
    for joint in actuated:
        where = f"{path}: joint '{joint.name}' <limit>"
        limit = joint.limit
        if joint.type == "continuous":
            lo, hi = -np.inf, np.inf
        else:
            if limit is None or limit.lower is None or limit.upper is None:
                raise RobotError(f"{where}: a {joint.type} joint needs lower and upper limits")
            lo, hi = float(limit.lower), float(limit.upper)
            if not (np.isfinite(lo) and np.isfinite(hi)):
                raise RobotError(f"{where}: lower and upper must be finite, got {lo!r}, {hi!r}")
            if lo > hi:
                raise RobotError(f"{where}: lower {lo!r} > upper {hi!r}")
        v = np.inf if limit is None or limit.velocity is None else float(limit.velocity)
        if not v > 0:
            raise RobotError(f"{where}: velocity must be > 0, got {v!r}")
        lower.append(lo)
        upper.append(hi)
        velocity.append(v)
    return np.array(lower), np.array(upper), np.array(velocity)


def _tree_order(robot, link_names: list[str], root: str, path: Path) -> tuple[list[str], list]:  # noqa: ANN001
    """The link frames root first and the joints in that order (children in URDF joint
    order); every link must hang from the root."""
    children: dict[str, list] = {name: [] for name in link_names}
    for joint in robot.joints:
        children[joint.parent].append(joint)
    frames = [root]
    ordered = []
    stack = list(reversed(children[root]))
    while stack:
        joint = stack.pop()
        frames.append(joint.child)
        ordered.append(joint)
        stack.extend(reversed(children[joint.child]))
    if len(frames) != len(link_names):
        missing = sorted(set(link_names) - set(frames))
        raise RobotError(f"{path}: links {missing} are not connected to the root link '{root}'")

    return frames, ordered


def _material_rgba(visual, materials: dict) -> ArrayF64 | None:
    material = visual.material
    if material is None:
        return None
    color = material.color if material.color is not None else None
    if color is None and material.name in materials and materials[material.name].color is not None:
        color = materials[material.name].color
    if color is None or color.rgba is None:
        return None
    rgba = _finite(color.rgba, 4)
    return None if rgba is None else np.clip(rgba, 0.0, 1.0)


# ---------------------------------------------------------------------------------------
# The robot
# ---------------------------------------------------------------------------------------


class Robot:
    """A robot from a URDF: joint limits, forward kinematics and collision geometry.

    Build it with :meth:`from_urdf` or :meth:`from_spec`. The object does not change after
    construction (:meth:`with_base` returns a moved copy sharing the geometry).

    Attributes:
        name: The URDF robot name.
        path: The URDF file.
        joint_names: Actuated joints (not fixed, not mimic), in URDF order; q follows it.
        lower: (dof,) lower joint limits [rad or m]; -inf for continuous joints.
        upper: (dof,) upper joint limits [rad or m]; +inf for continuous joints.
        velocity: (dof,) joint velocity limits [rad/s or m/s]; +inf where the URDF has none.
        dof: Number of actuated joints.
        link_names: Links with geometry (collision, else visual), in URDF order.
        frame_names: Every link of the tree (also those without geometry, e.g. a tool
            frame), root first.
        T_world_base: (4, 4) pose of the root link in the world.
    """

    name: str
    path: Path
    joint_names: tuple[str, ...]
    lower: ArrayF64
    upper: ArrayF64
    velocity: ArrayF64
    dof: int
    link_names: tuple[str, ...]
    frame_names: tuple[str, ...]
    T_world_base: Transform

    def __init__(
        self,
        *,
        name: str,
        path: Path,
        kinematics: _Kinematics,
        joint_names: tuple[str, ...],
        lower: ArrayF64,
        upper: ArrayF64,
        velocity: ArrayF64,
        collision: dict[str, tuple[_Shape, ...]],
        visual_source: dict[str, tuple[tuple[_Shape, ArrayF64 | None], ...]] | None,
        T_world_base: Transform,
        _geometry: dict[str, trimesh.Trimesh] | None = None,
        _pieces: dict[str, tuple[ArrayF64, ...]] | None = None,
    ) -> None:
        """Use :meth:`from_urdf`; this constructor takes already validated parts."""
        self.name = name
        self.path = path
        self._who = f"robot '{name}' ({path.name})"
        self._kin = kinematics
        self.joint_names = joint_names
        self.lower = lower
        self.upper = upper
        self.velocity = velocity
        for arr in (self.lower, self.upper, self.velocity):
            arr.setflags(write=False)
        self.dof = len(joint_names)
        self.frame_names = kinematics.frame_names
        self.link_names = tuple(name for name, shapes in collision.items() if shapes)
        self._frame_index = {f: i for i, f in enumerate(self.frame_names)}
        self._link_frames = np.array(
            [self._frame_index[n] for n in self.link_names], dtype=np.int64
        )
        self._collision = collision
        self._visual_source = visual_source
        self._visual_cache: dict[str, trimesh.Trimesh] | None = None
        try:
            T = check_rigid_transform(T_world_base, "T_world_base")
        except CameraError as exc:
            raise RobotError(f"{self._who}: {exc}") from exc
        self.T_world_base = T.copy()
        self.T_world_base.setflags(write=False)

        if _geometry is None or _pieces is None:
            _geometry, _pieces = self._build_geometry()
        self._geometry = _geometry
        self._pieces = _pieces
        # Everything static for the world-frame queries: per link, all piece vertices
        # stacked (for one matrix product) and the split points; all link meshes stacked.
        self._piece_stack = {n: np.vstack(p) for n, p in _pieces.items()}
        self._piece_split = {n: np.cumsum([len(v) for v in p])[:-1] for n, p in _pieces.items()}
        vertex_counts = [len(_geometry[n].vertices) for n in self.link_names]
        self._mesh_vertex_link = np.repeat(np.arange(len(self.link_names)), vertex_counts)
        self._mesh_vertices = np.vstack([_geometry[n].vertices for n in self.link_names])
        offsets = np.concatenate([[0], np.cumsum(vertex_counts)[:-1]])
        self._mesh_faces = np.vstack(
            [_geometry[n].faces + off for n, off in zip(self.link_names, offsets, strict=True)]
        )

    # -- construction ------------------------------------------------------------------

    @classmethod
    def from_urdf(cls, path: str | Path, T_world_base: Transform | None = None) -> Robot:
        """Load a robot from a URDF file.

        Args:
            path: The URDF file. Mesh files are resolved relative to it (see
                :func:`resolve_mesh_filename`).
            T_world_base: (4, 4) pose of the root link in the world; identity by default.

        Raises:
            RobotError: Missing or unparsable file, no actuated joint, invalid limits,
                axes, shapes, or a mesh file that cannot be found or read.
            GeometryError: A mesh that is empty, non-finite or has no volume.
        """
        path = Path(path)
        if not path.is_file():
            raise RobotError(f"robot URDF '{path}' does not exist or is not a file")
        urdf = _load_yourdfpy(path)
        kin, actuated, lower, upper, velocity = _parse_kinematics(urdf, path)

        collision: dict[str, tuple[_Shape, ...]] = {}
        visual_source: dict[str, tuple[tuple[_Shape, ArrayF64 | None], ...]] = {}
        materials = {m.name: m for m in urdf.robot.materials if m.name}
        for link in urdf.robot.links:
            elements = link.collisions if link.collisions else link.visuals
            kind = "collision" if link.collisions else "visual"
            collision[link.name] = tuple(
                _parse_shape(e, path, f"{path}: link '{link.name}' {kind}[{i}]")
                for i, e in enumerate(elements)
            )
            if link.visuals:
                visual_source[link.name] = tuple(
                    (
                        _parse_shape(e, path, f"{path}: link '{link.name}' visual[{i}]")
                        if kind != "visual"
                        else collision[link.name][i],
                        _material_rgba(e, materials),
                    )
                    for i, e in enumerate(link.visuals)
                )
        if not any(collision.values()):
            raise RobotError(f"{path}: no link has collision or visual geometry")
        return cls(
            name=str(urdf.robot.name or path.stem),
            path=path,
            kinematics=kin,
            joint_names=tuple(j.name for j in actuated),
            lower=lower,
            upper=upper,
            velocity=velocity,
            collision=collision,
            visual_source=visual_source,
            T_world_base=np.eye(4) if T_world_base is None else T_world_base,
        )

    @classmethod
    def from_spec(cls, spec: RobotSpec) -> Robot:
        """Load the robot of a cell: ``spec.urdf`` placed at ``spec.T_world_base``.

        The default joint vector ``spec.q`` (if given) is checked against the limits.
        """
        robot = cls.from_urdf(spec.urdf, spec.T_world_base)
        if spec.q:
            try:
                robot.check_q(spec.q)
            except RobotError as exc:
                raise RobotError(f"robot.q: {exc}") from exc
        return robot

    def with_base(self, T_world_base: Transform) -> Robot:
        """The same robot placed at another base pose (geometry is shared, not rebuilt)."""
        return Robot(
            name=self.name,
            path=self.path,
            kinematics=self._kin,
            joint_names=self.joint_names,
            lower=self.lower.copy(),
            upper=self.upper.copy(),
            velocity=self.velocity.copy(),
            collision=self._collision,
            visual_source=self._visual_source,
            T_world_base=T_world_base,
            _geometry=self._geometry,
            _pieces=self._pieces,
        )

    def _build_geometry(self) -> tuple[dict[str, trimesh.Trimesh], dict[str, tuple[ArrayF64, ...]]]:
        geometry: dict[str, trimesh.Trimesh] = {}
        pieces: dict[str, tuple[ArrayF64, ...]] = {}
        for name in self.link_names:
            shapes = self._collision[name]
            what = f"{self.path}: link '{name}'"
            link_pieces = []
            for shape in shapes:
                vertices = shape.convex_vertices()
                vertices.setflags(write=False)
                link_pieces.append(vertices)
            pieces[name] = tuple(link_pieces)
            mesh = _union([shape.solid() for shape in shapes], what)
            if not (mesh.is_watertight and np.isfinite(mesh.volume) and mesh.volume > 0):
                raise GeometryError(f"{what}: its collision geometry is not a closed volume")
            geometry[name] = mesh
        return geometry, pieces

    # -- joints and kinematics -----------------------------------------------------------

    def check_q(self, q: Sequence[float] | ArrayF64) -> ArrayF64:
        """Validate a joint vector.

        Args:
            q: (dof,) joint positions [rad or m] in the order of ``joint_names``, or a batch
                (N, dof).

        Returns:
            q as float64, same shape.

        Raises:
            RobotError: Wrong length, a non-finite value, or a value outside the joint's
                limits (by more than :data:`LIMIT_TOLERANCE`); the message names the joint.
        """
        try:
            arr = np.asarray(q, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise RobotError(f"{self._who}: q must be numbers, got {q!r}") from exc
        if arr.ndim not in (1, 2) or arr.shape[-1] != self.dof:
            raise RobotError(
                f"{self._who}: q must have {self.dof} values ({', '.join(self.joint_names)}), "
                f"got shape {arr.shape}"
            )
        rows = arr.reshape(-1, self.dof)
        bad = ~np.isfinite(rows)
        bad_kind = "is not finite"
        if not bad.any():
            bad = (rows < self.lower - LIMIT_TOLERANCE) | (rows > self.upper + LIMIT_TOLERANCE)
            bad_kind = "is outside its limits"
        if bad.any():
            row, col = (int(i) for i in np.argwhere(bad)[0])
            where = f" (row {row})" if arr.ndim == 2 else ""
            raise RobotError(
                f"{self._who}: {self.joint_names[col]} = "
                f"{float(rows[row, col])!r}{where} {bad_kind} [{self.lower[col]:.6g}, "
                f"{self.upper[col]:.6g}]"
            )
        return arr

    def frame_transforms(self, q: Sequence[float] | ArrayF64) -> dict[str, ArrayF64]:
        """T_world_frame for every link of the tree (also those without geometry).

        Args:
            q: (dof,) joint positions, or a batch (N, dof).

        Returns:
            Frame name -> (4, 4) transform, or (N, 4, 4) for a batch.
        """
        arr = self.check_q(q)
        T = self._kin.transforms(self.T_world_base, arr.reshape(-1, self.dof))
        if arr.ndim == 1:
            return {name: T[0, i] for i, name in enumerate(self.frame_names)}
        return {name: T[:, i] for i, name in enumerate(self.frame_names)}

    def link_transforms(self, q: Sequence[float] | ArrayF64) -> dict[str, ArrayF64]:
        """T_world_link (4, 4) for every link in ``link_names`` (batch: (N, 4, 4))."""
        frames = self.frame_transforms(q)
        return {name: frames[name] for name in self.link_names}

    def _link_T(self, q: Sequence[float] | ArrayF64) -> ArrayF64:
        """(L, 4, 4) T_world_link for the links in ``link_names`` at one q."""
        arr = self.check_q(q)
        if arr.ndim != 1:
            raise RobotError(
                f"{self._who}: q must be one joint vector of shape ({self.dof},), got {arr.shape}"
            )
        return self._kin.transforms(self.T_world_base, arr[None])[0, self._link_frames]

    # -- geometry ----------------------------------------------------------------------

    def link_geometry(self) -> dict[str, trimesh.Trimesh]:
        """Collision geometry per link in the LINK frame: one watertight mesh per link.

        Each mesh contains the link's URDF shapes (circumscribed tessellation, see the
        module docstring), united. Returned meshes are copies; change them freely.
        """
        return {name: self._geometry[name].copy() for name in self.link_names}

    def link_convex_pieces(self) -> dict[str, list[ArrayF64]]:
        """Per link, the vertices (K, 3) of convex pieces containing its shapes, LINK frame.

        One piece per URDF shape; a mesh becomes its convex hull (a non-convex mesh is
        over-approximated by its hull). The arrays are read-only.
        """
        return {name: list(self._pieces[name]) for name in self.link_names}

    def link_meshes(self, q: Sequence[float] | ArrayF64) -> dict[str, trimesh.Trimesh]:
        """Collision geometry per link (watertight) in the WORLD frame at ``q``."""
        T = self._link_T(q)
        return {
            name: _transformed(self._geometry[name], T[i]) for i, name in enumerate(self.link_names)
        }

    def convex_pieces_world(self, q: Sequence[float] | ArrayF64) -> list[tuple[str, ArrayF64]]:
        """All convex pieces at ``q``: (link name, vertices (K, 3) in the WORLD frame)."""
        T = self._link_T(q)
        out: list[tuple[str, ArrayF64]] = []
        for i, name in enumerate(self.link_names):
            stacked = _apply(T[i], self._piece_stack[name])
            out.extend((name, piece) for piece in np.split(stacked, self._piece_split[name]))
        return out

    def mesh(self, q: Sequence[float] | ArrayF64) -> trimesh.Trimesh:
        """All links' collision geometry in one WORLD-frame mesh (for ray casting).

        The links are concatenated, not united: links overlap at their joints.
        """
        T = self._link_T(q)
        Tv = T[self._mesh_vertex_link]  # (V, 4, 4)
        vertices = np.einsum("vab,vb->va", Tv[:, :3, :3], self._mesh_vertices) + Tv[:, :3, 3]
        return trimesh.Trimesh(vertices, self._mesh_faces, process=False)

    def visual_meshes(self, q: Sequence[float] | ArrayF64) -> dict[str, trimesh.Trimesh]:
        """Visual geometry per link (collision geometry where a link has no visual), WORLD
        frame at ``q``, coloured from the URDF materials. Visual mesh files are read on
        first use.
        """
        if self._visual_cache is None:
            cache: dict[str, trimesh.Trimesh] = {}
            for name in self.link_names:
                source = (self._visual_source or {}).get(name)
                if not source:
                    cache[name] = self._geometry[name]
                    continue
                parts = []
                for shape, rgba in source:
                    mesh = shape.visual()
                    if rgba is not None:
                        mesh.visual = trimesh.visual.ColorVisuals(
                            mesh, face_colors=np.round(rgba * 255).astype(np.uint8)
                        )
                    parts.append(mesh)
                merged = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
                assert isinstance(merged, trimesh.Trimesh)
                cache[name] = merged
            self._visual_cache = cache
        T = self._link_T(q)
        out = {}
        for i, name in enumerate(self.link_names):
            mesh = self._visual_cache[name].copy()
            mesh.apply_transform(T[i])
            out[name] = mesh
        return out

    def __repr__(self) -> str:
        return (
            f"Robot(name={self.name!r}, dof={self.dof}, links={len(self.link_names)}, "
            f"path='{self.path}')"
        )
