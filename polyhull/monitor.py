"""The monitor: one surveillance cycle from frames to a verdict (the pipeline).

Only this module knows the order of the stages (:mod:`polyhull.engine`):

0. once, at construction: the static model (:mod:`polyhull.engine.static_model`), the
   padded robot pieces, the distance model;
1. ``frames``: validation (missing, stale, duplicated, out-of-order frames);
2. ``kinematics``: link poses at q;
3. ``robot_raster``: the padded robot in every camera's image;
4. ``pixels``: every pixel classified; the engine's free depth image of every camera;
5. ``pieces``: tiles of unexplained pixels, carved by the other cameras (the dynamic part);
6. ``memory``: the robot shadow's memory near what the previous cycle saw as a target
   (:mod:`polyhull.engine.memory`);
7. ``plausibility``: the rules on the dynamic components, the sheets under them;
8. ``distance``: static BVH and the dynamic pieces near the robot (python-fcl);
9. ``speed``: ISO/TS 15066 (or the ramp).

The region is ``R = R3_static U Delta_kept U sheets U memory``. The verdict's manifolds
(``hull``, ``robot_occlusion``, ``region_r2``, ``region``, ``region_dynamic``) are built
only when read, off the hot path.

``Monitor.step`` never raises: any fault gives a verdict with ``speed_scale = 0`` that names
it, and faults latch until :meth:`Monitor.reset`.
"""

from __future__ import annotations

import functools
import math
import time
import weakref
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any, Generic, NamedTuple, TypeVar

import manifold3d as m3
import numba as nb
import numpy as np
from scipy.spatial import ConvexHull

from .cell import Cell
from .distance import (
    STATIC_TOLERANCE,
    ChunkedMesh,
    DistanceResult,
    RobotDistanceModel,
    StaticDistance,
    winding_numbers,
)
from .engine.dynamic_rules import (
    DynamicContext,
    DynamicResult,
    LazyMesh,
    crosses_sheet_top,
    in_shells,
    judge_dynamic,
    sheets_under,
)
from .engine.edge_wedges import EdgeWedges, SheetTiles, robot_boxes
from .engine.memory import MEMORY_PIECE, ShadowMemory, seen_parts, within_reach
from .engine.pieces import (
    CameraStack,
    CarveParams,
    ImageStack,
    MTest,
    PieceSet,
    PyramidStack,
    carve,
    columns_in_m,
    merge_adjacent,
    piece_vertices,
    piece_volumes,
    vertex_bounds,
)
from .engine.pixels import (
    PixelBuffers,
    StaticClasses,
    classify_frame,
    prepare_static,
    small_gap_pixels,
    tile_segments,
    window_range,
)
from .engine.refine import (
    FRONT,
    FRONT_SLACK,
    MEMORY,
    OWN,
    REACH_EXTRA,
    SPARED,
    RegionRules,
    refine_kept,
)
from .engine.robot_raster import PaddedPieces, RasterBuffers, RobotRaster, rasterize_robot
from .engine.static_model import StaticModel
from .engine.threads import share
from .engine.warmup import warmup_frames
from .errors import PolyhullError
from .frames import DepthFrame
from .occlusion import robot_occlusion
from .plausibility import _ICOSPHERE, RemovedComponent
from .regions import check_manifold, free_region_from_depth
from .robot import Robot
from .speed import decide_speed
from .typed import ArrayF64

__all__ = ["Monitor", "Verdict"]

_T = TypeVar("_T")


def _hexahedra_manifold(vertices: ArrayF64) -> m3.Manifold:
    """The union of convex hexahedra (N, 8, 3) as one manifold."""
    hulls = [m3.Manifold.hull_points(v) for v in vertices]
    hulls = [h for h in hulls if not h.is_empty()]
    if not hulls:
        return m3.Manifold()
    return check_manifold(m3.Manifold.batch_boolean(hulls, m3.OpType.Add), "dynamic region")


@dataclass(eq=False)
class _CycleGeometry:
    """What a verdict needs to build its manifolds when they are read."""

    static: StaticModel
    zone: m3.Manifold
    pieces_parts: tuple[ArrayF64, ...]  # (N_i, 8, 3) all dynamic pieces before the rules (with memory)
    kept_pieces: ArrayF64  # (K, 8, 3) kept dynamic pieces
    kept_boxes: ArrayF64  # (K, 7) the same in their cameras' image space
    stack: CameraStack  # the cameras, for the pieces' vertices
    sheet_boxes: ArrayF64  # (S, 8, 3) the sheet boxes under them
    robot_body: Callable[[], m3.Manifold]
    occlusion: Callable[[], m3.Manifold]
    full_pieces: Callable[[], ArrayF64]
    lease: object = None  # holds the cycle's images (see _Pool)
    cache: dict[str, m3.Manifold] = field(default_factory=dict)

    @functools.cached_property
    def pieces(self) -> ArrayF64:
        """(N, 8, 3) all dynamic pieces before the rules (with the memory's)."""
        return np.concatenate(self.pieces_parts)

    @functools.cached_property
    def kept(self) -> ArrayF64:
        """(K, 8, 3) the kept dynamic pieces, then the sheet boxes."""
        return np.concatenate([self.kept_pieces, self.sheet_boxes])

    def get(self, name: str) -> m3.Manifold:
        if name not in self.cache:
            self.cache[name] = self._build(name)
        return self.cache[name]

    def _build(self, name: str) -> m3.Manifold:
        s = self.static
        if name == "region_dynamic":
            # The sheet boxes are supersets of the static sheet they stand for: as a
            # manifold, only their part in R2_static (the removed sheet) is shown.
            # (the same union from a third as many pieces: siblings merged back)
            pieces = _hexahedra_manifold(piece_vertices(merge_adjacent(self.kept_boxes), self.stack)) ^ self.zone
            sheets = _hexahedra_manifold(self.sheet_boxes) ^ s.region_r2
            return check_manifold(pieces + sheets, "dynamic region")
        if name == "region":
            return check_manifold(s.region + self.get("region_dynamic"), "region R3")
        if name == "region_r2":
            dyn = _hexahedra_manifold(self.pieces) ^ self.zone
            return check_manifold((s.region_r2 + dyn) - s.solids - self.robot_body(), "region R2")
        if name == "hull":
            return check_manifold(s.hull + (_hexahedra_manifold(self.full_pieces()) ^ self.zone), "hull C")
        if name == "robot_occlusion":
            return self.occlusion()
        raise KeyError(name)


