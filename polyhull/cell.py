"""The work cell: zone Z, cameras, static obstacles, robot, and all parameters.

These are immutable values. :func:`polyhull.load_cell` (in :mod:`polyhull.cellfile`)
builds them from a TOML cell file; everything is validated here, in the constructors, so a
cell built in code is held to the same rules as one read from a file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import manifold3d as m3
import numpy as np
import trimesh

from .background import TaughtBackground
from .camera import Camera
from .errors import CellError, GeometryError
from .typed import ArrayBool, ArrayF64

__all__ = [
    "Zone",
    "Obstacle",
    "RobotSpec",
    "SafetyParams",
    "ReconstructionParams",
    "PlausibilityParams",
    "EntryArea",
    "MountingSurface",
    "Cell",
    "mesh_to_manifold",
]


def _finite_vec(value: object, n: int, what: str) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise CellError(f"{what} must be {n} finite numbers, got {value!r}")
    return tuple(float(x) for x in arr)


def mesh_to_manifold(mesh: trimesh.Trimesh, what: str) -> m3.Manifold:
    """Convert a watertight trimesh to a manifold3d Manifold, or raise GeometryError."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.uint32)
    if len(faces) == 0 or not np.all(np.isfinite(vertices)):
        raise GeometryError(f"{what}: mesh is empty or has non-finite vertices")
    # Manifold merges nearly coincident vertices itself; float32 storage is what it keeps.
    result = m3.Manifold(m3.Mesh(vert_properties=vertices.astype(np.float32), tri_verts=faces))
    if result.status() != m3.Error.NoError or result.is_empty():
        raise GeometryError(
            f"{what}: mesh is not a closed manifold (manifold3d status {result.status().name}); "
            "repair it (e.g. trimesh.repair.fill_holes) or give a box"
        )
    return result


