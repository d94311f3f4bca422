"""A procedural person: the target the simulator renders and the tests must find.

The body is built from spheres, capsules and hulls with human proportions scaled by the
height (segment lengths as fractions of stature after Drillis and Contini, widths and
girths of an average adult), posed by a few joint angles, and fused into one watertight
manifold with manifold3d.

Body frame: x forward, y to the person's left, z up, origin on the floor midway between
the feet. The mesh is placed in the world by a yaw about z (0 faces world +x) and a floor
position.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, get_args

import manifold3d as m3
import numpy as np
import trimesh

from .errors import GeometryError
from .typed import ArrayF64

__all__ = ["HEIGHTS", "POSES", "PersonPose", "make_person", "sample_points_inside", "PersonTrack"]

PersonPose = Literal["standing", "walking", "reaching", "crouching"]
POSES: tuple[str, ...] = get_args(PersonPose)
"""The poses :func:`make_person` builds."""

HEIGHTS = (0.5, 2.5)
"""The heights [m] :func:`make_person` builds a body for."""

# Segments per full circle of spheres; 16 keeps a person at a few thousand triangles.
_SEGMENTS = 16


@dataclass(frozen=True)
class _Proportions:
    """Body dimensions as fractions of the height (stature)."""

    head_radii: tuple[float, float, float] = (0.057, 0.045, 0.066)  # forward, lateral, up
    neck_radius: float = 0.030
    shoulder_z: float = 0.818  # shoulder joint height
    shoulder_y: float = 0.110  # lateral offset of the shoulder joint from the midline
    chest_z: float = 0.720
    chest_half_width: float = 0.085
    chest_half_depth: float = 0.065
    waist_z: float = 0.600
    waist_half_width: float = 0.075
    waist_half_depth: float = 0.055
    hip_z: float = 0.530  # hip joint height
    hip_y: float = 0.050  # lateral offset of the hip joint
    pelvis_half_width: float = 0.095
    pelvis_half_depth: float = 0.060
    upper_arm: float = 0.186
    upper_arm_radius: float = 0.026
    forearm: float = 0.146
    forearm_radius: float = 0.021
    hand: float = 0.090  # wrist to the centre of the fingers
    hand_radius: float = 0.022
    thigh: float = 0.245
    thigh_radius: float = 0.042
    shank: float = 0.246
    shank_radius: float = 0.030
    ankle_z: float = 0.039
    foot_length: float = 0.152
    foot_heel: float = 0.035  # heel behind the ankle
    foot_half_width: float = 0.030


_P = _Proportions()


def _rot_y(angle: float) -> ArrayF64:
    """Rotation about the lateral axis that swings a limb hanging along -z forward (+x).

    It maps (0, 0, -1) to (sin(angle), 0, -cos(angle)): a rotation by -angle about +y.
    """
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _rot_x(angle: float) -> ArrayF64:
    """Rotation by ``angle`` about +x (sideways abduction of a limb)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _sphere(center: ArrayF64, radius: float) -> m3.Manifold:
    return m3.Manifold.sphere(float(radius), _SEGMENTS).translate(tuple(map(float, center)))


def _capsule(a: ArrayF64, b: ArrayF64, radius: float) -> m3.Manifold:
    return m3.Manifold.batch_hull([_sphere(a, radius), _sphere(b, radius)])


def _ellipsoid(center: ArrayF64, radii: Sequence[float]) -> m3.Manifold:
    sphere = m3.Manifold.sphere(1.0, _SEGMENTS * 2)
    return sphere.scale(tuple(float(r) for r in radii)).translate(tuple(map(float, center)))


@dataclass(frozen=True)
class _Limb:
    """A two-segment limb: joint angles in [rad] (flexion about the lateral axis)."""

    swing: float  # upper segment from hanging straight down, + forward
    bend: float  # lower segment relative to the upper, + forward (elbow) / + back (knee)
    abduction: float = 0.0  # sideways, + away from the body


def _limb_points(
    root: ArrayF64, limb: _Limb, upper: float, lower: float, side: float, knee: bool
) -> tuple[ArrayF64, ArrayF64, ArrayF64]:
    """Root, middle joint and end points of a limb hanging from ``root`` (body frame)."""
    down = np.array([0.0, 0.0, -1.0])
    R_upper = _rot_x(side * limb.abduction) @ _rot_y(limb.swing)
    mid = root + R_upper @ (down * upper)
    bend = -limb.bend if knee else limb.bend
    end = mid + R_upper @ _rot_y(bend) @ (down * lower)
    return root, mid, end