@dataclass(frozen=True, eq=False)
class Verdict:
    """The answer of one cycle.

    Attributes:
        stamp: Cycle time [s].
        q: Joint positions used [rad] (empty when the joint state was unusable).
        removed: Components removed by the plausibility rules, each with its rule (the
            static ones, judged once, then this cycle's).
        min_distance: Minimum distance between the region and the robot [m] (inf: none).
        closest_points: (2, 3) closest points [m] (on the region, on the robot) or None.
        closest_link: Name of the closest robot link, or None.
        speed_scale: Allowed share of the robot's maximum speed in [0, 1]; 0 means stop.
        allowed_speed: Allowed robot speed [m/s].
        separation_distance: Protective separation distance S_p [m] at that speed.
        faults: Latched faults; non-empty means stop.
        warnings: Conditions reported without stopping (e.g. cycle over its deadline).
        timings: Duration of each stage and ``total`` [ms].
        counts: Per-cycle sizes: unexplained pixels, initial and kept pieces.

    The regions (``hull``, ``robot_occlusion``, ``region_r2``, ``region``,
    ``region_dynamic``) are manifold3d Manifolds built when first read.
    """

    stamp: float
    q: ArrayF64
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
    counts: dict[str, int] = field(default_factory=dict)
    _geometry: _CycleGeometry | None = field(default=None, repr=False)
    _fallback: m3.Manifold | None = field(default=None, repr=False)

    def _region(self, name: str) -> m3.Manifold:
        if self._geometry is None:
            if name in ("robot_occlusion", "region_dynamic"):
                return m3.Manifold()
            return self._fallback if self._fallback is not None else m3.Manifold()
        return self._geometry.get(name)

    @property
    def hull(self) -> m3.Manifold:
        """The depth hull C = R1 (world frame)."""
        return self._region("hull")

    @property
    def robot_occlusion(self) -> m3.Manifold:
        """The robot occlusion M of the padded robot."""
        return self._region("robot_occlusion")

    @property
    def region_r2(self) -> m3.Manifold:
        """R2 = C minus M (with shadow memory), the static solids and the robot."""
        return self._region("region_r2")

    @property
    def region(self) -> m3.Manifold:
        """R3, what the distance is measured to."""
        return self._region("region")

    @property
    def region_dynamic(self) -> m3.Manifold:
        """This cycle's part of R3: the kept dynamic pieces and the sheets under them."""
        return self._region("region_dynamic")

    @property
    def region_r1(self) -> m3.Manifold:
        """R1 = C, the paper's first approximation."""
        return self.hull

    def volumes(self) -> dict[str, float]:
        """Volumes [m^3] of C, M, R1, R2, R3 and the dynamic part (builds the manifolds)."""
        hull = self.hull.volume()
        return {
            "volume_hull": hull,
            "volume_robot_occlusion": self.robot_occlusion.volume(),
            "volume_r1": hull,
            "volume_r2": self.region_r2.volume(),
            "volume_region": self.region.volume(),
            "volume_region_dynamic": self.region_dynamic.volume(),
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
                "counts": dict(self.counts),
                "timings_ms": dict(self.timings),
                "stamp": self.stamp,
            }
        )
        return out


@dataclass
class _CameraHistory:
    last_stamp: float | None = None
    invalid_share: float | None = None