@dataclass(frozen=True)
class Zone:
    """The work cell Z: an axis-aligned box in the world frame [m]; the floor is z = min z."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo = _finite_vec(self.min, 3, "zone.min")
        hi = _finite_vec(self.max, 3, "zone.max")
        if not all(h > lo_ for lo_, h in zip(lo, hi, strict=True)):
            raise CellError(f"zone.max {list(hi)} must exceed zone.min {list(lo)} on every axis")
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)

    @property
    def size(self) -> ArrayF64:
        """Edge lengths (3,) [m]."""
        return np.subtract(self.max, self.min)

    @property
    def volume(self) -> float:
        """Volume of Z [m^3]."""
        return float(np.prod(self.size))

    @property
    def floor_z(self) -> float:
        """Height of the floor [m]."""
        return self.min[2]

    def contains(self, points: ArrayF64) -> ArrayBool:
        """Which points (N, 3) lie in the closed box."""
        p = np.asarray(points, dtype=np.float64)
        return np.all((p >= np.asarray(self.min)) & (p <= np.asarray(self.max)), axis=1)

    def manifold(self) -> m3.Manifold:
        """Z as a manifold box."""
        return m3.Manifold.cube(tuple(self.size)).translate(self.min)


@dataclass(frozen=True, eq=False)
class Obstacle:
    """A static object of the cell (world frame).

    Attributes:
        name: Unique name.
        mesh: Closed triangle mesh in the world frame [m].
        solid: True when a person cannot enter it (it is subtracted as O(j)).
    """

    name: str
    mesh: trimesh.Trimesh
    solid: bool = True
    _manifold: m3.Manifold = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_manifold", mesh_to_manifold(self.mesh, f"obstacle '{self.name}'"))

    @classmethod
    def box(
        cls, name: str, center: ArrayF64, size: ArrayF64, solid: bool = True
    ) -> Obstacle:
        """An axis-aligned box obstacle of ``size`` [m] centred at ``center`` [m]."""
        c = _finite_vec(center, 3, f"obstacle '{name}' box.center")
        s = _finite_vec(size, 3, f"obstacle '{name}' box.size")
        if min(s) <= 0:
            raise CellError(f"obstacle '{name}' box.size must be > 0 on every axis, got {list(s)}")
        mesh = trimesh.creation.box(extents=s)
        mesh.apply_translation(c)
        return cls(name=name, mesh=mesh, solid=solid)

    def manifold(self) -> m3.Manifold:
        """The obstacle as a manifold (world frame)."""
        return self._manifold


@dataclass(frozen=True)
class RobotSpec:
    """Where the robot description is and how it stands in the cell.

    Attributes:
        urdf: Path of the URDF file (resolved against the cell file).
        base: Base link position in the world [m].
        base_yaw: Rotation of the base about world z [rad].
        q: Default joint positions [rad], URDF order of the actuated joints.
        padding: Margin [m] by which link geometry is grown when computing the robot
            occlusion M; it absorbs depth noise in front of robot surfaces. The monitor adds
            it to the protective separation distance, so it never makes the robot faster.
        joint_state_topic: The ``sensor_msgs/JointState`` topic in ROS bags.
    """

    urdf: Path
    base: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_yaw: float = 0.0
    q: tuple[float, ...] = ()
    padding: float = 0.05
    joint_state_topic: str = "/joint_states"

    def __post_init__(self) -> None:
        object.__setattr__(self, "base", _finite_vec(self.base, 3, "robot.base"))
        object.__setattr__(self, "q", tuple(float(x) for x in self.q))
        if not np.all(np.isfinite(self.q)):
            raise CellError(f"robot.q must be finite, got {list(self.q)}")
        if not (np.isfinite(self.padding) and 0.0 <= self.padding <= 0.5):
            raise CellError(f"robot.padding must be in [0, 0.5] m, got {self.padding!r}")

    @property
    def T_world_base(self) -> ArrayF64:
        """(4, 4) pose of the robot base link in the world."""
        c, s = np.cos(self.base_yaw), np.sin(self.base_yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:3, 3] = self.base
        return T


@dataclass(frozen=True)
class SafetyParams:
    """Speed and separation monitoring (ISO/TS 15066) and fault-handling parameters.

    ``S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r`` with ``S_s = v_r T_s / 2``
    (constant deceleration) unless ``stopping_distance`` is given.

    Attributes:
        profile: ``"iso"`` (ISO/TS 15066 protective separation) or ``"ramp"`` (the paper's
            distance-velocity ramp).
        human_speed: v_h in [m/s] (ISO 13855: 1.6 m/s).
        human_speed_close: v_h in [m/s] below ``close_distance`` (ISO 13855: 2.0 m/s).
        close_distance: Distance [m] under which ``human_speed_close`` applies.
        reaction_time: T_r in [s], without the cycle latency (the measured latency is added).
        stopping_time: T_s in [s].
        robot_speed_max: Largest robot speed v_r in [m/s]; speed_scale = v_r / this.
        stopping_distance: S_s in [m] at full speed, or None for ``v_r * T_s / 2``.
        intrusion_distance: C in [m].
        sensor_uncertainty: Z_d in [m].
        robot_uncertainty: Z_r in [m].
        ramp_stop_distance: d0 [m] of the ramp profile: stop below it.
        ramp_full_distance: d1 [m] of the ramp profile: full speed above it.
        max_frame_age: A frame older than this [s] is stale.
        cycle_deadline: A cycle longer than this [s] is reported as over its deadline.
        min_free_share: Coverage is lost when the free share of Z falls below this.
        invalid_jump: Contamination fault when a camera's share of invalid pixels jumps
            by more than this between cycles.
        background_mismatch: Camera-moved fault when more than this share of the pixels
            that see the floor or a static object read farther than the reference allows.
        joint_state_max_age: Joint state older than this [s] is stale.
    """

    profile: Literal["iso", "ramp"] = "iso"
    human_speed: float = 1.6
    human_speed_close: float = 2.0
    close_distance: float = 0.5
    reaction_time: float = 0.1
    stopping_time: float = 0.3
    robot_speed_max: float = 1.5
    stopping_distance: float | None = None
    intrusion_distance: float = 0.0
    sensor_uncertainty: float = 0.05
    robot_uncertainty: float = 0.02
    ramp_stop_distance: float = 0.5
    ramp_full_distance: float = 2.0
    max_frame_age: float = 0.2
    cycle_deadline: float = 0.05
    min_free_share: float = 0.2
    invalid_jump: float = 0.25
    background_mismatch: float = 0.05
    joint_state_max_age: float = 0.1

    def __post_init__(self) -> None:
        if self.profile not in ("iso", "ramp"):
            raise CellError(f"safety.profile must be 'iso' or 'ramp', got {self.profile!r}")
        for name, value in self.__dict__.items():
            if name == "profile" or value is None:
                continue
            if not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise CellError(f"safety.{name} must be a finite number >= 0, got {value!r}")
        if self.robot_speed_max <= 0:
            raise CellError(f"safety.robot_speed_max must be > 0 m/s, got {self.robot_speed_max}")
        if self.ramp_full_distance <= self.ramp_stop_distance:
            raise CellError(
                "safety.ramp_full_distance must exceed safety.ramp_stop_distance, got "
                f"{self.ramp_full_distance} <= {self.ramp_stop_distance}"
            )
        if not 0 <= self.min_free_share < 1:
            raise CellError(f"safety.min_free_share must be in [0, 1), got {self.min_free_share}")


@dataclass(frozen=True)
class ReconstructionParams:
    """How the static model and the per-cycle pieces are built.

    Attributes:
        block: Pixels per block side of the static free surfaces (precomputed once): a
            piecewise-linear surface over b x b pixel blocks that never passes behind a
            pixel's static free depth. Smaller is tighter along depth edges and slower to
            precompute (2: ~15 s for the paper cell, cached on disk).
        tile: Pixels per tile side of the per-cycle pieces: the unexplained pixels of a
            tile start as one frustum piece, which the carving then splits.
        k_of_n: A point is free only if at least this many cameras see it free.
        shadow_memory: Keep the part of M touching the previous region
            (:mod:`polyhull.engine.memory`).
    """

    block: int = 2
    tile: int = 8
    k_of_n: int = 1
    shadow_memory: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.block, int) and 1 <= self.block <= 64):
            raise CellError(f"reconstruction.block must be an integer in [1, 64], got {self.block!r}")
        if not (isinstance(self.tile, int) and 1 <= self.tile <= 64):
            raise CellError(f"reconstruction.tile must be an integer in [1, 64], got {self.tile!r}")
        if not (isinstance(self.k_of_n, int) and self.k_of_n >= 1):
            raise CellError(f"reconstruction.k_of_n must be an integer >= 1, got {self.k_of_n!r}")


@dataclass(frozen=True)
class EntryArea:
    """A declared entry area (axis-aligned box, world frame [m]) where people come in."""

    name: str
    min: tuple[float, float, float]
    max: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo = _finite_vec(self.min, 3, f"entry '{self.name}'.min")
        hi = _finite_vec(self.max, 3, f"entry '{self.name}'.max")
        if not all(h > lo_ for lo_, h in zip(lo, hi, strict=True)):
            raise CellError(f"entry '{self.name}': max must exceed min on every axis")
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)


@dataclass(frozen=True)
class PlausibilityParams:
    """The plausibility rules that turn R2 into R3 (:mod:`polyhull.plausibility`); each is
    switchable.

    Attributes:
        floor_shell: Remove the depth-noise sheet above the floor, except under anything
            crossing ``floor_shell_height`` (see :mod:`polyhull.engine.static_model`).
        keep_at_boundary: Never remove by flying, too_small or too_thin a component that
            touches a wall or the ceiling of Z (a person outside may reach in).
        flying: Remove components with no support below them (floor or static object).
        too_small: Remove components with volume under ``min_volume``.
        too_thin: Remove components lying inside a shell of ``shell_thickness`` around
            known objects (obstacles, robot).
        entry: Remove components touching neither the boundary of Z, an entry area, nor a
            component of the previous cycle.
        teleport: Remove components farther than ``human_speed_max * dt`` from every
            component of the previous cycle.
        small_gaps: In image space, free the segments of pixel clusters without a reading
            (dropout patches, out-of-range pixels) walled in by pixels that read the static
            scene or the robot, as far as their rays are too narrow to hide an object of
            ``detection_size`` (whole when they are at their far end).
        support_eps: Contact tolerance [m] of the flying rule.
        min_volume: Smallest volume [m^3] of a person part that can appear alone.
        shell_thickness: Thickness [m] of the noise shell around known objects.
        human_speed_max: v_max [m/s] of the teleport and entry rules.
        floor_shell_height: Height [m] of the floor shell; above the noise band, below
            the thickness of a person lying down.
        floor_shell_margin: Horizontal reach [m] of feet around the legs' cross-section.
        standing_depth: How far [m] a person standing against a wall or an obstacle's side
            protrudes from it at the least (an adult's chest, head and feet: 0.18 m and
            more): the noise sheet in front of a vertical face is judged only this deep;
            where the static region reaches farther out, it stays (a person may stand in it
            unseen).
        detection_size: The detection capability [m]: the smallest cross-section of an
            object the small_gaps rule never removes.
        entry_areas: Declared entry areas.
    """

    floor_shell: bool = True
    keep_at_boundary: bool = True
    flying: bool = True
    too_small: bool = True
    too_thin: bool = True
    entry: bool = False
    teleport: bool = False
    small_gaps: bool = True
    support_eps: float = 0.05
    min_volume: float = 0.001
    shell_thickness: float = 0.04
    human_speed_max: float = 2.0
    floor_shell_height: float = 0.25
    floor_shell_margin: float = 0.3
    standing_depth: float = 0.15
    detection_size: float = 0.07
    entry_areas: tuple[EntryArea, ...] = ()

    def __post_init__(self) -> None:
        for name in (
            "support_eps",
            "min_volume",
            "shell_thickness",
            "human_speed_max",
            "floor_shell_height",
            "floor_shell_margin",
            "standing_depth",
            "detection_size",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise CellError(f"plausibility.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class MountingSurface:
    """A rectangle where cameras may be mounted (placement optimiser), world frame [m].

    The rectangle is ``origin + a * edge_u + b * edge_v`` for a, b in [0, 1].
    """

    name: str
    origin: tuple[float, float, float]
    edge_u: tuple[float, float, float]
    edge_v: tuple[float, float, float]

    def __post_init__(self) -> None:
        for attr in ("origin", "edge_u", "edge_v"):
            object.__setattr__(
                self, attr, _finite_vec(getattr(self, attr), 3, f"mounting '{self.name}'.{attr}")
            )
        if np.linalg.norm(np.cross(self.edge_u, self.edge_v)) < 1e-9:
            raise CellError(f"mounting '{self.name}': edge_u and edge_v must span a rectangle")

    def point(self, a: float, b: float) -> ArrayF64:
        """The point at rectangle coordinates (a, b) in [0, 1]^2 [m]."""
        return np.asarray(self.origin) + a * np.asarray(self.edge_u) + b * np.asarray(self.edge_v)


@dataclass(frozen=True, eq=False)
class Cell:
    """A work cell: everything the monitor, the simulator and the optimiser need.

    Attributes:
        name: Human-readable name.
        zone: The work cell Z.
        cameras: The cameras, names unique.
        obstacles: Static objects (rendered into the reference; solid ones subtracted).
        robot: The robot, or None for a cell without one.
        safety: Speed and separation and fault parameters.
        reconstruction: Region building and fusion parameters.
        plausibility: The R3 rules.
        mounting: Surfaces where the placement optimiser may put cameras.
        path: The cell file it was read from, if any.
        background: The taught background (``polyhull teach``), if the cell file names one;
            the static model uses it instead of the CAD reference where it is valid.
    """

    name: str
    zone: Zone
    cameras: tuple[Camera, ...]
    obstacles: tuple[Obstacle, ...] = ()
    robot: RobotSpec | None = None
    safety: SafetyParams = SafetyParams()
    reconstruction: ReconstructionParams = ReconstructionParams()
    plausibility: PlausibilityParams = PlausibilityParams()
    mounting: tuple[MountingSurface, ...] = ()
    path: Path | None = None
    background: TaughtBackground | None = None

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise CellError(f"camera names must be unique, repeated: {dup}")
        onames = [o.name for o in self.obstacles]
        odup = sorted({n for n in onames if onames.count(n) > 1})
        if odup:
            raise CellError(f"obstacle names must be unique, repeated: {odup}")
        if self.reconstruction.k_of_n > max(1, len(self.cameras)):
            raise CellError(
                f"reconstruction.k_of_n = {self.reconstruction.k_of_n} exceeds the number of "
                f"cameras ({len(self.cameras)})"
            )

    def camera(self, name: str) -> Camera:
        """The camera called ``name``."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise CellError(f"no camera named {name!r}; cameras are {[c.name for c in self.cameras]}")

    @property
    def solid_obstacles(self) -> tuple[Obstacle, ...]:
        """The obstacles a person cannot enter, O(j)."""
        return tuple(o for o in self.obstacles if o.solid)
