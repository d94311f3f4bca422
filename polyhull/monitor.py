"""The monitor: one surveillance cycle from frames to a verdict (the pipeline).

Only this module knows the order of the stages (:mod:`polyhull.engine`):

0. once, at construction: the static model (:mod:`polyhull.engine.static_model`), the
   padded robot pieces, the distance model;
1. ``frames``: validation (missing, stale, duplicated, out-of-order frames);
2. ``kinematics``: link poses at q, the padded robot's pieces in the world;
3. ``robot_raster``: the padded robot in every camera's image;
4. ``pixels``: every pixel classified; the engine's free depth image of every camera;
5. ``pieces``: tiles of unexplained pixels, carved by the other cameras (the dynamic part);
6. ``memory``: the robot shadow's memory near what the previous cycle saw as a target
   (:mod:`polyhull.engine.memory`);
7. ``plausibility``: the rules on the dynamic components, the sheets under them;
8. ``distance``: static BVH and the dynamic pieces near the robot (python-fcl);
9. ``speed``: ISO/TS 15066 (or the ramp).

Each stage is a method of :class:`Monitor` (``_images``, ``_carving`` and the carve,
``_memory``, ``_judge``, ``_distance``, ``_remember``) that takes what the stages before it
produced and returns its own; :meth:`Monitor._step` calls them in this order. The padded
robot at q comes from :mod:`polyhull.engine.robot_pose`, the reused image buffers from
:mod:`polyhull.engine.buffers`.

The region is ``R = R3_static U Delta_kept U sheets U memory``. The verdict
(:mod:`polyhull.verdict`) builds its manifolds (``hull``, ``robot_occlusion``,
``region_r2``, ``region``, ``region_dynamic``) only when they are read, off the hot path.

``Monitor.step`` never raises: any fault gives a verdict with ``speed_scale = 0`` that names
it, and faults latch until :meth:`Monitor.reset`.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any, NamedTuple, TypeVar

import manifold3d as m3
import numpy as np

from .cachedir import kernel_cache_directory, kernels_cached
from .cell import Cell
from .distance import (
    STATIC_TOLERANCE,
    ChunkedMesh,
    DistanceResult,
    RobotDistanceModel,
    StaticCycle,
    StaticDistance,
    winding_numbers,
)
from .engine.buffers import CycleBuffers, Lease, Pool
from .engine.dynamic_rules import (
    DynamicContext,
    DynamicResult,
    crosses_sheet_top,
    hidden_legs,
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
    piece_vertices,
    piece_volumes,
    vertex_bounds,
)
from .engine.pixels import (
    PixelBuffers,
    classify_frame,
    only_marked_segments,
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
    RESIDUE,
    SPARED,
    Refined,
    RegionRules,
    refine_kept,
)
from .engine.robot_pose import NO_ROBOT, RobotPieces, RobotPose
from .engine.robot_raster import PaddedPieces, RasterBuffers, RobotRaster, rasterize_robot
from .engine.static_model import StaticModel
from .engine.threads import Beside, share
from .engine.warmup import warmup_frames
from .errors import PolyhullError
from .frames import DepthFrame
from .occlusion import robot_occlusion
from .regions import check_manifold, free_region_from_depth
from .robot import Robot
from .speed import decide_speed
from .typed import ArrayF64
from .verdict import (
    CycleGeometry,
    CycleImages,
    Verdict,
    gaps_removed,
    pieces_manifold,
    pieces_removed,
)

__all__ = ["Monitor", "Verdict"]

_T = TypeVar("_T")

log = logging.getLogger(__name__)


@dataclass
class _CameraHistory:
    last_stamp: float | None = None
    invalid_share: float | None = None


class _CameraPixels(NamedTuple):
    """What one camera's pixel pass gives the cycle."""

    active: bool  # the camera had a usable frame
    tiles: np.ndarray  # (T, 7) initial pieces
    gaps: np.ndarray  # (G, 7) pixel segments freed by small_gaps
    unexplained: int
    invalid_share: float
    far_side_share: float
    invalid: np.ndarray | None = None  # (H, W) pixels without a usable reading (this cycle's buffer)