@dataclass(frozen=True, eq=False)
class CycleImages:
    """One cycle's per-camera images (inspection, tests, the bench's oracles).

    Attributes:
        free: Camera name -> (H, W) engine free depth [m].
        end: Camera name -> (H, W) end of each pixel's segment [m].
        raster: Camera name -> the padded robot's raster.

    The images are the monitor's buffers, reused by a later cycle only once this object is
    gone (the free-depth and end images also wait for the cycle's verdict).
    """

    free: dict[str, np.ndarray]
    end: dict[str, np.ndarray]
    raster: dict[str, RobotRaster]
    _lease: object = field(default=None, repr=False)  # holds the images and rasters (see _Pool)


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
        carve_params: CarveParams | None = None,
        static: StaticModel | None = None,
        warm_up: bool = True,
    ) -> None:
        """Precompute references, the static model and the robot models.

        Args:
            cell: The cell.
            references: Reference depth per camera (H, W) [m]; rendered from the cell's
                CAD (floor and static obstacles) when omitted.
            robot: The robot model; loaded from ``cell.robot`` when omitted.
            carve_params: How finely the dynamic pieces are split (defaults otherwise).
            static: A static model built before for the same cell and references.
            warm_up: Run two synthetic cycles (:mod:`polyhull.engine.warmup`) and forget
                them, so that the first real cycle costs what later ones do (0.3 s more
                on the default cell; without it its first two cycles take about 150 and
                50 ms, later ones 15 to 35 ms).

        Raises:
            PolyhullError: the cell cannot be monitored (bad reference, geometry failure).
        """
        self.cell = cell
        if references is None:
            from .raycast import render_reference

            references = render_reference(cell)
        self.static = static if static is not None else StaticModel.load_or_build(cell, dict(references))
        self.static.prepare()
        self._zone = self.static.zone
        self._stack = CameraStack.of(cell.cameras)
        self._carve = carve_params or CarveParams()
        self._dyn_ctx = DynamicContext.of(
            cell, self.static.sheets, self.static.touch, self.static.sheet_heights, static_near=self.static.boxes_meet
        )
        self._static_region_mesh = _mesh_arrays(self.static.region)
        if robot is None and cell.robot is not None:
            robot = Robot.from_spec(cell.robot)
        self.robot = robot
        self._padding = cell.robot.padding if cell.robot is not None else 0.0
        # A tile's merged piece may reach this far into the robot's padding (never the
        # robot itself, so never a false contact); deeper, the tile is split into pixels.
        self._tile_tol = 0.5 * self._padding
        # Pieces grow by at most padding * sqrt(3) (cube corners): that is the margin added
        # to the protective separation distance.
        self._margin = self._padding * math.sqrt(3.0)
        self._blind = {c.name: np.full(c.shape, np.nan, dtype=np.float32) for c in cell.cameras}
        self._inf_img = {c.name: np.full(c.shape, np.inf, dtype=np.float32) for c in cell.cameras}
        def shadow_memory(front: bool) -> ShadowMemory:
            return ShadowMemory(
                cell.cameras, [c.free_static for c in self.static.cameras], self._stack, cell.reconstruction.tile,
                self._tile_tol, front=front,
            )

        self._shadow = shadow_memory(False)
        self._binary = tuple(c.kind == "color" for c in cell.cameras)
        # the robot occlusion in front of the robot: a colour camera's whole ray, a depth
        # camera's tolerance band before the padded front
        self._shadow_front = shadow_memory(True)
        # a cycle's images (held by its verdict and last_images) and its rasters (held by
        # last_images only), reused once nobody holds them; the rasteriser's depth buffers,
        # one pair per camera, are left reset after each use
        self._static_classes = [
            prepare_static(s.lower, s.upper, s.free_static, c.near, s.edge)
            for c, s in zip(cell.cameras, self.static.cameras, strict=True)
        ]
        # the edge pixels' wedges, projected into the other cameras (built once)
        self._edge_wedges = EdgeWedges.build(self.static.cameras)
        # the band sheets' tiles, projected into the other cameras (built once)
        self._sheet_tiles = SheetTiles.build(
            self.static.cameras, cell.reconstruction.tile, cell.plausibility.floor_shell_margin,
            cell.plausibility.floor_shell_height,
        )
        # the static free depth and its pyramids, for the tests of M (built once)
        self._free_static = ImageStack(self._stack, fill=None)
        for i, s in enumerate(self.static.cameras):
            self._free_static.image(i)[:] = s.free_static
        self._static_pyramids = PyramidStack.build(self._free_static, np.ones(len(cell.cameras), dtype=bool))
        self._image_pool: _Pool[_CycleBuffers] = _Pool(
            lambda: _CycleBuffers(self._stack, self._static_classes, [s.free_static for s in self.static.cameras])
        )
        scratch = {
            c.name: (np.full(c.shape, np.inf, dtype=np.float64), np.full(c.shape, -np.inf, dtype=np.float64))
            for c in cell.cameras
        }
        self._raster_pool: _Pool[dict[str, RasterBuffers]] = _Pool(
            lambda: {c.name: RasterBuffers(c.shape, scratch[c.name]) for c in cell.cameras}
        )
        # the top of the floor's noise sheet (nothing crosses it without a floor sheet)
        floor = [sh for sh in self.static.sheets if sh.name == "floor"]
        self._floor_top = floor[0].level + floor[0].height if floor else -math.inf
        self._no_robot = {c.name: np.zeros(c.shape, dtype=bool) for c in cell.cameras}
        # per-camera work (robot raster, pixel classes) runs on two threads: the compiled
        # kernels release the GIL
        self._pool = ThreadPoolExecutor(max_workers=min(2, max(1, len(cell.cameras))), thread_name_prefix="polyhull")
        if robot is not None:
            moving = _moving_links(robot)
            geometry = robot.link_geometry()
            self._distance_model: RobotDistanceModel | None = RobotDistanceModel(
                {name: mesh for name, mesh in geometry.items() if name in moving}
            )
            self._padded: PaddedPieces | None = PaddedPieces.build(robot.link_convex_pieces(), self._padding)
            self._shell_planes = _ShellPlanes(_shell_planes(self._padded, cell.plausibility.shell_thickness))
            self._piece_spheres = [_sphere(v) for v in self._padded.vertices]
            # the padded pieces of the links the distance is measured to (not of a base fixed
            # to the world: the solids stand for it)
            self._measured = np.array([n in moving for n in self._padded.links], dtype=bool)
            self._static_distance: StaticDistance | None = StaticDistance(
                self._distance_model, ChunkedMesh.of_manifold(self.static.region, tolerance=STATIC_TOLERANCE), self._static_contains
            )
        else:
            self._static_distance = None
            self._distance_model = None
            self._padded = None
            self._shell_planes = _ShellPlanes([])
            self._piece_spheres = []
            self._measured = np.zeros(0, dtype=bool)
        self.reset()
        if warm_up:
            self._warm_up(references)

    def _warm_up(self, references: Mapping[str, np.ndarray]) -> None:
        """Two cycles on synthetic frames, then :meth:`reset`: compiled kernels loaded,
        buffers allocated, threads started. Their verdicts are dropped; no state they leave
        is read by a later cycle (history, faults and the previous region are reset, and
        the pooled buffers are rewritten where a cycle or the one before it wrote)."""
        q, points = None, np.zeros((0, 3))
        if self.robot is not None and self.cell.robot is not None:
            q = np.asarray(self.cell.robot.q, dtype=np.float64)
            points = np.array([T[:3, 3] for T in self.robot.link_transforms(q).values()])
        dt = 0.1
        for k, frames in enumerate(warmup_frames(self.cell, references, [0.0, dt], points)):
            self.step(frames, q, stamp=k * dt)
        self.reset()

    # -- state -----------------------------------------------------------------------
    def reset(self) -> None:
        """Clear latched faults and the history (previous region, frame stamps)."""
        self._latched: list[str] = []
        self._history = {cam.name: _CameraHistory() for cam in self.cell.cameras}
        self._prev_lo: ArrayF64 | None = None
        self._prev_hi: ArrayF64 | None = None
        self._seed_lo: ArrayF64 | None = None
        self._seed_hi: ArrayF64 | None = None
        self._prev_stamp: float | None = None
        self._prev_distance = math.inf  # where the last cycle's frontier was
        if self._static_distance is not None:
            self._static_distance.reset()
        self.last_images: CycleImages | None = None

    @property
    def statics(self) -> tuple:  # type: ignore[type-arg]
        """Every camera's static data (:class:`polyhull.engine.static_model.StaticCamera`)."""
        return self.static.cameras

    def camera_regions(self, frames: Mapping[str, DepthFrame]) -> dict[str, m3.Manifold]:
        """C(i) = Z minus F(i) for every camera with a frame of the right shape, built from the
        engine's free depth of ``frames`` (inspection, not the hot path; a camera without a
        usable frame frees nothing, so its C(i) is Z)."""
        out = {}
        for cam, s in zip(self.cell.cameras, self.static.cameras, strict=True):
            frame = frames.get(cam.name)
            if not isinstance(frame, DepthFrame) or frame.shape != cam.shape:
                out[cam.name] = self._zone
                continue
            cls = classify_frame(
                frame.depth, s.reference, s.lower, s.upper, s.free_static,
                np.full(cam.shape, np.inf, dtype=np.float32),
                near=cam.near, far=cam.far, tau_a=s.tau_a, tau_min=cam.tolerance_min,
                is_color=cam.kind == "color", edge=s.edge,
            )
            free = free_region_from_depth(cam, cls.free.astype(np.float64), self.cell.reconstruction.block)
            out[cam.name] = check_manifold(self._zone - free, f"camera '{cam.name}' region C(i)")
        return out

    @property
    def hull_static(self) -> m3.Manifold:
        """The depth hull of the empty cell (all frames equal to the references)."""
        return self.static.hull

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
            faults.append(f"internal: {type(exc).__name__}: {exc}")
            try:
                return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)
            except Exception as exc2:  # noqa: BLE001 - last resort, no formatting of inputs
                if (last := f"internal: {type(exc2).__name__}") not in self._latched:
                    self._latched.append(last)
                return Verdict(
                    stamp=math.nan, q=np.zeros(0), removed=(), min_distance=0.0, closest_points=None,
                    closest_link=None, speed_scale=0.0, allowed_speed=0.0,
                    separation_distance=math.inf,
                    faults=tuple(self._latched),
                    warnings=(), _fallback=self._zone,
                )

    def _timed(self, timings: dict[str, float], stage: str, fn: Callable[[], _T]) -> _T:
        t0 = time.perf_counter()
        try:
            return fn()
        finally:
            timings[stage] = timings.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3

    def _stop_verdict(
        self,
        stamp: object,
        q: object,
        faults: list[str],
        warnings: list[str],
        timings: dict[str, float],
        t_start: float,
    ) -> Verdict:
        for f in faults:
            if f not in self._latched:
                self._latched.append(f)
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        try:
            st = float(stamp)  # type: ignore[arg-type]
        except (TypeError, ValueError, OverflowError):
            st = math.nan
        # the verdict echoes q only when it is a real array (never a cast of bad input)
        # a copy: the verdict keeps no view of the caller's array
        qv = np.array(q, dtype=np.float64).reshape(-1) if q is not None and _is_real_array(q) else np.zeros(0)
        return Verdict(
            stamp=st if math.isfinite(st) else math.nan,
            q=qv,
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
            _fallback=self._zone,
        )

    def _check_q(self, q: object, stamp: float, q_stamp: object, faults: list[str]) -> ArrayF64 | None:
        if self.robot is None:
            return np.zeros(0)
        if q is None:
            faults.append("joint state: missing")
            return None
        if isinstance(q, str | bytes) or not _is_real_array(q):
            faults.append(f"joint state: invalid: q must be a sequence of real numbers [rad], got {type(q).__name__}")
            return None
        try:
            qv = self.robot.check_q(q)  # type: ignore[arg-type]
        except PolyhullError as exc:
            faults.append(f"joint state: invalid: {exc}")
            return None
        if qv.ndim != 1:
            faults.append(f"joint state: invalid: q must have shape ({self.robot.dof},), got {qv.shape}")
            return None
        if q_stamp is not None:
            try:
                age = stamp - float(q_stamp)  # type: ignore[arg-type]
            except (TypeError, ValueError, OverflowError):
                faults.append(f"joint state: q_stamp must be a time [s], got {q_stamp!r}")
                return None
            limit = self.cell.safety.joint_state_max_age
            if not age <= limit:
                faults.append(f"joint state: stale ({age:.4f} s old > {limit:.4f} s)")
        return qv

    def _frame_faults(self, frames: Mapping[str, DepthFrame], stamp: float, faults: list[str]) -> dict[str, np.ndarray]:
        """Validate frames; return the usable depth per camera; list the faults."""
        usable: dict[str, np.ndarray] = {}
        max_age = self.cell.safety.max_frame_age
        known = {c.name for c in self.cell.cameras}
        for name in frames:
            if name not in known:
                faults.append(f"camera '{name}': frame for an unknown camera (cameras: {sorted(known)})")
        for cam in self.cell.cameras:
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
            if not age <= max_age:
                faults.append(f"camera '{cam.name}': frame stale ({age:.4f} s old > {max_age:.4f} s)")
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
        q: object,
        stamp: object,
        q_stamp: object,
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
        if isinstance(stamp, bool) or not isinstance(stamp, int | float | np.integer | np.floating) or not _finite(stamp):
            faults.append(f"stamp: must be a finite time [s], got {stamp!r}")
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)
        t = float(stamp)

        usable = self._timed(timings, "frames", lambda: self._frame_faults(frames, t, faults))
        if not usable:
            faults.append("coverage lost: no usable camera frame")
        qv = self._check_q(q, t, q_stamp, faults)
        if qv is None:
            return self._stop_verdict(t, q, faults, warnings, timings, t_start)

        # kinematics and the padded robot in every image
        T_links: dict[str, ArrayF64] = {}
        padded_world: list[ArrayF64] = []
        spheres = np.zeros((0, 4))
        if self.robot is not None and self._padded is not None:
            T_links = self._timed(timings, "kinematics", lambda: self.robot.link_transforms(qv))  # type: ignore[union-attr]
            padded_world = self._padded.world(T_links)
            spheres = np.array(
                [
                    [*(T_links[n][:3, :3] @ c + T_links[n][:3, 3]), r]
                    for n, (c, r) in zip(self._padded.links, self._piece_spheres, strict=True)
                ]
            ).reshape(-1, 4)
        # this cycle's images, reused once no verdict or CycleImages holds them (fresh
        # allocations every cycle cost page faults, which serialise the two threads)
        bufs, lease = self._image_pool.take()
        raster_bufs, raster_lease = self._raster_pool.take()
        free_stack, end_stack, pyramids = bufs.free, bufs.end, bufs.pyramids
        pixel_bufs = bufs.pixels

        # each camera's robot raster, then its pixels, on this thread and one of the pool's
        # (one task a camera: no wait for the other cameras' rasters); the raster stage's time runs
        # until the last raster is done, the pixel stage's from then on
        t0 = time.perf_counter()
        raster_done = [t0] * len(cell.cameras)

        # where each camera sees the padded robot's pieces (the edge wedges and sheet tiles
        # their shadows may meet)
        boxes = robot_boxes(cell.cameras, padded_world)

        def camera(i: int) -> tuple[RobotRaster | None, _CameraPixels]:
            cam = cell.cameras[i]
            raster = None
            if padded_world:
                raster = rasterize_robot(cam, padded_world, self._padded, raster_bufs[cam.name])  # type: ignore[arg-type]
            raster_done[i] = time.perf_counter()
            return raster, self._camera_pixels(
                i, usable, raster, pixel_bufs[i], pyramids, bufs.end_pyramids, self._edge_wedges.ends(i, boxes),
                self._sheet_tiles.cycle(i, boxes),
            )

        done = share(self._pool, camera, range(len(cell.cameras)))
        rasters: dict[str, RobotRaster] = {
            cam.name: r for cam, (r, _) in zip(cell.cameras, done, strict=True) if r is not None
        }
        results = [p for _, p in done]
        t1 = max(raster_done)
        timings["robot_raster"] = (t1 - t0) * 1e3
        free_imgs: list[np.ndarray | None] = [free_stack.image(i) for i in range(len(cell.cameras))]
        end_imgs: list[np.ndarray | None] = [end_stack.image(i) for i in range(len(cell.cameras))]
        active = np.array([r.active for r in results], dtype=bool)
        init_parts = [r.tiles for r in results if len(r.tiles)]
        gap_parts = [r.gaps for r in results if len(r.gaps)]
        unexplained = sum(r.unexplained for r in results)
        for cam, r in zip(cell.cameras, results, strict=True):
            if not r.active:
                continue
            hist = self._history[cam.name]
            if hist.invalid_share is None and r.invalid_share > safety.invalid_jump:
                faults.append(
                    f"camera '{cam.name}': blind or masked: {r.invalid_share:.1%} of the pixels that "
                    f"see the cell have no depth (> {safety.invalid_jump:.1%})"
                )
            elif hist.invalid_share is not None and r.invalid_share - hist.invalid_share > safety.invalid_jump:
                faults.append(
                    f"camera '{cam.name}': contamination or masking: invalid pixels "
                    f"jumped from {hist.invalid_share:.1%} to {r.invalid_share:.1%}"
                )
            hist.invalid_share = r.invalid_share
            if r.far_side_share > safety.background_mismatch:
                faults.append(
                    f"camera '{cam.name}': moved or miscalibrated: {r.far_side_share:.1%} "
                    f"of the background reads beyond the reference (> {safety.background_mismatch:.1%})"
                )
        timings["pixels"] = (time.perf_counter() - t1) * 1e3
        if not active.all():
            # A camera without a usable frame frees nothing, so its whole image would become
            # pieces (thousands: ~1.5 s of geometry). Its fault latches and stops the robot,
            # so the verdict is a stop now, with the whole zone as its region (a superset).
            self.last_images = None
            return self._stop_verdict(t, qv, faults, warnings, timings, t_start)
        initial = np.concatenate(init_parts) if init_parts else np.zeros((0, 7))
        zlo = np.asarray(cell.zone.min, dtype=np.float64)
        zhi = np.asarray(cell.zone.max, dtype=np.float64)
        k = cell.reconstruction.k_of_n

        params = self._carve
        pyramid_stack = pyramids.only(active)
        # the memory's test of M: the segment ends (the free depth of the empty cell with
        # the padded robot) and the static free depth
        m_test = MTest(bufs.end_pyramids, self._static_pyramids)

        # The distance is decided near the frontier (about last cycle's distance): pieces
        # there, and pieces crossing the floor sheet's top within reach of it, are split
        # finely, coarser behind it (:mod:`polyhull.engine.refine` finishes the job).
        # the static region's distance: links measured only when their bound from the
        # last measurement (less their motion since) is below what the pieces give
        static_now = None if self._static_distance is None else self._static_distance.cycle(T_links)
        last = self._prev_distance
        if not math.isfinite(last) and static_now is not None:
            # no last cycle (after a reset): the static region's distance, which the
            # region's cannot exceed
            last = float(static_now.nearer().distance)
        front = max(last - FRONT_SLACK, 0.0) if math.isfinite(last) else 0.0
        floor_top = (self._floor_top, REACH_EXTRA + cell.plausibility.floor_shell_margin)

        def run_carve(
            init: np.ndarray, frees: ImageStack, ends: ImageStack, coarse: bool = False, memory_part: bool = False
        ) -> tuple[PieceSet, bool]:
            # coarse: the memory's (only inside M) or the hull C's pieces
            p = params
            if coarse:
                p = replace(p, size_min=max(p.size_min, MEMORY_PIECE), size_max=max(p.size_max, MEMORY_PIECE))
                return carve(
                    init, self._stack, active, pyramid_stack, frees, ends, spheres, zlo, zhi, k, p, pool=self._pool,
                    m_test=m_test if memory_part else None,
                )
            return carve(
                init, self._stack, active, pyramid_stack, frees, ends, spheres, zlo, zhi, k, p, front, floor_top,
                pool=self._pool,
            )

        pieces, overflow = self._timed(timings, "pieces", lambda: run_carve(initial, free_stack, end_stack))
        if overflow:
            warnings.append(f"pieces: the budget of {self._carve.max_pieces} pieces was reached; undecided pieces kept whole")

        # the robot shadow's memory near what the previous cycle saw as a target
        dt = None if self._prev_stamp is None else max(t - self._prev_stamp, 0.0)
        memory = memory_front = PieceSet.empty()
        mem_seeds = None  # the previous cycle's seeds, and a person's reach since
        if (
            cell.reconstruction.shadow_memory
            and rasters
            and self._seed_lo is not None
            and self._seed_hi is not None
            and len(self._seed_lo)
            and dt is not None
        ):
            s_lo, s_hi, reach = self._seed_lo, self._seed_hi, safety.human_speed * dt + 1e-3
            mem_seeds = (s_lo, s_hi, reach)

            def remember(shadow: ShadowMemory) -> PieceSet:
                return shadow.pieces(
                    rasters, free_imgs, lambda init, f, e: run_carve(init, f, e, True, True)[0], s_lo, s_hi, reach, self._pool
                )

            memory = self._timed(timings, "memory", lambda: remember(self._shadow))
            memory_front = self._timed(timings, "memory", lambda: remember(self._shadow_front))
        memory = PieceSet.concat([memory, memory_front])
        allp = PieceSet.concat([pieces, memory])
        vols = piece_volumes(allp.boxes, self._stack)
        at_robot = _at_robot(allp.boxes, [rasters.get(c.name) for c in cell.cameras])

        # plausibility of the dynamic components
        ctx = DynamicContext(
            **{
                **self._dyn_ctx.__dict__,
                "robot_shell_planes": self._shell_planes.world(T_links),
                "robot_spheres": spheres,
                "previous_lo": self._prev_lo,
                "previous_hi": self._prev_hi,
                "dt": dt,
                "m_columns": (
                    (lambda xy, h: columns_in_m(xy, h, self._stack, self._free_static, end_stack, active, k))
                    if rasters
                    else None
                ),
            }
        )
        result: DynamicResult = self._timed(
            timings,
            "plausibility",
            lambda: judge_dynamic(
                allp.vertices, vols, at_robot, ctx, lambda idx: _hexahedra_manifold(allp.vertices[idx]),
                memory=np.arange(len(allp)) >= len(pieces), pool=self._pool,
            ),
        )
        # coverage: the free share of Z is at least 1 - (C_static + pieces) / Z
        occupied = self.static.hull_volume + float(vols.sum())
        free_share = 1.0 - occupied / cell.zone.volume
        if free_share < safety.min_free_share:
            # a lower bound of the free share (overlapping pieces count twice)
            faults.append(
                f"coverage lost: only {max(free_share, 0.0):.1%} of the zone is surely seen free "
                f"(< {safety.min_free_share:.1%})"
            )

        # distance, with the kept pieces that decide it carved finely (the frontier), and
        # the sheets under what stands on a surface
        is_memory = np.arange(len(allp)) >= len(pieces)
        is_front = np.arange(len(allp)) >= len(allp) - len(memory_front)
        flags = (
            np.where(result.own, OWN, 0)
            | np.where(is_memory, MEMORY, 0)
            | np.where(is_front, FRONT, 0)
            | np.where(result.spared, SPARED, 0)
        )[result.keep].astype(np.int8)

        def recarve(boxes: np.ndarray, piece_flags: int, offset: float, alpha: float, size_min: float) -> PieceSet:
            p = replace(params, size_min=size_min, alpha=alpha)
            mem = bool(piece_flags & MEMORY)
            shadow = self._shadow_front if piece_flags & FRONT else self._shadow
            mem_stacks = None if shadow is None else shadow.stacks
            frees, ends = mem_stacks if mem and mem_stacks is not None else (free_stack, end_stack)
            out = carve(
                boxes, self._stack, active, pyramid_stack, frees, ends, spheres, zlo, zhi, k, p, offset, pool=self._pool,
                m_test=m_test if mem else None,
            )[0]
            if mem and mem_seeds is not None:
                # the memory is what comes within reach of the seeds: a coarse memory piece
                # that did at a corner is, carved finely, only its children that do
                out = within_reach(out, *mem_seeds, self._pool)
            return out

        def measure(vertices: ArrayF64, best: DistanceResult | None) -> DistanceResult:
            if self._distance_model is None or static_now is None:
                return DistanceResult(math.inf, None, None)
            if static_now.contact is not None:
                return static_now.contact
            res = self._distance_model.distance(T_links, pieces=vertices, best=best, cutoff=static_now.upper)
            return static_now.nearer(res)

        rules = RegionRules(
            in_shells=lambda v: in_shells(v, ctx),
            crossing=lambda v: crosses_sheet_top(v, ctx),
            sheets=lambda v: sheets_under(v, ctx),
            margin=cell.plausibility.floor_shell_margin,
            too_thin=cell.plausibility.too_thin,
        )
        # no robot: no refinement
        no_refine = self._distance_model is None
        refined = self._timed(
            timings,
            "distance",
            lambda: refine_kept(
                allp.select(result.keep), flags, result.inside[result.keep], rules,
                np.zeros((0, 4)) if no_refine else spheres, params.alpha, recarve, measure, self._pool,
                front if math.isfinite(last) else None, spheres[self._measured] if len(spheres) else None,
                sheets_under(result.legs, ctx, horizontal=True),
            ),
        )
        dist, sheet_boxes = refined.distance, refined.sheets
        kept_pieces = refined.pieces
        refine_removed = (_pieces_removed("too_thin", refined.cut, self._stack),) if len(refined.cut) else ()
        if dist.distance <= 0.0:
            faults.append(f"contact: the region touches robot link '{dist.link}'")

        # history for the next cycle: the kept dynamic pieces' boxes (not the sheet boxes,
        # which are the static noise layer under them, not an observation)
        observed = allp.vertices[result.keep]
        self._prev_lo, self._prev_hi = vertex_bounds(observed)
        seeds = seen_parts(
            allp.boxes[result.seeds], free_imgs, self._stack, self._binary, [r.invalid for r in results]
        )
        self._seed_lo, self._seed_hi = vertex_bounds(seeds)
        self._prev_stamp = t
        self._prev_distance = float(dist.distance)
        self.last_images = CycleImages(
            free={c.name: f for c, f in zip(cell.cameras, free_imgs, strict=True) if f is not None},
            end={c.name: e for c, e in zip(cell.cameras, end_imgs, strict=True) if e is not None},
            raster=rasters,
            _lease=(lease, raster_lease),
        )

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

        gap_boxes = np.concatenate(gap_parts) if gap_parts else np.zeros((0, 7))
        gap_verts = piece_vertices(gap_boxes, self._stack)
        gaps = _gaps_removed(gap_boxes, gap_verts, self._stack)
        geometry = _CycleGeometry(
            static=self.static,
            zone=self._zone,
            pieces_parts=(allp.vertices, gap_verts),
            kept_pieces=kept_pieces.vertices,
            kept_boxes=kept_pieces.boxes,
            stack=self._stack,
            sheet_boxes=sheet_boxes,
            robot_body=lambda: _robot_body(padded_world),
            occlusion=lambda: self._occlusion(padded_world),
            full_pieces=lambda: self._full_pieces(free_stack, run_carve),
            lease=lease,
        )
        return Verdict(
            stamp=t,
            q=np.array(qv, dtype=np.float64),  # a copy: check_q may return the caller's array
            removed=self.static.removed + gaps + result.removed + refine_removed,
            min_distance=dist.distance,
            closest_points=dist.points,
            closest_link=dist.link,
            speed_scale=0.0 if stop else decision.speed_scale,
            allowed_speed=0.0 if stop else decision.allowed_speed,
            separation_distance=decision.separation,
            faults=tuple(self._latched),
            warnings=tuple(warnings),
            timings=timings,
            counts={
                "unexplained_pixels": int(unexplained),
                "small_gap_pixels": int(sum(len(g) for g in gap_parts)),
                "initial_pieces": int(initial.shape[0]),
                "pieces": len(pieces),
                "memory_pieces": len(memory),
                "kept_pieces": int(result.keep.sum()),
                "refined_pieces": len(kept_pieces),
                "refine_rounds": refined.rounds,
                "sheet_boxes": int(sheet_boxes.shape[0]),
            },
            _geometry=geometry,
        )

    # -- parts of the cycle ------------------------------------------------------------
    def _camera_pixels(
        self,
        i: int,
        usable: Mapping[str, np.ndarray],
        raster: RobotRaster | None,
        buffers: PixelBuffers,
        pyramids: PyramidStack,
        end_pyramids: PyramidStack,
        wedges: tuple[np.ndarray, np.ndarray],
        sheets: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float],
    ) -> _CameraPixels:
        """One camera's pixel classes, small gaps, free-depth pyramids and initial tiles
        (thread-safe: it writes only camera ``i``'s images; ``wedges``: its edge pixels
        whose segment runs to their own free depth this cycle; ``sheets``: its
        :meth:`polyhull.engine.edge_wedges.SheetTiles.cycle`)."""
        cell = self.cell
        cam, s = cell.cameras[i], self.static.cameras[i]
        depth = usable.get(cam.name)
        if raster is None:
            shadow = self._inf_img[cam.name]
            covered = self._no_robot[cam.name]
        else:
            shadow = raster.shadow_start
            covered = raster.covered
        cls = classify_frame(
            depth if depth is not None else self._blind[cam.name],
            s.reference, s.lower, s.upper, s.free_static, shadow,
            near=cam.near, far=cam.far, tau_a=s.tau_a, tau_min=cam.tolerance_min,
            is_color=cam.kind == "color", tile=cell.reconstruction.tile,
            shadow_rect=(0, -1, 0, -1) if raster is None or raster.rect is None else raster.rect,
            static=self._static_classes[i],
            buffers=buffers,
            wedges=wedges,
            free_empty=s.free_empty,
            sheets=sheets,
        )
        gaps = np.zeros((0, 7))
        if cell.plausibility.small_gaps and depth is not None:
            vu = small_gap_pixels(
                cls.free, cls.end, cls.invalid, s.free_static, cam.near,
                cam.intrinsics.fx, cam.intrinsics.fy, cell.plausibility.detection_size,
                tiles=(cell.reconstruction.tile, cls.tiles),
            )
            if len(vu):
                v_idx, u_idx = vu[:, 0], vu[:, 1]
                gaps = np.column_stack(
                    [np.full(len(u_idx), float(i)), u_idx, u_idx, v_idx, v_idx, cls.free[v_idx, u_idx], cls.end[v_idx, u_idx]]
                )
                cls.free[v_idx, u_idx] = cls.end[v_idx, u_idx]
        # (also without a frame: the pyramids must follow the images they are kept for)
        pyramids.update_camera(i, buffers.changed)
        end_pyramids.update_camera(i, buffers.end_changed)
        tiles = tile_segments(
            cls.free, cls.end, covered, cell.reconstruction.tile,
            None if raster is None else raster.front, None if raster is None else raster.back, self._tile_tol,
            tiles=cls.tiles,
        )
        if len(tiles):
            tiles = np.column_stack([np.full(len(tiles), float(i)), tiles])
        return _CameraPixels(
            depth is not None, tiles, gaps, cls.unexplained, cls.invalid_share, cls.far_side_share, cls.invalid
        )

    def _static_contains(self, points: ArrayF64) -> np.ndarray:
        """Which points (P, 3) lie inside R3_static (touch grid first, then winding number)."""
        near = self.static.touch.any_in(points, points)
        out = np.zeros(len(points), dtype=bool)
        if near.any() and self._static_region_mesh is not None:
            v, t = self._static_region_mesh
            out[near] = winding_numbers(points[near], v, t) > 0.5
        return out

    def _full_pieces(self, free_stack: ImageStack, run_carve: Callable[..., tuple[PieceSet, bool]]) -> ArrayF64:
        """Every camera's segments without the robot's shadow clip (for the hull C)."""
        parts = []
        ends = ImageStack(self._stack)
        for i, (cam, s) in enumerate(zip(self.cell.cameras, self.static.cameras, strict=True)):
            free = free_stack.image(i)
            ends.image(i)[:] = s.free_static
            tiles = tile_segments(free, s.free_static, np.zeros(cam.shape, dtype=bool), self.cell.reconstruction.tile)
            if len(tiles):
                parts.append(np.column_stack([np.full(len(tiles), float(i)), tiles]))
        if not parts:
            return np.zeros((0, 8, 3))
        # C is drawn and measured, never used for the distance: coarse pieces (a superset)
        pieces, _ = run_carve(np.concatenate(parts), free_stack, ends, True)
        return pieces.vertices

    def _occlusion(self, padded_world: list[ArrayF64]) -> m3.Manifold:
        """M of the padded robot (built when read)."""
        if not padded_world:
            return m3.Manifold()
        pad = self._padding
        # a depth camera's shadow starts in the tolerance band before the padded robot, a
        # colour camera's at ``near`` (binary depth: the robot hides the whole ray)
        bands = [
            (lambda z, c=cam: np.maximum(0.0, z - c.near))
            if cam.kind == "color"
            else (lambda z, c=cam: np.maximum(0.0, 2.0 * c.tau(z) - pad))
            for cam in self.cell.cameras
        ]
        union = m3.Manifold.batch_boolean([f for f in self.static.free if not f.is_empty()], m3.OpType.Add) ^ self._zone
        return robot_occlusion(self.cell.cameras, self.static.free, union, padded_world, bands)