def make_person(
    height: float = 1.75,
    pose: PersonPose = "standing",
    position: Sequence[float] = (0.0, 0.0),
    yaw: float = 0.0,
    phase: float = 0.0,
    floor_z: float = 0.0,
) -> trimesh.Trimesh:
    """A watertight person mesh standing on the floor.

    Args:
        height: Stature [m] (top of the head above the floor when standing).
        pose: ``"standing"`` (arms hanging), ``"walking"`` (legs and arms swung by
            ``phase``), ``"reaching"`` (both arms forward and slightly down, as over a
            table, hands about 0.6 m in front of the chest) or ``"crouching"`` (a deep
            squat, as to pick something up from the floor: thighs about level, the trunk
            leaning forward, the hands low in front of the knees; about 0.64 of the height
            tall).
        position: Floor position (x, y) of the point midway between the feet [m], world.
        yaw: Heading about world z [rad]; 0 faces world +x.
        phase: Gait phase [rad] of the walking pose; one gait cycle (two steps) is 2 pi.
        floor_z: Height of the floor [m]; the lowest point of the feet touches it.

    Returns:
        A watertight, outward-oriented trimesh in the world frame [m].
    """
    if not (np.isfinite(height) and HEIGHTS[0] <= height <= HEIGHTS[1]):
        raise GeometryError(f"person height must be in [{HEIGHTS[0]}, {HEIGHTS[1]}] m, got {height!r}")
    if pose not in POSES:
        raise GeometryError(f"person pose must be one of {list(POSES)}, got {pose!r}")
    xy = np.asarray(position, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise GeometryError(f"person position must be 2 finite numbers (x, y) [m], got {position!r}")
    for name, value in (("yaw", yaw), ("phase", phase), ("floor_z", floor_z)):
        if not np.isfinite(value):
            raise GeometryError(f"person {name} must be finite, got {value!r}")

    arms, legs = _pose_angles(pose, phase)
    body = _body(height, arms, legs, lean=_CROUCH_LEAN if pose == "crouching" else 0.0)
    # Feet on the floor: shift so that the lowest point sits at z = 0.
    lowest_z = float(body.bounding_box()[2])
    body = body.translate((0.0, 0.0, -lowest_z))
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.array(
        [[c, -s, 0.0, xy[0]], [s, c, 0.0, xy[1]], [0.0, 0.0, 1.0, float(floor_z)]]
    )
    body = body.transform(T)
    if body.status() != m3.Error.NoError or body.is_empty():
        raise GeometryError(f"person mesh construction failed (manifold3d {body.status().name})")
    out = body.to_mesh64()
    mesh = trimesh.Trimesh(
        np.asarray(out.vert_properties, dtype=np.float64)[:, :3],
        np.asarray(out.tri_verts, dtype=np.int64),
        process=False,
    )
    return mesh


def _pose_angles(pose: str, phase: float) -> tuple[tuple[_Limb, _Limb], tuple[_Limb, _Limb]]:
    """(left arm, right arm), (left leg, right leg) joint angles for a pose."""
    if pose == "standing":
        arm = _Limb(swing=0.0, bend=0.1, abduction=0.08)
        leg = _Limb(swing=0.0, bend=0.0, abduction=0.02)
        return (arm, arm), (leg, leg)
    if pose == "reaching":
        arm = _Limb(swing=np.radians(68.0), bend=np.radians(12.0), abduction=0.05)
        leg = _Limb(swing=0.0, bend=0.0, abduction=0.02)
        return (arm, arm), (leg, leg)
    if pose == "crouching":
        # thighs swung about level (knees a little apart), shanks folded back under them;
        # the arms hang forward from the leaning trunk, past the knees
        arm = _Limb(swing=np.radians(25.0), bend=np.radians(15.0), abduction=0.12)
        leg = _Limb(swing=np.radians(92.0), bend=np.radians(128.0), abduction=0.18)
        return (arm, arm), (leg, leg)
    # Walking: sinusoidal hip swing of +-25 deg, knee flexion peaking at 55 deg in swing,
    # arms swinging opposite to the legs by +-20 deg with slightly bent elbows.
    legs = []
    arms = []
    for side_phase in (0.0, np.pi):
        hip = np.radians(25.0) * np.sin(phase + side_phase)
        swing = max(0.0, np.sin(phase + side_phase + np.pi / 2))  # leg moving forward
        knee = np.radians(8.0) + np.radians(47.0) * swing**2
        legs.append(_Limb(swing=float(hip), bend=float(knee), abduction=0.02))
        arm = np.radians(20.0) * np.sin(phase + side_phase + np.pi)
        arms.append(_Limb(swing=float(arm), bend=np.radians(20.0), abduction=0.10))
    return (arms[0], arms[1]), (legs[0], legs[1])


_CROUCH_LEAN = np.radians(35.0)
"""The trunk's forward lean of the crouching pose [rad]."""


def _body(
    height: float, arms: tuple[_Limb, _Limb], legs: tuple[_Limb, _Limb], lean: float = 0.0
) -> m3.Manifold:
    """The posed body in the body frame before the floor shift (manifold); ``lean`` [rad]
    tilts the trunk, head and arms forward about the hip joints' axis."""
    h = height
    p = _P
    parts: list[m3.Manifold] = []
    # Head and neck.
    head_center = np.array([0.01 * h, 0.0, h - p.head_radii[2] * h])
    parts.append(_ellipsoid(head_center, [r * h for r in p.head_radii]))
    parts.append(
        _capsule(
            np.array([0.0, 0.0, p.shoulder_z * h]),
            head_center - np.array([0.0, 0.0, 0.03 * h]),
            p.neck_radius * h,
        )
    )
    # Torso: hull of ellipsoids at shoulders, chest, waist and pelvis.
    torso = [
        _ellipsoid(
            np.array([0.0, 0.0, (p.shoulder_z - 0.01) * h]),
            [p.chest_half_depth * 0.8 * h, p.shoulder_y * h, 0.035 * h],
        ),
        _ellipsoid(
            np.array([0.0, 0.0, p.chest_z * h]),
            [p.chest_half_depth * h, p.chest_half_width * h, 0.05 * h],
        ),
        _ellipsoid(
            np.array([0.0, 0.0, p.waist_z * h]),
            [p.waist_half_depth * h, p.waist_half_width * h, 0.05 * h],
        ),
        _ellipsoid(
            np.array([0.0, 0.0, (p.hip_z + 0.01) * h]),
            [p.pelvis_half_depth * h, p.pelvis_half_width * h, 0.045 * h],
        ),
    ]
    parts.append(m3.Manifold.batch_hull(torso))
    # Arms: upper arm, forearm, hand.
    for side, limb in zip((1.0, -1.0), arms, strict=True):
        root = np.array([0.0, side * p.shoulder_y * h, p.shoulder_z * h])
        a, b, c = _limb_points(root, limb, p.upper_arm * h, p.forearm * h, side, knee=False)
        parts.append(_sphere(a, p.upper_arm_radius * h * 1.15))
        parts.append(_capsule(a, b, p.upper_arm_radius * h))
        parts.append(_capsule(b, c, p.forearm_radius * h))
        direction = (c - b) / np.linalg.norm(c - b)
        parts.append(_capsule(c, c + direction * p.hand * h, p.hand_radius * h))
    if lean:
        # the upper body about the hip axis: +lean brings the head forward (+x)
        pivot = np.array([0.0, 0.0, p.hip_z * h])
        c, s = np.cos(lean), np.sin(lean)
        R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # (0, 0, 1) -> (s, 0, c)
        T = np.eye(4)[:3]
        T[:, :3] = R
        T[:, 3] = pivot - R @ pivot
        parts = [m3.Manifold.batch_boolean(parts, m3.OpType.Add).transform(T)]
    # Legs: thigh, shank, foot.
    for side, limb in zip((1.0, -1.0), legs, strict=True):
        root = np.array([0.0, side * p.hip_y * h, p.hip_z * h])
        a, b, c = _limb_points(root, limb, p.thigh * h, p.shank * h, side, knee=True)
        parts.append(_capsule(a, b, p.thigh_radius * h))
        parts.append(_capsule(b, c, p.shank_radius * h))
        parts.append(_foot(c, limb, h, side))
    body = m3.Manifold.batch_boolean(parts, m3.OpType.Add)
    return body


def _foot(ankle: ArrayF64, limb: _Limb, h: float, side: float) -> m3.Manifold:
    """A foot below the ankle: hull of a heel and a toe ball, pitched with the shank."""
    p = _P
    # Foot pitch follows the shank (hip swing minus knee bend), halved: the ankle
    # compensates part of it so the sole stays near the floor.
    pitch = 0.5 * (limb.swing - limb.bend)
    R = _rot_y(pitch)
    sole_r = p.ankle_z * h * 0.5
    heel = ankle + R @ np.array([-p.foot_heel * h + sole_r, 0.0, -p.ankle_z * h + sole_r])
    toe = ankle + R @ np.array(
        [(p.foot_length - p.foot_heel) * h - sole_r, side * 0.005 * h, -p.ankle_z * h + sole_r]
    )
    half_w = p.foot_half_width * h
    return m3.Manifold.batch_hull(
        [
            _sphere(ankle, p.shank_radius * h * 0.8),
            _ellipsoid(heel, [sole_r, half_w * 0.8, sole_r]),
            _ellipsoid(toe, [sole_r, half_w, sole_r]),
        ]
    )


def sample_points_inside(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> ArrayF64:
    """``n`` points uniformly distributed inside a watertight mesh (rejection sampling).

    Args:
        mesh: A watertight triangle mesh.
        n: Number of points.
        seed: Seed of the random generator.

    Returns:
        (n, 3) float64 points [m].
    """
    if n < 0:
        raise GeometryError(f"number of points must be >= 0, got {n}")
    if len(mesh.faces) == 0 or not mesh.is_watertight:
        raise GeometryError("sample_points_inside needs a non-empty watertight mesh")
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    box_volume = float(np.prod(hi - lo))
    share = max(float(mesh.volume) / box_volume, 1e-3) if box_volume > 0 else 1.0
    points: list[ArrayF64] = []
    count = 0
    for _ in range(100):
        if count >= n:
            break
        batch = int(min(2_000_000, max(256, 1.3 * (n - count) / share)))
        candidates = rng.uniform(lo, hi, size=(batch, 3))
        inside = candidates[mesh.contains(candidates)]
        points.append(inside)
        count += len(inside)
    if count < n:
        raise GeometryError(
            f"rejection sampling found only {count} of {n} points inside the mesh"
        )
    return np.concatenate(points)[:n] if points else np.zeros((0, 3))


@dataclass(frozen=True)
class PersonTrack:
    """A person walking along a straight line on the floor, then standing at the end.

    Attributes:
        start: Floor position (x, y) at ``t0`` [m], world.
        end: Floor position (x, y) where the walk ends [m], world.
        speed: Walking speed [m/s] (> 0).
        height: Stature [m].
        t0: Time [s] at which the walk starts; before it the person stands at ``start``.
        end_pose: Pose after arrival, e.g. ``"reaching"`` for a person reaching over a table.
        stride: Gait cycle length (two steps) [m]; None for 0.8 x height.
        floor_z: Floor height [m].
    """

    start: tuple[float, float]
    end: tuple[float, float]
    speed: float = 1.2
    height: float = 1.75
    t0: float = 0.0
    end_pose: PersonPose = "standing"
    stride: float | None = None
    floor_z: float = 0.0

    def __post_init__(self) -> None:
        for name in ("start", "end"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.shape != (2,) or not np.all(np.isfinite(value)):
                raise GeometryError(f"PersonTrack.{name} must be 2 finite numbers [m]")
            object.__setattr__(self, name, (float(value[0]), float(value[1])))
        if not (np.isfinite(self.speed) and self.speed > 0):
            raise GeometryError(f"PersonTrack.speed must be > 0 m/s, got {self.speed!r}")
        if self.stride is not None and not (np.isfinite(self.stride) and self.stride > 0):
            raise GeometryError(f"PersonTrack.stride must be > 0 m, got {self.stride!r}")

    @property
    def length(self) -> float:
        """Length of the path [m]."""
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    @property
    def duration(self) -> float:
        """Walking time from start to end [s]."""
        return self.length / self.speed

    @property
    def yaw(self) -> float:
        """Heading of the walk about world z [rad] (0 along +x)."""
        if self.length == 0.0:
            return 0.0
        return float(np.arctan2(self.end[1] - self.start[1], self.end[0] - self.start[0]))

    def distance(self, t: float) -> float:
        """Distance walked at time ``t`` [s], in [0, length] [m]."""
        return float(np.clip((t - self.t0) * self.speed, 0.0, self.length))

    def position(self, t: float) -> ArrayF64:
        """Floor position (x, y) [m] at time ``t`` [s]."""
        a = self.distance(t) / self.length if self.length > 0 else 0.0
        return (1.0 - a) * np.asarray(self.start) + a * np.asarray(self.end)

    def is_walking(self, t: float) -> bool:
        """True while the person is between start and end."""
        return self.t0 <= t < self.t0 + self.duration

    def params(self, t: float) -> dict[str, Any]:
        """The :func:`make_person` keyword arguments of the person at time ``t`` [s].

        Plain floats and strings, so they can be recorded (e.g. in a fixture manifest) and
        replayed with ``make_person(**params)``.
        """
        if self.is_walking(t):
            stride = 0.8 * self.height if self.stride is None else self.stride
            phase = float(2.0 * np.pi * self.distance(t) / stride)
            pose: PersonPose = "walking"
        else:
            phase = 0.0
            pose = "standing" if t < self.t0 else self.end_pose
        x, y = self.position(t)
        return {
            "height": float(self.height),
            "pose": pose,
            "position": (float(x), float(y)),
            "yaw": self.yaw,
            "phase": phase,
            "floor_z": float(self.floor_z),
        }

    def mesh(self, t: float) -> trimesh.Trimesh:
        """The person at time ``t`` [s] (world frame)."""
        return make_person(**self.params(t))