@dataclass(frozen=True, eq=False)
class _Images:
    """The image stages' product: every camera's robot raster and pixel pass, in the
    cycle's buffers (held by ``lease`` and ``raster_lease``)."""

    bufs: CycleBuffers
    lease: Lease
    raster_lease: Lease
    rasters: dict[str, RobotRaster]
    pixels: list[_CameraPixels]
    free: list[np.ndarray]  # (H, W) every camera's free depth
    end: list[np.ndarray]  # (H, W) every camera's segment ends
    active: np.ndarray  # (n,) which cameras had a usable frame

    @functools.cached_property
    def initial(self) -> ArrayF64:
        """(T, 7) the tiles of unexplained pixels of every camera: the initial pieces."""
        parts = [p.tiles for p in self.pixels if len(p.tiles)]
        return np.concatenate(parts) if parts else np.zeros((0, 7))

    @functools.cached_property
    def gaps(self) -> ArrayF64:
        """(G, 7) the pixel segments the small_gaps rule freed, of every camera."""
        parts = [p.gaps for p in self.pixels if len(p.gaps)]
        return np.concatenate(parts) if parts else np.zeros((0, 7))


class _Memory(NamedTuple):
    """The shadow memory's pieces (behind the robot, in front of it) and the seeds they
    were kept within reach of (None: no memory this cycle)."""

    pieces: PieceSet
    front: PieceSet
    seeds: tuple[ArrayF64, ArrayF64, float] | None


class _History(NamedTuple):
    """What the next cycle keeps of this one (:meth:`Monitor._next_history`)."""

    kept_lo: ArrayF64  # (K, 3) the kept pieces' boxes
    kept_hi: ArrayF64
    seed_lo: ArrayF64  # (S, 3) the shadow memory's seeds' boxes
    seed_hi: ArrayF64