def _pieces_removed(rule: str, pieces: PieceSet, stack: CameraStack) -> RemovedComponent:
    """One removed component made of ``pieces`` (its mesh built when read)."""
    vols = piece_volumes(pieces.boxes, stack)
    centres = 0.5 * np.add(*vertex_bounds(pieces.vertices))
    centroid = (centres * vols[:, None]).sum(axis=0) / max(float(vols.sum()), 1e-12)
    return RemovedComponent(rule, float(vols.sum()), centroid, LazyMesh(_hexahedra_manifold, pieces.vertices))


def _gaps_removed(boxes: ArrayF64, verts: ArrayF64, stack: CameraStack) -> tuple[RemovedComponent, ...]:
    """The pixel segments (boxes (N, 7), vertices (N, 8, 3)) the small_gaps rule freed this
    cycle, as one reported removal (they are part of R2, before the rules)."""
    return (_pieces_removed("small_gaps", PieceSet(boxes, verts), stack),) if len(boxes) else ()


class _CycleBuffers:
    """One cycle's images: every camera's free depth, segment ends and pyramids."""

    def __init__(self, stack: CameraStack, statics: list[StaticClasses], free_static: list[np.ndarray]) -> None:
        self.free = ImageStack(stack, fill=None)
        self.end = ImageStack(stack, fill=None)
        # the static images, and their pyramids: each cycle restores and updates only
        # what the last one changed
        self.pixels = [
            PixelBuffers(st, fs, self.free.image(i), self.end.image(i))
            for i, (st, fs) in enumerate(zip(statics, free_static, strict=True))
        ]
        self.pyramids = PyramidStack.allocate(self.free)
        # the segment ends' pyramids: outside them is the padded robot's occlusion M
        # (what the shadow memory holds, :mod:`polyhull.engine.memory`)
        self.end_pyramids = PyramidStack.allocate(self.end)
        for i in range(len(statics)):
            self.pyramids.build_camera(i)
            self.end_pyramids.build_camera(i)


