"""The monitor: one surveillance cycle from frames to a verdict (the pipeline).

Only this module knows the order of the stages:

1. frames: validation and per-camera free depth (:mod:`polyhull.regions`);
2. camera regions F(i);
3. fusion: the depth hull ``C = Z \\ F`` (:mod:`polyhull.fusion`), k-of-n optional;
4. robot occlusion M at q (:mod:`polyhull.occlusion`);
5. ``R2 = (C \\ M) U (C n M n grow(R_prev)) \\ O \\ robot`` (shadow memory, SPEC section 4);
6. plausibility: ``R3``: the floor-shell rule (:mod:`polyhull.floor`), then the rules over
   components (:mod:`polyhull.plausibility`);
7. distance between R3 and the robot (:mod:`polyhull.distance`, python-fcl);
8. speed (:mod:`polyhull.speed`).

``Monitor.step`` never raises: any fault gives a verdict with ``speed_scale = 0`` that names
it, and faults latch until :meth:`Monitor.reset`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import manifold3d as m3
import numpy as np

from .cell import Cell
from .distance import DistanceResult, RobotDistanceModel
from .errors import PolyhullError
from .floor import floor_shell
from .frames import DepthFrame
from .fusion import clip_to_box, depth_hull
from .occlusion import grow_piece, robot_occlusion
from .plausibility import (
    PlausibilityContext,
    RemovedComponent,
    apply_plausibility,
    mesh_volume_centroid,
)
from .regions import CameraStatic, check_manifold
from .robot import Robot
from .speed import decide_speed
from .typed import ArrayF64

__all__ = ["Monitor", "Verdict"]

_T = TypeVar("_T")


@dataclass(frozen=True, eq=False)
class Verdict:
    """The answer of one cycle.

    Attributes:
        stamp: Cycle time [s].
        q: Joint positions used [rad] (empty when the joint state was unusable).
        hull: The depth hull C = R1 (world frame).
        robot_occlusion: The robot occlusion M.
        region_r2: R2 = C minus M (with shadow memory), static solids and the robot.
        region: R3, what the distance is measured to.
        removed: Components removed by the plausibility rules, each with its rule.
        min_distance: Minimum distance between the region and the robot [m] (inf: none).
        closest_points: (2, 3) closest points [m] (on the region, on the robot) or None.
        closest_link: Name of the closest robot link, or None.
        speed_scale: Allowed share of the robot's maximum speed in [0, 1]; 0 means stop.
        allowed_speed: Allowed robot speed [m/s].
        separation_distance: Protective separation distance S_p [m] at that speed.
        faults: Latched faults; non-empty means stop.
        warnings: Conditions reported without stopping (e.g. cycle over its deadline).
        timings: Duration of each stage and ``total`` [ms].
    """

    stamp: float
    q: ArrayF64
    hull: m3.Manifold
    robot_occlusion: m3.Manifold
    region_r2: m3.Manifold
    region: m3.Manifold
    removed: tuple[RemovedComponent, ...]
    min_distance: float
    closest_points: ArrayF64 | None
    closest_link: str | None
    speed_scale: float
    allowed_speed: float
    separation_distance: float
    faults: tuple[str, ...]
    warnings: tuple[str, ...]
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def region_r1(self) -> m3.Manifold:
        """R1 = C, the paper's first approximation."""
        return self.hull

    def volumes(self) -> dict[str, float]:
        """Volumes [m^3] of C, M, R1, R2 and R3."""
        return {
            "volume_hull": self.hull.volume(),
            "volume_robot_occlusion": self.robot_occlusion.volume(),
            "volume_r1": self.hull.volume(),
            "volume_r2": self.region_r2.volume(),
            "volume_region": self.region.volume(),
        }

    def to_json(self) -> dict[str, Any]:
        """The JSON object of ``polyhull run --json`` (SPEC section 6)."""
        out: dict[str, Any] = dict(self.volumes())
        out.update(
            {
                "min_distance": self.min_distance if math.isfinite(self.min_distance) else None,
                "closest_link": self.closest_link,
                "closest_points": None if self.closest_points is None else self.closest_points.tolist(),
                "speed_scale": self.speed_scale,
                "allowed_speed": self.allowed_speed,
                "separation_distance": self.separation_distance
                if math.isfinite(self.separation_distance)
                else None,
                "faults": list(self.faults),
                "warnings": list(self.warnings),
                "removed": [
                    {"rule": r.rule, "volume": r.volume, "centroid": np.asarray(r.centroid).tolist()}
                    for r in self.removed
                ],
                "timings_ms": dict(self.timings),
                "stamp": self.stamp,
            }
        )
        return out