@dataclass(frozen=True, eq=False)
class _Carving:
    """:func:`polyhull.engine.pieces.carve` bound to one cycle: the cameras, their images
    and pyramids, the robot's spheres and the frontier (see :meth:`Monitor._carving`)."""

    stack: CameraStack
    active: np.ndarray
    pyramids: PyramidStack
    free: ImageStack
    end: ImageStack
    spheres: ArrayF64
    zone_lo: ArrayF64
    zone_hi: ArrayF64
    k: int
    params: CarveParams
    m_test: MTest
    front: float  # [m] the frontier (0 when unknown)
    front_known: bool
    floor_top: tuple[float, float]  # the floor sheet's top [m] and its reach [m]
    shadows: tuple[ShadowMemory, ShadowMemory]  # the memories behind and in front of the robot
    static_now: StaticCycle | None
    pool: ThreadPoolExecutor

    def _run(
        self, init: ArrayF64, frees: ImageStack, ends: ImageStack, p: CarveParams, offset: float = 0.0, **kw: Any
    ) -> tuple[PieceSet, bool]:
        return carve(
            init, self.stack, self.active, self.pyramids, frees, ends, self.spheres, self.zone_lo, self.zone_hi,
            self.k, p, offset, pool=self.pool, **kw,
        )

    def hull(self, init: ArrayF64) -> tuple[PieceSet, bool]:
        """The region's pieces from the initial tiles ``init`` (N, 7): split finely at the
        frontier and where they cross the floor sheet's top near it; and whether the piece
        budget was reached."""
        return self._run(init, self.free, self.end, self.params, self.front, sheet=self.floor_top)

    def coarse(self, init: ArrayF64, frees: ImageStack, ends: ImageStack, memory: bool = False) -> tuple[PieceSet, bool]:
        """Pieces no finer than ``MEMORY_PIECE``: the memory's (inside M, tested by
        ``m_test`` when ``memory``) or the hull C's (drawn, never measured)."""
        p = self.params
        p = replace(p, size_min=max(p.size_min, MEMORY_PIECE), size_max=max(p.size_max, MEMORY_PIECE))
        return self._run(init, frees, ends, p, m_test=self.m_test if memory else None)

    def memory(self, init: ArrayF64, frees: ImageStack, ends: ImageStack) -> PieceSet:
        """The shadow memory's pieces (:meth:`coarse` with the test of M)."""
        return self.coarse(init, frees, ends, memory=True)[0]

    def recarve(
        self,
        boxes: ArrayF64,
        piece_flags: int,
        offset: float,
        alpha: float,
        size_min: float,
        seeds: tuple[ArrayF64, ArrayF64, float] | None = None,
    ) -> PieceSet:
        """Kept pieces carved again, finer (:mod:`polyhull.engine.refine`): the memory's by
        its own images and the test of M, and only their children within reach of the
        ``seeds`` (a coarse memory piece that came within reach at a corner, carved finely,
        keeps only its children that do)."""
        p = replace(self.params, size_min=size_min, alpha=alpha)
        mem = bool(piece_flags & MEMORY)
        shadow = self.shadows[1] if piece_flags & FRONT else self.shadows[0]
        stacks = shadow.stacks
        frees, ends = stacks if mem and stacks is not None else (self.free, self.end)
        out = self._run(boxes, frees, ends, p, offset, m_test=self.m_test if mem else None)[0]
        if mem and seeds is not None:
            out = within_reach(out, *seeds, self.pool)
        return out


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
        compiling = not kernels_cached()
        t_init = time.perf_counter()
        if compiling:
            log.info(
                "first run of this polyhull version: compiling the engine's kernels as they are first used "
                "(once; cached in %s)", kernel_cache_directory(),
            )
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
        # refinement even where it cannot change the distance (the warm-up's cycles)
        self._always_refine = False
        self._prepare_images()
        self._prepare_robot(robot)
        self.reset()
        if warm_up:
            self._warm_up(references)
        if compiling:
            log.info("monitor of cell '%s' ready in %.1f s", cell.name, time.perf_counter() - t_init)

    def _prepare_images(self) -> None:
        """What the image stages and the memory read every cycle, built once: the static
        pixel classes, the edge wedges and sheet tiles, the static free depth and its
        pyramids, the shadow memories, the pools of per-cycle buffers and the threads."""
        cell = self.cell
        self._blind = {c.name: np.full(c.shape, np.nan, dtype=np.float32) for c in cell.cameras}
        self._inf_img = {c.name: np.full(c.shape, np.inf, dtype=np.float32) for c in cell.cameras}
        self._residue_mark = [np.zeros(c.shape, dtype=np.bool_) for c in cell.cameras]

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
        # a cycle's images (held by its verdict and last_images) and its rasters (held by
        # last_images only), reused once nobody holds them; the rasteriser's depth buffers,
        # one pair per camera, are left reset after each use
        self._image_pool: Pool[CycleBuffers] = Pool(
            lambda: CycleBuffers(self._stack, self._static_classes, [s.free_static for s in self.static.cameras])
        )
        scratch = {
            c.name: (np.full(c.shape, np.inf, dtype=np.float64), np.full(c.shape, -np.inf, dtype=np.float64))
            for c in cell.cameras
        }
        self._raster_pool: Pool[dict[str, RasterBuffers]] = Pool(
            lambda: {c.name: RasterBuffers(c.shape, scratch[c.name]) for c in cell.cameras}
        )
        # the top of the floor's noise sheet (nothing crosses it without a floor sheet)
        floor = [sh for sh in self.static.sheets if sh.name == "floor"]
        self._floor_top = floor[0].level + floor[0].height if floor else -math.inf
        self._no_robot = {c.name: np.zeros(c.shape, dtype=bool) for c in cell.cameras}
        # per-camera work (robot raster, pixel classes) runs on two threads: the compiled
        # kernels release the GIL
        self._pool = ThreadPoolExecutor(max_workers=min(2, max(1, len(cell.cameras))), thread_name_prefix="polyhull")

    def _prepare_robot(self, robot: Robot | None) -> None:
        """The padded robot's pieces (:mod:`polyhull.engine.robot_pose`), the distance model
        of its moving links and the static region's distance (python-fcl), built once."""
        cell = self.cell
        if robot is not None:
            self._robot_pieces: RobotPieces | None = RobotPieces(robot, self._padding, cell.plausibility.shell_thickness)
            self._padded: PaddedPieces | None = self._robot_pieces.padded
            geometry = robot.link_geometry()
            self._distance_model: RobotDistanceModel | None = RobotDistanceModel(
                {name: mesh for name, mesh in geometry.items() if name in self._robot_pieces.moving},
                robot.link_convex_pieces(),
            )
            self._static_distance: StaticDistance | None = StaticDistance(
                self._distance_model, ChunkedMesh.of_manifold(self.static.region, tolerance=STATIC_TOLERANCE), self._static_contains
            )
        else:
            self._robot_pieces = None
            self._padded = None
            self._static_distance = None
            self._distance_model = None

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
        # refined even where the static region is nearer than the box (a cell whose static
        # region comes close to the robot): its kernels must load now
        self._always_refine = True
        try:
            for k, frames in enumerate(warmup_frames(self.cell, references, [0.0, dt], points)):
                self.step(frames, q, stamp=k * dt)
        finally:
            self._always_refine = False
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
        self._prev_certain = False  # whether the static region or the legs' sheet decided it
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
        """The stages in order (see the module docstring); each a method below."""
        t = self._cycle_time(frames, stamp, faults)
        if t is None:
            return self._stop_verdict(stamp, q, faults, warnings, timings, t_start)
        usable = self._timed(timings, "frames", lambda: self._frame_faults(frames, t, faults))
        if not usable:
            faults.append("coverage lost: no usable camera frame")
        qv = self._check_q(q, t, q_stamp, faults)
        if qv is None:
            return self._stop_verdict(t, q, faults, warnings, timings, t_start)
        robot = self._robot_pieces
        pose = NO_ROBOT if robot is None else self._timed(timings, "kinematics", lambda: robot.pose(qv))

        images = self._images(pose, usable, timings, faults)
        if not images.active.all():
            # A camera without a usable frame frees nothing, so its whole image would become
            # pieces (thousands: ~1.5 s of geometry). Its fault latches and stops the robot,
            # so the verdict is a stop now, with the whole zone as its region (a superset).
            self.last_images = None
            return self._stop_verdict(t, qv, faults, warnings, timings, t_start)

        carving = self._carving(pose, images)
        pieces, overflow = self._timed(timings, "pieces", lambda: carving.hull(images.initial))
        if overflow:
            warnings.append(f"pieces: the budget of {self._carve.max_pieces} pieces was reached; undecided pieces kept whole")
        dt = None if self._prev_stamp is None else max(t - self._prev_stamp, 0.0)
        memory = self._memory(carving, images, dt, timings)
        allp = PieceSet.concat([pieces, memory.pieces, memory.front])
        vols = piece_volumes(allp.boxes, self._stack)
        judged, ctx = self._judge(pose, images, allp, vols, len(pieces), dt, timings)
        # coverage: the free share of Z is at least 1 - (C_static + pieces) / Z
        free_share = 1.0 - (self.static.hull_volume + float(vols.sum())) / self.cell.zone.volume
        if free_share < self.cell.safety.min_free_share:
            # a lower bound of the free share (overlapping pieces count twice)
            faults.append(
                f"coverage lost: only {max(free_share, 0.0):.1%} of the zone is surely seen free "
                f"(< {self.cell.safety.min_free_share:.1%})"
            )
        # on a pool thread, beside the distance stage: the sheets under the legs the robot
        # may hide (the stage asks for them when it first measures the region), then, beside
        # the rest of the stage, the next cycle's history; one job at a time (the stage's
        # own work shares the pool's other thread)
        legs = Beside(self._pool, lambda: self._leg_sheets(allp, judged, ctx))
        history: list[Beside[_History]] = []

        def leg_sheets() -> ArrayF64:
            out = legs.result()
            if not history:
                history.append(Beside(self._pool, lambda: self._next_history(allp, judged, images)))
            return out

        try:
            refined = self._timed(
                timings,
                "distance",
                lambda: self._distance(pose, carving, allp, len(pieces), len(memory.front), judged, ctx, memory.seeds, leg_sheets),
            )
        finally:
            legs.wait()
            for job in history:
                job.wait()
        dist = refined.distance
        if dist.distance <= 0.0:
            faults.append(f"contact: the region touches robot link '{dist.link}'")
        if not history:  # (the stage never measured the region)
            history.append(Beside(None, lambda: self._next_history(allp, judged, images)))
        self._remember(t, images, float(dist.distance), history[0].result())
        self._prev_certain = refined.certain
        # the removals to report (before the latency: the caller waits for them too)
        gap_boxes = images.gaps
        gap_verts = piece_vertices(gap_boxes, self._stack)
        refine_removed = (pieces_removed("too_thin", refined.cut, self._stack),) if len(refined.cut) else ()
        removed = self.static.removed + gaps_removed(gap_boxes, gap_verts, self._stack) + judged.removed + refine_removed

        latency = time.perf_counter() - t_start
        decision = self._timed(
            timings, "speed", lambda: decide_speed(dist.distance, self.cell.safety, latency, self._margin)
        )
        if latency > self.cell.safety.cycle_deadline:
            warnings.append(
                f"cycle over its deadline: {latency * 1e3:.1f} ms > {self.cell.safety.cycle_deadline * 1e3:.0f} ms"
            )
        for f in faults:
            if f not in self._latched:
                self._latched.append(f)
        stop = bool(self._latched)
        timings["total"] = (time.perf_counter() - t_start) * 1e3

        # what the lazy geometry reads (not ``images``: the rasters' lease is last_images' only)
        padded_world, free_stack = pose.padded_world, images.bufs.free
        geometry = CycleGeometry(
            static=self.static,
            zone=self._zone,
            pieces_parts=(allp, PieceSet(gap_boxes, gap_verts)),
            kept_pieces=refined.pieces.vertices,
            kept_boxes=refined.pieces.boxes,
            kept_residue=(refined.flags & RESIDUE) > 0,
            stack=self._stack,
            sheet_boxes=refined.sheets,
            robot_body=lambda: _robot_body(padded_world),
            occlusion=lambda: self._occlusion(padded_world),
            full_pieces=lambda: self._full_pieces(free_stack, carving),
            lease=images.lease,
            k_of_n=self.cell.reconstruction.k_of_n,
        )
        return Verdict(
            stamp=t,
            q=np.array(qv, dtype=np.float64),  # a copy: check_q may return the caller's array
            removed=removed,
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
                "unexplained_pixels": int(sum(p.unexplained for p in images.pixels)),
                "small_gap_pixels": int(len(gap_boxes)),
                "initial_pieces": int(images.initial.shape[0]),
                "pieces": len(pieces),
                "memory_pieces": len(memory.pieces) + len(memory.front),
                "kept_pieces": int(judged.keep.sum()),
                "refined_pieces": len(refined.pieces),
                "refine_rounds": refined.rounds,
                "sheet_boxes": int(refined.sheets.shape[0]),
            },
            _geometry=geometry,
        )

    # -- the stages ------------------------------------------------------------------
    def _cycle_time(self, frames: object, stamp: object, faults: list[str]) -> float | None:
        """The cycle's time [s] (the newest frame's when ``stamp`` is None), or None with a
        fault when the frames are not a mapping or the time is not a finite number."""
        if not isinstance(frames, Mapping):
            faults.append(f"frames: expected a mapping camera name -> DepthFrame, got {type(frames).__name__}")
            return None
        if stamp is None:
            stamps = [f.stamp for f in frames.values() if isinstance(f, DepthFrame)]
            stamp = max(stamps) if stamps else math.nan
        if isinstance(stamp, bool) or not isinstance(stamp, int | float | np.integer | np.floating) or not _finite(stamp):
            faults.append(f"stamp: must be a finite time [s], got {stamp!r}")
            return None
        return float(stamp)

    def _images(
        self, pose: RobotPose, usable: Mapping[str, np.ndarray], timings: dict[str, float], faults: list[str]
    ) -> _Images:
        """Stages ``robot_raster`` and ``pixels``: each camera's robot raster, then its pixels,
        on this thread and one of the pool's (one task a camera: no wait for the other
        cameras' rasters); the raster stage's time runs until the last raster is done, the
        pixel stage's from then on. Then each camera's image faults."""
        cell = self.cell
        # this cycle's images, reused once no verdict or CycleImages holds them (fresh
        # allocations every cycle cost page faults, which serialise the two threads)
        bufs, lease = self._image_pool.take()
        raster_bufs, raster_lease = self._raster_pool.take()
        t0 = time.perf_counter()
        raster_done = [t0] * len(cell.cameras)
        # where each camera sees the padded robot's pieces (the edge wedges and sheet tiles
        # their shadows may meet)
        boxes = robot_boxes(cell.cameras, pose.padded_world)

        def camera(i: int) -> tuple[RobotRaster | None, _CameraPixels]:
            cam = cell.cameras[i]
            raster = None
            if pose.padded_world:
                raster = rasterize_robot(cam, pose.padded_world, self._padded, raster_bufs[cam.name])  # type: ignore[arg-type]
            raster_done[i] = time.perf_counter()
            return raster, self._camera_pixels(
                i, usable, raster, bufs.pixels[i], bufs.pyramids, bufs.end_pyramids, self._edge_wedges.ends(i, boxes),
                self._sheet_tiles.cycle(i, boxes),
            )

        done = share(self._pool, camera, range(len(cell.cameras)))
        t1 = max(raster_done)
        timings["robot_raster"] = (t1 - t0) * 1e3
        pixels = [p for _, p in done]
        self._camera_faults(pixels, faults)
        timings["pixels"] = (time.perf_counter() - t1) * 1e3
        return _Images(
            bufs=bufs,
            lease=lease,
            raster_lease=raster_lease,
            rasters={cam.name: r for cam, (r, _) in zip(cell.cameras, done, strict=True) if r is not None},
            pixels=pixels,
            free=[bufs.free.image(i) for i in range(len(cell.cameras))],
            end=[bufs.end.image(i) for i in range(len(cell.cameras))],
            active=np.array([p.active for p in pixels], dtype=bool),
        )

    def _camera_faults(self, pixels: list[_CameraPixels], faults: list[str]) -> None:
        """A camera that is blind, masked or contaminated (invalid pixels), or that has
        moved (its background reads beyond the reference)."""
        safety = self.cell.safety
        for cam, r in zip(self.cell.cameras, pixels, strict=True):
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

    def _carving(self, pose: RobotPose, images: _Images) -> _Carving:
        """This cycle's carving and its frontier.

        The distance is decided near the frontier (about last cycle's distance): pieces
        there, and pieces crossing the floor sheet's top within reach of it, are split
        finely, coarser behind it (:mod:`polyhull.engine.refine` finishes the job). The
        static region's distance: links measured only when their bound from the last
        measurement (less their motion since) is below what the pieces give."""
        cell = self.cell
        static_now = None if self._static_distance is None else self._static_distance.cycle(pose.T_links)
        last = self._prev_distance
        if not math.isfinite(last) and static_now is not None:
            # no last cycle (after a reset): the static region's distance, which the
            # region's cannot exceed
            last = float(static_now.nearer().distance)
        known = math.isfinite(last)
        return _Carving(
            stack=self._stack,
            active=images.active,
            pyramids=images.bufs.pyramids.only(images.active),
            free=images.bufs.free,
            end=images.bufs.end,
            spheres=pose.spheres,
            zone_lo=np.asarray(cell.zone.min, dtype=np.float64),
            zone_hi=np.asarray(cell.zone.max, dtype=np.float64),
            k=cell.reconstruction.k_of_n,
            params=self._carve,
            # the memory's test of M: the segment ends (the free depth of the empty cell
            # with the padded robot) and the static free depth
            m_test=MTest(images.bufs.end_pyramids, self._static_pyramids),
            front=max(last - FRONT_SLACK, 0.0) if known else 0.0,
            front_known=known,
            floor_top=(self._floor_top, REACH_EXTRA + cell.plausibility.floor_shell_margin),
            shadows=(self._shadow, self._shadow_front),
            static_now=static_now,
            pool=self._pool,
        )

    def _memory(self, carving: _Carving, images: _Images, dt: float | None, timings: dict[str, float]) -> _Memory:
        """Stage ``memory``: the robot shadow's memory near what the previous cycle saw as a
        target (:mod:`polyhull.engine.memory`), behind the robot and in front of it."""
        if not (
            self.cell.reconstruction.shadow_memory
            and images.rasters
            and self._seed_lo is not None
            and self._seed_hi is not None
            and len(self._seed_lo)
            and dt is not None
        ):
            return _Memory(PieceSet.empty(), PieceSet.empty(), None)
        # the previous cycle's seeds, and a person's reach since
        s_lo, s_hi, reach = self._seed_lo, self._seed_hi, self.cell.safety.human_speed * dt + 1e-3

        def remember(shadow: ShadowMemory) -> PieceSet:
            return shadow.pieces(images.rasters, images.free, carving.memory, s_lo, s_hi, reach, self._pool)

        behind = self._timed(timings, "memory", lambda: remember(self._shadow))
        front = self._timed(timings, "memory", lambda: remember(self._shadow_front))
        return _Memory(behind, front, (s_lo, s_hi, reach))

    def _judge(
        self,
        pose: RobotPose,
        images: _Images,
        allp: PieceSet,
        vols: ArrayF64,
        n_pieces: int,
        dt: float | None,
        timings: dict[str, float],
    ) -> tuple[DynamicResult, DynamicContext]:
        """Stage ``plausibility``: the rules on the dynamic components (the carved pieces,
        then the memory's, ``allp``, of volumes ``vols``)."""
        at_robot = _at_robot(allp.boxes, [images.rasters.get(c.name) for c in self.cell.cameras])
        active, free_static, end = images.active, self._free_static, images.bufs.end
        k = self.cell.reconstruction.k_of_n
        ctx = DynamicContext(
            **{
                **self._dyn_ctx.__dict__,
                "robot_shell_planes": pose.shell_planes,
                "robot_spheres": pose.spheres,
                "previous_lo": self._prev_lo,
                "previous_hi": self._prev_hi,
                "dt": dt,
                "m_columns": (
                    (lambda xy, h: columns_in_m(xy, h, self._stack, free_static, end, active, k))
                    if images.rasters
                    else None
                ),
            }
        )
        result: DynamicResult = self._timed(
            timings,
            "plausibility",
            lambda: judge_dynamic(
                allp.vertices, vols, at_robot, ctx, lambda idx: pieces_manifold(allp.boxes[idx], self._stack),
                memory=np.arange(len(allp)) >= n_pieces, pool=self._pool,
                residue=self._residue(images, allp.boxes, n_pieces),
            ),
        )
        return result, ctx

    def _residue(self, images: _Images, boxes: ArrayF64, n_pieces: int) -> np.ndarray:
        """(N,) the carved pieces (the first ``n_pieces`` of ``boxes``) made only of the far
        part of a small gap: pixels the small_gaps rule freed in part (their segments now
        start where the cluster's rays widen to ``detection_size``)."""
        out = np.zeros(len(boxes), dtype=bool)
        gaps = images.gaps
        if not len(gaps) or not n_pieces:
            return out
        cam = gaps[:, 0].astype(np.int64)
        u, v = gaps[:, 1].astype(np.int64), gaps[:, 3].astype(np.int64)
        for i in np.unique(cam):
            sel = cam == i
            ends = images.end[i][v[sel], u[sel]]
            part = gaps[sel, 6] < ends
            if not part.any():
                continue
            mark = self._residue_mark[i]
            vi, ui = v[sel][part], u[sel][part]
            mark[vi, ui] = True
            try:
                idx = np.nonzero(boxes[:n_pieces, 0] == i)[0]
                rects = boxes[idx, 1:5].astype(np.int64)
                out[idx] = only_marked_segments(rects, images.free[i], images.end[i], mark)
            finally:
                mark[vi, ui] = False
        return out

    def _distance(
        self,
        pose: RobotPose,
        carving: _Carving,
        allp: PieceSet,
        n_pieces: int,
        n_front: int,
        result: DynamicResult,
        ctx: DynamicContext,
        seeds: tuple[ArrayF64, ArrayF64, float] | None,
        leg_sheets: Callable[[], ArrayF64],
    ) -> Refined:
        """Stage ``distance``: the distance, with the kept pieces that decide it carved
        finely (the frontier), and the sheets under what stands on a surface (and, from
        ``leg_sheets()``, under the legs the robot may hide)."""
        index = np.arange(len(allp))
        flags = (
            np.where(result.own, OWN, 0)
            | np.where(index >= n_pieces, MEMORY, 0)
            | np.where(index >= len(allp) - n_front, FRONT, 0)
            | np.where(result.spared, SPARED, 0)
            | np.where(result.residue, RESIDUE, 0)
        )[result.keep].astype(np.int8)
        static_now = carving.static_now

        def measure(vertices: ArrayF64, best: DistanceResult | None) -> DistanceResult:
            if self._distance_model is None or static_now is None:
                return DistanceResult(math.inf, None, None)
            if static_now.contact is not None:
                return static_now.contact
            res = self._distance_model.distance(pose.T_links, pieces=vertices, best=best, cutoff=static_now.upper)
            return static_now.nearer(res)

        rules = RegionRules(
            in_shells=lambda v: in_shells(v, ctx),
            crossing=lambda v: crosses_sheet_top(v, ctx),
            sheets=lambda v: sheets_under(v, ctx),
            margin=self.cell.plausibility.floor_shell_margin,
            too_thin=self.cell.plausibility.too_thin,
        )
        spheres = pose.spheres
        measured = self._robot_pieces.measured if self._robot_pieces is not None else np.zeros(0, dtype=bool)
        # no robot: no refinement
        no_refine = self._distance_model is None
        return refine_kept(
            allp.select(result.keep), flags, result.inside[result.keep], rules,
            np.zeros((0, 4)) if no_refine else spheres, self._carve.alpha,
            functools.partial(carving.recarve, seeds=seeds), measure, self._pool,
            carving.front if carving.front_known else None, spheres[measured] if len(spheres) else None,
            leg_sheets, leave_out=not self._always_refine, last_certain=self._prev_certain,
        )

    def _leg_sheets(self, allp: PieceSet, result: DynamicResult, ctx: DynamicContext) -> ArrayF64:
        """(L, 8, 3) the floor's sheet boxes under the legs the robot may hide
        (:func:`hidden_legs`) under the judged pieces (reads, writes nothing: it runs beside
        the distance stage)."""
        hiding = allp.vertices[result.hiding]
        legs = hidden_legs(*vertex_bounds(hiding), np.ones(len(hiding), dtype=bool), ctx)
        return sheets_under(legs, ctx, horizontal=True)

    def _next_history(self, allp: PieceSet, result: DynamicResult, images: _Images) -> _History:
        """The next cycle's history from this cycle's judged pieces: the kept pieces' boxes
        (not the sheet boxes, which are the static noise layer under them, not an
        observation) and the shadow memory's seeds (reads, writes nothing: it runs beside
        the distance stage)."""
        seeds = seen_parts(
            allp.boxes[result.seeds], images.free, self._stack, self._binary, [p.invalid for p in images.pixels]
        )
        return _History(*vertex_bounds(allp.vertices[result.keep]), *vertex_bounds(seeds))

    def _remember(self, t: float, images: _Images, distance: float, history: _History) -> None:
        """History for the next cycle: ``history``, the frontier and this cycle's images."""
        self._prev_lo, self._prev_hi = history.kept_lo, history.kept_hi
        self._seed_lo, self._seed_hi = history.seed_lo, history.seed_hi
        self._prev_stamp = t
        self._prev_distance = distance
        names = [c.name for c in self.cell.cameras]
        self.last_images = CycleImages(
            free=dict(zip(names, images.free, strict=True)),
            end=dict(zip(names, images.end, strict=True)),
            raster=images.rasters,
            _lease=(images.lease, images.raster_lease),
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
            vu, to = small_gap_pixels(
                cls.free, cls.end, cls.invalid, s.free_static, cam.near,
                cam.intrinsics.fx, cam.intrinsics.fy, cell.plausibility.detection_size,
                tiles=(cell.reconstruction.tile, cls.tiles),
            )
            if len(vu):
                v_idx, u_idx = vu[:, 0], vu[:, 1]
                gaps = np.column_stack([np.full(len(u_idx), float(i)), u_idx, u_idx, v_idx, v_idx, cls.free[v_idx, u_idx], to])
                cls.free[v_idx, u_idx] = to
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

    def _full_pieces(self, free_stack: ImageStack, carving: _Carving) -> PieceSet:
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
            return PieceSet.empty()
        # C is drawn and measured, never used for the distance: coarse pieces (a superset)
        pieces, _ = carving.coarse(np.concatenate(parts), free_stack, ends)
        return pieces

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
        return robot_occlusion(self.cell.cameras, self.static.free, self._zone, padded_world, bands)


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