class _Lease:
    """What a cycle's readers hold while buffers of a :class:`_Pool` are in use."""


class _Pool(Generic[_T]):
    """Buffers reused once nobody holds their lease.

    A cycle takes buffers with a lease (:meth:`take`); whatever reads them later (the
    verdict's lazy geometry, ``last_images``) holds the lease, and when the lease is gone
    the buffers go back to the spares. Buffers whose lease is kept for long stay as they
    are; the pool then makes new ones.
    """

    def __init__(self, make: Callable[[], _T]) -> None:
        self._make = make
        self._spare: list[_T] = []

    def take(self) -> tuple[_T, _Lease]:
        item = self._spare.pop() if self._spare else self._make()
        lease = _Lease()
        weakref.finalize(lease, self._spare.append, item)
        return item, lease


class _CameraPixels(NamedTuple):
    """What one camera's pixel pass gives the cycle."""

    active: bool  # the camera had a usable frame
    tiles: np.ndarray  # (T, 7) initial pieces
    gaps: np.ndarray  # (G, 7) pixel segments freed by small_gaps
    unexplained: int
    invalid_share: float
    far_side_share: float
    invalid: np.ndarray | None = None  # (H, W) pixels without a usable reading (this cycle's buffer)


def _robot_body(padded_world: list[ArrayF64]) -> m3.Manifold:
    if not padded_world:
        return m3.Manifold()
    return m3.Manifold.batch_boolean([m3.Manifold.hull_points(p) for p in padded_world], m3.OpType.Add)