@dataclass
class _CameraHistory:
    last_stamp: float | None = None
    invalid_share: float | None = None


class Monitor:
    """Surveillance of one cell: precomputes the static parts, then runs a cycle per call.

    Example:
        >>> monitor = Monitor(cell)
        >>> verdict = monitor.step(frames, q, stamp=t)
        >>> robot_speed = verdict.speed_scale * v_max
    """

    def __init__(
        self,
        cell: Cell,
        *,
        references: Mapping[str, np.ndarray] | None = None,
        robot: Robot | None = None,
    ) -> None:
        """Precompute references, static camera regions and robot models.

        Args:
            cell: The cell.
            references: Reference depth per camera (H, W) [m]; rendered from the cell's
                CAD (floor and static obstacles) when omitted.
            robot: The robot model; loaded from ``cell.robot`` when omitted.

        Raises:
            PolyhullError: the cell cannot be monitored (bad reference, geometry failure).
        """
        self.cell = cell
        params = cell.reconstruction
        if references is None:
            from .raycast import render_reference

            references = render_reference(cell)
        self._statics: list[CameraStatic] = []
        for cam in cell.cameras:
            if cam.name not in references:
                raise PolyhullError(f"no reference depth for camera '{cam.name}'")
            ref = np.asarray(references[cam.name], dtype=np.float64)
            self._statics.append(CameraStatic(cam, ref, params.block))
        self._zone = cell.zone.manifold()
        # Clipped to the zone's box once: M is a subset of Z, where the clip changes nothing,
        # and the occlusion booleans skip the frustum parts beyond the walls.
        self._free_static = clip_to_box([s.free_static for s in self._statics], self._zone)
        # Clipped to Z: M (a subset of it) then stays inside the zone.
        self._free_static_union = check_manifold(
            m3.Manifold.batch_boolean([f for f in self._free_static if not f.is_empty()], m3.OpType.Add)
            ^ self._zone,
            "static free region",
        )
        self._hull_static = check_manifold(self._zone - self._free_static_union, "static hull")
        solids = [o.manifold() for o in cell.solid_obstacles]
        self._solids = m3.Manifold.batch_boolean(solids, m3.OpType.Add) if solids else m3.Manifold()
        self._support = m3.Manifold.batch_boolean([o.manifold() for o in cell.obstacles], m3.OpType.Add) if cell.obstacles else m3.Manifold()
        self._obstacle_manifolds = tuple(o.manifold() for o in cell.obstacles)
        if robot is None and cell.robot is not None:
            robot = Robot.from_spec(cell.robot)
        self.robot = robot
        self._padding = cell.robot.padding if cell.robot is not None else 0.0
        # Pieces grow by at most padding * sqrt(3) (cube corners): that is the margin added
        # to the protective separation distance.
        self._margin = self._padding * math.sqrt(3.0)
        if robot is not None:
            moving = _moving_links(robot)
            geometry = robot.link_geometry()
            self._distance_model: RobotDistanceModel | None = RobotDistanceModel(
                {name: mesh for name, mesh in geometry.items() if name in moving}
            )
            pieces = robot.link_convex_pieces()
            self._pieces_link = {
                name: [grow_piece(p, self._padding) for p in plist] for name, plist in pieces.items()
            }
        else:
            self._distance_model = None
            self._pieces_link = {}
        self.reset()

    # -- state -----------------------------------------------------------------------
    def reset(self) -> None:
        """Clear latched faults and the history (previous region, frame stamps)."""
        self._latched: list[str] = []
        self._history = {cam.name: _CameraHistory() for cam in self.cell.cameras}
        self._prev_region: m3.Manifold | None = None
        self._prev_components: tuple[m3.Manifold, ...] | None = None
        self._prev_stamp: float | None = None

    @property
    def statics(self) -> tuple[CameraStatic, ...]:
        """The precomputed static part of every camera."""
        return tuple(self._statics)

    @property
    def hull_static(self) -> m3.Manifold:
        """The depth hull of the empty cell (all frames equal to the references)."""
        return self._hull_static

    # -- per-camera inspection -------------------------------------------------------
    def camera_regions(self, frames: Mapping[str, DepthFrame]) -> dict[str, m3.Manifold]:
        """C(i) = Z \\ F(i) for every camera with a frame (inspection, not the hot path)."""
        out = {}
        for static in self._statics:
            frame = frames.get(static.camera.name)
            if frame is None or frame.shape != static.camera.shape:
                out[static.camera.name] = self._zone
                continue
            free, _ = static.free_region(frame.depth)
            out[static.camera.name] = self._zone - free
        return out

    # -- the cycle -------------------------------------------------------------------
    def step(
        self,
        frames: Mapping[str, DepthFrame],
        q: ArrayF64 | None,
        stamp: float | None = None,
        *,
        q_stamp: float | None = None,
    ) -> Verdict:
        """Run one surveillance cycle. Never raises.

        Args:
            frames: Camera name -> depth frame.
            q: Joint positions [rad] in URDF order, or None when the joint state is missing.
            stamp: Cycle time [s]; the newest frame stamp when omitted.
            q_stamp: Time the joint state was measured [s]; stale if older than
                ``safety.joint_state_max_age``.

        Returns:
            The verdict; ``speed_scale == 0`` whenever ``faults`` is non-empty.
        """
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        faults: list[str] = []
        warnings: list[str] = []
        try:
            return self._step(frames, q, stamp, q_stamp, t_start, timings, faults, warnings)
        except Exception as exc:  # noqa: BLE001 - the controller loop must never see one
            name = type(exc).__name__
            faults.append(f"internal: {name}: {exc}")
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)

    def _timed(self, timings: dict[str, float], stage: str, fn: Callable[[], _T]) -> _T:
        t0 = time.perf_counter()
        try:
            return fn()
        finally:
            timings[stage] = timings.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3

    def _stop_verdict(
        self,
        stamp: float | None,
        q: ArrayF64 | None,
        faults: list[str],
        warnings: list[str],
        timings: dict[str, float],
        t_start: float,
        hull: m3.Manifold | None = None,
    ) -> Verdict:
        for f in faults:
            if f not in self._latched:
                self._latched.append(f)
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        empty = m3.Manifold()
        return Verdict(
            stamp=float(stamp) if stamp is not None and math.isfinite(stamp) else math.nan,
            q=np.asarray(q, dtype=np.float64).reshape(-1) if q is not None else np.zeros(0),
            hull=hull if hull is not None else self._zone,
            robot_occlusion=empty,
            region_r2=hull if hull is not None else self._zone,
            region=hull if hull is not None else self._zone,
            removed=(),
            min_distance=0.0,
            closest_points=None,
            closest_link=None,
            speed_scale=0.0,
            allowed_speed=0.0,
            separation_distance=math.inf,
            faults=tuple(self._latched),
            warnings=tuple(warnings),
            timings=timings,
        )

    def _check_q(self, q: ArrayF64 | None, stamp: float, q_stamp: float | None, faults: list[str]) -> ArrayF64 | None:
        if self.robot is None:
            return np.zeros(0)
        if q is None:
            faults.append("joint state: missing")
            return None
        try:
            qv = self.robot.check_q(q)
        except PolyhullError as exc:
            faults.append(f"joint state: invalid: {exc}")
            return None
        if q_stamp is not None and stamp - q_stamp > self.cell.safety.joint_state_max_age:
            faults.append(
                f"joint state: stale ({stamp - q_stamp:.3f} s old > "
                f"{self.cell.safety.joint_state_max_age} s)"
            )
        return qv

    def _frame_faults(self, frames: Mapping[str, DepthFrame], stamp: float, faults: list[str]) -> dict[str, np.ndarray]:
        """Validate frames; return the usable depth per camera; list the faults."""
        usable: dict[str, np.ndarray] = {}
        max_age = self.cell.safety.max_frame_age
        known = {c.name for c in self.cell.cameras}
        for name in frames:
            if name not in known:
                faults.append(f"camera '{name}': frame for an unknown camera (cameras: {sorted(known)})")
        for static in self._statics:
            cam = static.camera
            frame = frames.get(cam.name)
            hist = self._history[cam.name]
            if frame is None:
                faults.append(f"camera '{cam.name}': frame missing")
                continue
            if not isinstance(frame, DepthFrame):
                faults.append(f"camera '{cam.name}': not a DepthFrame ({type(frame).__name__})")
                continue
            if frame.shape != cam.shape:
                faults.append(f"camera '{cam.name}': frame shape {frame.shape} != {cam.shape}")
                continue
            age = stamp - frame.stamp
            if age > max_age:
                faults.append(f"camera '{cam.name}': frame stale ({age:.3f} s old > {max_age} s)")
                continue
            if hist.last_stamp is not None:
                if frame.stamp == hist.last_stamp:
                    faults.append(f"camera '{cam.name}': frame duplicated (stamp {frame.stamp})")
                    continue
                if frame.stamp < hist.last_stamp:
                    faults.append(
                        f"camera '{cam.name}': frame out of order ({frame.stamp} < {hist.last_stamp})"
                    )
                    continue
            hist.last_stamp = frame.stamp
            usable[cam.name] = frame.depth
        return usable

    def _step(
        self,
        frames: Mapping[str, DepthFrame],
        q: ArrayF64 | None,
        stamp: float | None,
        q_stamp: float | None,
        t_start: float,
        timings: dict[str, float],
        faults: list[str],
        warnings: list[str],
    ) -> Verdict:
        cell = self.cell
        safety = cell.safety
        if not isinstance(frames, Mapping):
            faults.append(f"frames: expected a mapping camera name -> DepthFrame, got {type(frames).__name__}")
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)
        if stamp is None:
            stamps = [f.stamp for f in frames.values() if isinstance(f, DepthFrame)]
            stamp = max(stamps) if stamps else math.nan
        if not math.isfinite(stamp):
            faults.append(f"stamp: must be finite [s], got {stamp!r}")
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)

        # 1-2. frames -> per-camera free regions
        usable = self._timed(timings, "frames", lambda: self._frame_faults(frames, stamp, faults))
        if not usable:
            faults.append("coverage lost: no usable camera frame")
        free_regions: list[m3.Manifold] = []
        t0 = time.perf_counter()
        for static in self._statics:
            depth = usable.get(static.camera.name)
            if depth is None:
                continue  # a camera with no frame frees nothing
            free, info = static.free_region(depth)
            free_regions.append(free)
            hist = self._history[static.camera.name]
            if hist.invalid_share is not None and info.invalid_share - hist.invalid_share > safety.invalid_jump:
                faults.append(
                    f"camera '{static.camera.name}': contamination or masking: invalid pixels "
                    f"jumped from {hist.invalid_share:.1%} to {info.invalid_share:.1%}"
                )
            hist.invalid_share = info.invalid_share
            if info.far_side_share > safety.background_mismatch:
                faults.append(
                    f"camera '{static.camera.name}': moved or miscalibrated: {info.far_side_share:.1%} "
                    f"of the background reads beyond the reference (> {safety.background_mismatch:.1%})"
                )
        timings["camera_regions"] = (time.perf_counter() - t0) * 1e3

        # 3. fusion
        hull = self._timed(
            timings, "fusion", lambda: depth_hull(self._zone, free_regions, cell.reconstruction.k_of_n)
        )
        free_share = 1.0 - hull.volume() / cell.zone.volume
        if free_share < safety.min_free_share:
            faults.append(f"coverage lost: free share {free_share:.1%} < {safety.min_free_share:.1%}")

        # 4. robot occlusion
        qv = self._check_q(q, stamp, q_stamp, faults)
        if qv is None:
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start, hull=hull)
        T_links: dict[str, ArrayF64] = {}
        robot_body = m3.Manifold()
        robot_pieces: tuple[m3.Manifold, ...] = ()
        occlusion = m3.Manifold()
        if self.robot is not None:
            T_links = self._timed(timings, "kinematics", lambda: self.robot.link_transforms(qv))  # type: ignore[union-attr]
            pieces = [
                p @ T_links[name][:3, :3].T + T_links[name][:3, 3]
                for name, plist in self._pieces_link.items()
                for p in plist
            ]
            occlusion = self._timed(
                timings,
                "occlusion",
                lambda: robot_occlusion(
                    cell.cameras,
                    self._free_static,
                    self._free_static_union,
                    pieces,
                    cell.reconstruction.block,
                ),
            )
            robot_pieces = tuple(m3.Manifold.hull_points(p) for p in pieces)
            robot_body = m3.Manifold.batch_boolean(list(robot_pieces), m3.OpType.Add)

        # 5. R2 with the shadow memory
        def region_r2() -> m3.Manifold:
            # (C \ M) U (C n M n G) == C \ (M \ G): one clean subtraction.
            hidden = occlusion
            if (
                cell.reconstruction.shadow_memory
                and self._prev_region is not None
                and self._prev_stamp is not None
                and not occlusion.is_empty()
            ):
                dt = max(stamp - self._prev_stamp, 0.0)
                grown = _grow_near(self._prev_region, occlusion, safety.human_speed * dt + 1e-3)
                if not grown.is_empty():
                    hidden = occlusion - grown
            r = m3.Manifold.batch_boolean([hull, hidden, self._solids, robot_body], m3.OpType.Subtract)
            return check_manifold(r, "region R2")

        r2 = self._timed(timings, "subtract", region_r2)

        # 6. plausibility
        dt_prev = None if self._prev_stamp is None else max(stamp - self._prev_stamp, 0.0)
        ctx = PlausibilityContext(
            zone=cell.zone,
            params=cell.plausibility,
            support=self._support,
            known_objects=self._obstacle_manifolds + robot_pieces,
            previous=self._prev_components,
            dt=dt_prev,
            occlusion=occlusion if not occlusion.is_empty() else None,
        )
        floor_removed: tuple[RemovedComponent, ...] = ()
        r2_rules = r2
        if cell.plausibility.floor_shell:
            p = cell.plausibility
            r2_rules, sheet = self._timed(
                timings,
                "floor_shell",
                lambda: floor_shell(
                    r2,
                    hull,
                    cell.zone,
                    p.floor_shell_height,
                    p.floor_shell_margin,
                    m3.Manifold.batch_boolean([robot_body, self._solids], m3.OpType.Add),
                ),
            )
            if not sheet.is_empty():
                volume, centroid = mesh_volume_centroid(sheet)
                floor_removed = (RemovedComponent("floor_shell", volume, centroid, sheet),)
        result = self._timed(timings, "plausibility", lambda: apply_plausibility(r2_rules, ctx))
        region = check_manifold(result.region, "region R3")

        # 7. distance
        if self._distance_model is not None:
            dist = self._timed(timings, "distance", lambda: self._distance_model.distance(region, T_links))  # type: ignore[union-attr]
        else:
            dist = DistanceResult(math.inf, None, None)
        if dist.distance <= 0.0:
            faults.append(f"contact: the region touches robot link '{dist.link}'")

        # history for the next cycle
        self._prev_region = region
        self._prev_components = result.kept
        self._prev_stamp = stamp

        # 8. speed
        latency = time.perf_counter() - t_start
        decision = self._timed(
            timings, "speed", lambda: decide_speed(dist.distance, safety, latency, self._margin)
        )
        if latency > safety.cycle_deadline:
            warnings.append(f"cycle over its deadline: {latency * 1e3:.1f} ms > {safety.cycle_deadline * 1e3:.0f} ms")
        for f in faults:
            if f not in self._latched:
                self._latched.append(f)
        stop = bool(self._latched)
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        return Verdict(
            stamp=float(stamp),
            q=np.asarray(qv, dtype=np.float64),
            hull=hull,
            robot_occlusion=occlusion,
            region_r2=r2,
            region=region,
            removed=floor_removed + result.removed,
            min_distance=dist.distance,
            closest_points=dist.points,
            closest_link=dist.link,
            speed_scale=0.0 if stop else decision.speed_scale,
            allowed_speed=0.0 if stop else decision.allowed_speed,
            separation_distance=decision.separation,
            faults=tuple(self._latched),
            warnings=tuple(warnings),
            timings=timings,
        )