def _mesh_arrays(m: m3.Manifold) -> tuple[ArrayF64, np.ndarray] | None:
    if m.is_empty():
        return None
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int64)


def _finite(x: int | float | np.integer | np.floating) -> bool:
    """Whether a number is finite as a float (an int too large for a float is not)."""
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _is_real_array(q: object) -> bool:
    try:
        arr = np.asarray(q)
    except Exception:  # noqa: BLE001 - ragged or exotic input
        return False
    return arr.dtype.kind in "iuf"


def _sphere(vertices: ArrayF64) -> tuple[ArrayF64, float]:
    c = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return c, float(np.linalg.norm(vertices - c, axis=1).max())


def _shell_planes(padded: PaddedPieces, thickness: float) -> list[tuple[str, ArrayF64]]:
    """Per padded piece, (F, 4) planes ``n . x <= d`` (link frame) of the piece grown by a
    polytope inscribed in the ball of radius ``thickness``: inside the true shell."""
    out = []
    for name, v in zip(padded.links, padded.vertices, strict=True):
        grown = (v[:, None, :] + thickness * _ICOSPHERE[None, :, :]).reshape(-1, 3)
        eq = ConvexHull(grown).equations  # n . x + c <= 0 inside
        out.append((name, np.column_stack([eq[:, :3], -eq[:, 3]])))
    return out