def _moving_links(robot: Robot) -> frozenset[str]:
    """Links whose pose depends on an actuated joint (the others are fixed to the world).

    A link fixed to the world (the base) cannot move toward a person; it is a static solid
    like an obstacle, so speed and separation monitoring measures to the moving links only.
    """
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    ref = robot.link_transforms((lo + hi) / 2)
    moving: set[str] = set()
    for _ in range(3):
        T = robot.link_transforms(rng.uniform(lo, hi))
        moving |= {n for n in ref if not np.allclose(T[n], ref[n], atol=1e-9)}
    return frozenset(moving)


def _box(lo: np.ndarray, hi: np.ndarray) -> m3.Manifold:
    size = tuple(float(x) for x in np.maximum(hi - lo, 1e-9))
    return m3.Manifold.cube(size).translate(tuple(float(x) for x in lo))


def _grow_near(region: m3.Manifold, target: m3.Manifold, margin: float) -> m3.Manifold:
    """A box containing every point of ``target`` within ``margin`` [m] of ``region``.

    The points of ``region`` that matter lie in the box of ``target`` grown by ``margin``;
    the bounding box of those points, grown by ``margin``, contains every point within
    ``margin`` of them. A superset keeps more of M in R, which is conservative.
    """
    if region.is_empty() or target.is_empty():
        return m3.Manifold()
    lo, hi = _bounds(target)
    near = region ^ _box(lo - margin, hi + margin)
    if near.is_empty():
        return m3.Manifold()
    lo, hi = _bounds(near)
    return _box(lo - margin, hi + margin)


def _bounds(m: m3.Manifold) -> tuple[np.ndarray, np.ndarray]:
    bb = m.bounding_box()
    return np.asarray(bb[:3], dtype=np.float64), np.asarray(bb[3:], dtype=np.float64)