class _ShellPlanes:
    """Every padded piece's shell planes (link frame), moved to the world in one batch."""

    def __init__(self, planes: list[tuple[str, ArrayF64]]) -> None:
        self._links = [n for n, _ in planes]
        self._flat = np.concatenate([p for _, p in planes]).reshape(-1, 4) if planes else np.zeros((0, 4))
        self._piece = np.repeat(np.arange(len(planes)), [len(p) for _, p in planes]).astype(np.int64)
        self._splits = np.cumsum([len(p) for _, p in planes])[:-1]

    def world(self, T_links: Mapping[str, ArrayF64]) -> tuple[ArrayF64, ...]:
        """(F_i, 4) planes ``n . x <= d`` of every piece in the world frame."""
        if not self._links:
            return ()
        T = np.array([T_links[n] for n in self._links], dtype=np.float64)
        out = np.empty_like(self._flat)
        _move_planes(self._flat, self._piece, T, out)
        return tuple(np.split(out, self._splits))


@nb.njit(cache=True, nogil=True)
def _move_planes(planes, piece, T, out):  # pragma: no cover - compiled
    """Planes ``n . x <= d`` (F, 4) of piece ``piece[f]`` from its frame to the world
    (``T`` (P, 4, 4), world from piece): ``n' = R n``, ``d' = d + n' . t``."""
    for f in range(planes.shape[0]):
        p = piece[f]
        dot = 0.0
        for a in range(3):
            x = T[p, a, 0] * planes[f, 0] + T[p, a, 1] * planes[f, 1] + T[p, a, 2] * planes[f, 2]
            out[f, a] = x
            dot += x * T[p, a, 3]
        out[f, 3] = planes[f, 3] + dot


def _at_robot(boxes: np.ndarray, rasters: list[RobotRaster | None]) -> np.ndarray:
    """(N,) whether each piece's pixel rectangle meets the robot's raster in its camera."""
    out = np.zeros(len(boxes), dtype=bool)
    for i, r in enumerate(rasters):
        if r is None:
            continue
        sel = np.nonzero(boxes[:, 0] == i)[0]
        if len(sel) == 0:
            continue
        _, covered_max = window_range(r.covered.view(np.uint8), boxes[sel, 1:5].astype(np.int64))
        out[sel] = covered_max > 0
    return out


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
