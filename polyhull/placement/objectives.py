"""Quality of a sensor placement: the objectives f1 to f4 and their optimal values.

Paper section 4. With the voxel labels of
:mod:`polyhull.placement.labels`, every value is a volume in [m^3] (a voxel count times
the voxel volume), weighted where the objective says so:

- ``f1`` = undetectable volume [m^3];
- ``f2`` = importance-weighted undetectable volume, ``sum_n w(n) [n undetectable] dV``
  [m^3 x weight];
- ``f3 = w1 * changed + w2 * undetectable`` [m^3 x weight];
- ``f4`` = ``f3`` with the labels of the k-of-n rule (a voxel is target-free only when at
  least ``k`` cameras say so).

Optimal values (the stopping criteria of paper section 4): ``f1_opt`` = volume inside
static objects, ``f2_opt`` = its weighted volume, ``f3_opt = f4_opt = w2 * static volume +
min(w1, w2) * target volume``. They are lower bounds: static voxels are always
undetectable and target voxels never target-free (see :mod:`~polyhull.placement.labels`).

A placement is scored on several target scenes (:mod:`~polyhull.placement.targets`) and
every value, f_opt included, is the mean over the scenes.

:class:`PlacementProblem` is the picklable description of what is scored (grid, static
meshes, target scenes, weights); :func:`evaluate_cameras` scores a set of cameras. The
ray-casting scene and the voxel indicators are built once per process and cached, so an
evaluation in a worker process or on a Dask worker only ships the problem and the cameras.
"""

from __future__ import annotations

import atexit
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
import trimesh

from ..camera import Camera
from ..cell import Cell
from ..errors import GeometryError, PolyhullError
from ..raycast import MeshCaster
from ..typed import ArrayBool, ArrayF32, ArrayF64
from .labels import (
    PAPER_GRID,
    Label,
    VoxelGrid,
    free_depth_image,
    fuse_labels,
    mesh_mask,
    project_grid,
)
from .targets import TargetScene

__all__ = [
    "ObjectiveName",
    "OBJECTIVES",
    "ImportanceRegion",
    "Importance",
    "ObjectiveParams",
    "Objectives",
    "MeshArrays",
    "PlacementProblem",
    "PreparedProblem",
    "prepare",
    "evaluate_cameras",
    "label_scene",
]

ObjectiveName = Literal["f1", "f2", "f3", "f4"]
#: The objective names, in order.
OBJECTIVES: tuple[ObjectiveName, ...] = ("f1", "f2", "f3", "f4")


@dataclass(frozen=True)
class ImportanceRegion:
    """An axis-aligned box of the world [m] whose voxels get ``weight`` in f2."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    weight: float

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=np.float64)
        hi = np.asarray(self.hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)):
            raise PolyhullError(
                f"importance region: lo and hi must be 3 finite numbers [m], got {self.lo!r}, {self.hi!r}"
            )
        if not np.all(hi >= lo):
            raise PolyhullError(f"importance region: hi {hi.tolist()} must be >= lo {lo.tolist()}")
        if not (np.isfinite(self.weight) and self.weight >= 0):
            raise PolyhullError(f"importance region: weight must be finite and >= 0, got {self.weight!r}")
        object.__setattr__(self, "lo", tuple(float(x) for x in lo))
        object.__setattr__(self, "hi", tuple(float(x) for x in hi))
        object.__setattr__(self, "weight", float(self.weight))


@dataclass(frozen=True, eq=False)
class Importance:
    """Importance weights w(n) of the voxels (objective f2).

    Either a per-voxel field, or a default weight overridden by boxes (later regions win
    where they overlap).

    Attributes:
        field: Weights of shape ``grid.shape`` or ``(N,)``, finite and >= 0; or None.
        regions: Boxes with their weight (used when ``field`` is None).
        default: Weight of the voxels outside every region.
    """

    field: ArrayF64 | None = None
    regions: tuple[ImportanceRegion, ...] = ()
    default: float = 1.0

    def __post_init__(self) -> None:
        if self.field is not None:
            w = np.array(self.field, dtype=np.float64)
            if not np.all(np.isfinite(w)) or np.any(w < 0):
                raise PolyhullError("importance field: weights must be finite and >= 0")
            w.setflags(write=False)
            object.__setattr__(self, "field", w)
            if self.regions:
                raise PolyhullError("importance: give either a field or regions, not both")
        if not (np.isfinite(self.default) and self.default >= 0):
            raise PolyhullError(f"importance default weight must be finite and >= 0, got {self.default!r}")
        object.__setattr__(self, "regions", tuple(self.regions))

    def weights(self, grid: VoxelGrid) -> ArrayF64:
        """Weights (N,) of the voxels of ``grid``."""
        if self.field is not None:
            if self.field.shape not in (grid.shape, (grid.size,)):
                raise PolyhullError(
                    f"importance field has shape {self.field.shape}, expected the grid shape "
                    f"{grid.shape} or ({grid.size},)"
                )
            return np.asarray(self.field, dtype=np.float64).ravel()
        w = np.full(grid.size, float(self.default))
        for region in self.regions:
            w[grid.flat_indices_in_box(np.asarray(region.lo), np.asarray(region.hi))] = region.weight
        return w


@dataclass(frozen=True)
class ObjectiveParams:
    """Weights and rules of the objectives.

    Attributes:
        w1: Weight of the changed volume in f3 and f4.
        w2: Weight of the undetectable volume in f3 and f4. The default 2 puts the emphasis
            on not leaving points undetectable (paper section 4, item 3).
        k: k of the k-of-n rule of f4 (paper section 4, item 4).
        importance: Voxel weights of f2 (uniform 1 when None, so f2 = f1).
    """

    w1: float = 1.0
    w2: float = 2.0
    k: int = 2
    importance: Importance | None = None

    def __post_init__(self) -> None:
        for name in ("w1", "w2"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise PolyhullError(f"objective weight {name} must be finite and >= 0, got {value!r}")
        if not (isinstance(self.k, int | np.integer) and self.k >= 1):
            raise PolyhullError(f"k of the k-of-n rule must be an integer >= 1, got {self.k!r}")


@dataclass(frozen=True)
class Objectives:
    """Objective values of one placement, means over the target scenes.

    Attributes:
        f1: Undetectable volume [m^3].
        f2: Importance-weighted undetectable volume [m^3 x weight].
        f3: ``w1 * changed + w2 * undetectable`` [m^3 x weight].
        f4: f3 under the k-of-n rule [m^3 x weight].
        free: Target-free volume [m^3] (plain rule).
        changed: Changed volume [m^3] (plain rule).
        undetectable: Undetectable volume [m^3] (plain rule), equal to f1.
        free_k: Target-free volume [m^3] under the k-of-n rule.
        changed_k: Changed volume [m^3] under the k-of-n rule.
        undetectable_k: Undetectable volume [m^3] under the k-of-n rule.
    """

    f1: float
    f2: float
    f3: float
    f4: float
    free: float = 0.0
    changed: float = 0.0
    undetectable: float = 0.0
    free_k: float = 0.0
    changed_k: float = 0.0
    undetectable_k: float = 0.0

    def __getitem__(self, name: str) -> float:
        if name not in OBJECTIVES:
            raise PolyhullError(f"unknown objective {name!r}; choose one of {list(OBJECTIVES)}")
        return float(getattr(self, name))

    def as_dict(self) -> dict[str, float]:
        """All values by name."""
        return {k: float(v) for k, v in self.__dict__.items()}


class MeshArrays(NamedTuple):
    """A triangle mesh as plain arrays (cheap to pickle).

    Attributes:
        vertices: (V, 3) float64 vertices [m], world frame.
        faces: (F, 3) int64 vertex indices.
    """

    vertices: ArrayF64
    faces: np.ndarray

    @classmethod
    def of(cls, mesh: trimesh.Trimesh) -> MeshArrays:
        """The arrays of a trimesh."""
        return cls(
            np.ascontiguousarray(mesh.vertices, dtype=np.float64),
            np.ascontiguousarray(mesh.faces, dtype=np.int64),
        )

    def trimesh(self) -> trimesh.Trimesh:
        """The mesh as a trimesh (not processed)."""
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


@dataclass(frozen=True, eq=False)
class PlacementProblem:
    """What a placement is scored on: a picklable value shipped to every evaluation.

    Attributes:
        grid: The voxel grid over Z.
        floor_z: Height of the floor plane [m] (rendered into the reference).
        static_meshes: Closed static obstacles [m] (reference scene and the static
            indicator delta_s).
        target_scenes: Per scene, its closed target meshes [m]; an empty tuple scores one
            scene without targets.
        params: Weights and rules of the objectives.
        step: Pixel stride of the rendered depth images (1: every pixel, as the paper).
        key: Content hash, the key of the per-process cache (computed).
    """

    grid: VoxelGrid
    floor_z: float
    static_meshes: tuple[MeshArrays, ...] = ()
    target_scenes: tuple[tuple[MeshArrays, ...], ...] = ()
    params: ObjectiveParams = ObjectiveParams()
    step: int = 1
    key: str = field(init=False, default="")

    def __post_init__(self) -> None:
        if not np.isfinite(self.floor_z):
            raise GeometryError(f"floor_z must be finite [m], got {self.floor_z!r}")
        if not (isinstance(self.step, int | np.integer) and self.step >= 1):
            raise GeometryError(f"pixel step must be a positive integer [px], got {self.step!r}")
        h = hashlib.sha1()
        h.update(repr((self.grid.lo, self.grid.hi, self.grid.shape, float(self.floor_z))).encode())
        h.update(repr((self.params.w1, self.params.w2, self.params.k, int(self.step))).encode())
        imp = self.params.importance
        if imp is not None:
            h.update(repr((imp.regions, imp.default)).encode())
            if imp.field is not None:
                h.update(np.ascontiguousarray(imp.field).tobytes())
        for group in ((self.static_meshes,), self.target_scenes):
            h.update(b"|")
            for meshes in group:
                for m in meshes:
                    h.update(np.ascontiguousarray(m.vertices).tobytes())
                    h.update(np.ascontiguousarray(m.faces).tobytes())
                h.update(b";")
        object.__setattr__(self, "key", h.hexdigest())

    @classmethod
    def from_cell(
        cls,
        cell: Cell,
        scenes: Sequence[TargetScene] = (),
        grid_shape: Sequence[int] = PAPER_GRID,
        params: ObjectiveParams | None = None,
        step: int = 1,
        extra_static: Sequence[trimesh.Trimesh] = (),
    ) -> PlacementProblem:
        """The problem of a cell: its zone, floor and obstacles, with target scenes.

        Args:
            cell: The work cell (its cameras are not part of the problem).
            scenes: Target scenes (:func:`~polyhull.placement.targets.sample_target_scenes`).
            grid_shape: Voxel counts over Z (default: the paper's 126 x 90 x 66).
            params: Weights and rules; defaults to :class:`ObjectiveParams` with the cell's
                k-of-n when it is above 1.
            step: Pixel stride of the rendered depth images.
            extra_static: Further closed static occluders [m] (e.g. the robot at its default
                configuration); the reference depth B (the empty cell) holds only the obstacles.
        """
        if params is None:
            k = cell.reconstruction.k_of_n
            params = ObjectiveParams(k=k if k > 1 else 2)
        statics = [MeshArrays.of(o.mesh) for o in cell.obstacles]
        statics += [MeshArrays.of(m) for m in extra_static]
        return cls(
            grid=VoxelGrid.from_zone(cell.zone, grid_shape),
            floor_z=cell.zone.floor_z,
            static_meshes=tuple(statics),
            target_scenes=tuple(tuple(MeshArrays.of(m) for m in s.meshes) for s in scenes),
            params=params,
            step=step,
        )


@dataclass(frozen=True, eq=False)
class PreparedProblem:
    """The per-process state of a :class:`PlacementProblem` (built by :func:`prepare`).

    Attributes:
        problem: The problem.
        static_casters: Per static mesh, its ray caster (each is traced only over the image
            window of its own bounding box; the floor is analytic).
        static_corners: Per static mesh, (8, 3) corners of its bounding box [m].
        static_mask: (N,) delta_s, voxels inside static meshes.
        target_masks: Per scene (N,) delta_t, voxels inside targets (and not static).
        target_casters: Per scene, the ray caster of its targets.
        target_corners: Per scene, (8, 3) corners of the targets' bounding box [m].
        weights: (N,) importance weights of f2.
        optimum: The optimal values f_opt (means over the scenes).
    """

    problem: PlacementProblem
    static_casters: tuple[MeshCaster, ...]
    static_corners: tuple[ArrayF64, ...]
    static_mask: ArrayBool
    target_masks: tuple[ArrayBool, ...]
    target_casters: tuple[MeshCaster, ...]
    target_corners: tuple[ArrayF64, ...]
    weights: ArrayF64
    optimum: Objectives


_CACHE: OrderedDict[str, PreparedProblem] = OrderedDict()
_CACHE_LOCK = threading.Lock()
_CACHE_SIZE = 4
# Prepared problems hold the cell's manifolds: free them before interpreter shutdown
# (nanobind reports manifolds still alive then as leaks).
atexit.register(_CACHE.clear)


def prepare(problem: PlacementProblem) -> PreparedProblem:
    """The prepared state of ``problem``, built once per process and cached by its key."""
    with _CACHE_LOCK:
        cached = _CACHE.get(problem.key)
        if cached is not None:
            _CACHE.move_to_end(problem.key)
            return cached
        prepared = _build(problem)
        _CACHE[problem.key] = prepared
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
        return prepared


def _build(problem: PlacementProblem) -> PreparedProblem:
    grid = problem.grid
    statics = [m.trimesh() for m in problem.static_meshes]
    static_mask = mesh_mask(grid, statics)
    scenes = problem.target_scenes or ((),)
    target_masks = []
    casters = []
    corners = []
    for scene in scenes:
        meshes = [m.trimesh() for m in scene]
        target_masks.append(mesh_mask(grid, meshes) & ~static_mask)
        casters.append(MeshCaster(meshes))
        if meshes:
            lo = np.min([m.bounds[0] for m in meshes], axis=0)
            hi = np.max([m.bounds[1] for m in meshes], axis=0)
            corners.append(_box_corners(lo, hi))
        else:
            corners.append(np.zeros((0, 3)))
    params = problem.params
    importance = params.importance or Importance()
    weights = importance.weights(grid)
    vv = grid.voxel_volume
    n_static = float(np.count_nonzero(static_mask))
    n_target = float(np.mean([np.count_nonzero(t) for t in target_masks]))
    f3_opt = (params.w2 * n_static + min(params.w1, params.w2) * n_target) * vv
    optimum = Objectives(
        f1=n_static * vv,
        f2=float(np.sum(weights[static_mask])) * vv,
        f3=f3_opt,
        f4=f3_opt,
    )
    return PreparedProblem(
        problem=problem,
        static_casters=tuple(MeshCaster([m]) for m in statics),
        static_corners=tuple(_box_corners(*m.bounds) for m in statics),
        static_mask=static_mask,
        target_masks=tuple(target_masks),
        target_casters=tuple(casters),
        target_corners=tuple(corners),
        weights=weights,
        optimum=optimum,
    )


# Edges of a box given by its 8 corners in itertools.product order (x, y, z bits 4, 2, 1).
_BOX_EDGES = np.array([(i, i | bit) for bit in (4, 2, 1) for i in range(8) if not i & bit])


def _box_corners(lo: ArrayF64, hi: ArrayF64) -> ArrayF64:
    """The 8 corners (8, 3) of the box [lo, hi], x slowest."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _points_in_front(camera: Camera, corners: ArrayF64) -> ArrayF64:
    """Camera-frame vertices (M, 3) of the box ``corners`` cut to ``z >= 1e-6`` (in front).

    The vertices of a convex solid cut by a plane are its corners on the kept side and its
    edges' crossings of the plane; the part behind the camera projects nowhere.
    """
    pc = camera.world_to_camera(corners)  # (8, 3)
    plane = 1e-6
    points = [pc[pc[:, 2] >= plane]]
    a, b = pc[_BOX_EDGES[:, 0]], pc[_BOX_EDGES[:, 1]]
    da, db = a[:, 2] - plane, b[:, 2] - plane
    cross = da * db < 0
    if np.any(cross):
        t = (da[cross] / (da[cross] - db[cross]))[:, None]
        points.append(a[cross] + t * (b[cross] - a[cross]))
    return np.concatenate(points)


def _render_window(
    camera: Camera, caster: MeshCaster, corners: ArrayF64, step: int, shape: tuple[int, int]
) -> tuple[tuple[slice, slice], ArrayF32] | None:
    """z-depth [m] of meshes over the image rectangle their bounding box projects to.

    Args:
        camera: The camera.
        caster: Ray caster of the meshes.
        corners: (8, 3) corners of the meshes' axis-aligned bounding box [m], world.
        step: Pixel stride of the rendered image.
        shape: (H', W') of the rendered image.

    Returns:
        None when no pixel can see the meshes; otherwise the (rows, cols) slices of the
        rendered image and the depth over them (+inf where nothing is hit).
    """
    if caster.is_empty or len(corners) == 0:
        return None
    k = camera.intrinsics
    pc = _points_in_front(camera, corners)
    if len(pc) == 0:
        return None
    u = k.fx * pc[:, 0] / pc[:, 2] + k.cx
    v = k.fy * pc[:, 1] / pc[:, 2] + k.cy
    h, w = shape
    # One rendered pixel of margin: the rectangle holds every pixel centre whose ray
    # can meet the box.
    u0 = max(int(np.floor(u.min() / step)) - 1, 0)
    u1 = min(int(np.ceil(u.max() / step)) + 2, w)
    v0 = max(int(np.floor(v.min() / step)) - 1, 0)
    v1 = min(int(np.ceil(v.max() / step)) + 2, h)
    if u0 >= u1 or v0 >= v1:
        return None
    rows, cols = slice(v0, v1), slice(u0, u1)
    x = (np.arange(u0, u1, dtype=np.float64) * step - k.cx) / k.fx
    y = (np.arange(v0, v1, dtype=np.float64) * step - k.cy) / k.fy
    R = camera.T_world_camera[:3, :3]
    # World ray directions with unit camera z: R @ (x, y, 1), built without a matmul.
    directions = (
        x[None, :, None] * R[:, 0] + y[:, None, None] * R[:, 1] + R[:, 2]
    ).reshape(-1, 3)
    t = caster.first_hit(np.asarray(camera.center, dtype=np.float64), directions)
    return (rows, cols), t.reshape(len(y), len(x)).astype(np.float32)


def _render_reference(prep: PreparedProblem, camera: Camera, step: int) -> ArrayF32:
    """Reference z-depth B [m] (H', W'): the floor plane, then each static mesh in its window.

    The same image as :meth:`polyhull.raycast.StaticScene.render` (the first hit along a
    ray is the minimum of the z-depths of the parts), traced over far fewer pixels.
    """
    k = camera.intrinsics
    shape = (-(-k.height // step), -(-k.width // step))
    R = camera.T_world_camera[:3, :3]
    x = (np.arange(shape[1], dtype=np.float64) * step - k.cx) / k.fx
    y = (np.arange(shape[0], dtype=np.float64) * step - k.cy) / k.fy
    dz = R[2, 0] * x[None, :] + R[2, 1] * y[:, None] + R[2, 2]  # world z of the rays
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (prep.problem.floor_z - float(camera.center[2])) / dz
    depth = np.where(np.isfinite(t) & (t > 0.0), t, np.inf).astype(np.float32)
    for caster, corners in zip(prep.static_casters, prep.static_corners, strict=True):
        window = _render_window(camera, caster, corners, step, shape)
        if window is not None:
            view = depth[window[0]]
            np.minimum(view, window[1], out=view)
    return depth


class _SceneVotes(NamedTuple):
    """Votes of all cameras for all scenes (internal)."""

    base_count: np.ndarray  # (N,) int16 cameras calling each voxel free without targets
    correction: np.ndarray  # (S, N) int16 change of that count per scene
    changed: np.ndarray  # (S, N) bool some camera calls the voxel changed


def _votes(prep: PreparedProblem, cameras: Sequence[Camera]) -> _SceneVotes:
    problem = prep.problem
    grid = problem.grid
    step = problem.step
    n_scenes = len(prep.target_masks)
    base_count = np.zeros(grid.size, dtype=np.int16)
    correction = np.zeros((n_scenes, grid.size), dtype=np.int16)
    changed = np.zeros((n_scenes, grid.size), dtype=bool)
    for camera in cameras:
        proj = project_grid(camera, grid, step)
        B = _render_reference(prep, camera, step)
        f_ref, _ = free_depth_image(camera, B, B)
        visible = proj.pixel >= 0
        pix = np.where(visible, proj.pixel, 0)
        base_free = visible & (proj.depth < f_ref.ravel()[pix])
        base_count += base_free
        hit_union = np.zeros(B.shape, dtype=bool)
        # Per scene: its window of the image, and free depth and change mask over it.
        per_scene: list[tuple[int, tuple[slice, slice], ArrayF32, ArrayBool]] = []
        for s in range(n_scenes):
            roi = _render_window(
                camera, prep.target_casters[s], prep.target_corners[s], step, B.shape
            )
            if roi is None:
                continue
            window, T = roi
            B_roi = B[window]
            D_roi = np.minimum(B_roi, T)
            hit = D_roi < B_roi
            if not np.any(hit):
                continue
            f_roi, ch_roi = free_depth_image(camera, B_roi, D_roi)
            hit_union[window] |= hit
            per_scene.append((s, window, f_roi, ch_roi))
        if not per_scene:
            continue
        # Only voxels seen through a pixel that some target covers can change label.
        affected = np.flatnonzero(visible & hit_union.ravel()[pix])
        if len(affected) == 0:
            continue
        pa = pix[affected]
        row, col = np.divmod(pa, B.shape[1])
        za = proj.depth[affected]
        base_a = base_free[affected]
        for s, (rows, cols), f_roi, ch_roi in per_scene:
            inside = (row >= rows.start) & (row < rows.stop) & (col >= cols.start) & (col < cols.stop)
            idx = np.flatnonzero(inside)
            if len(idx) == 0:
                continue
            local = (row[idx] - rows.start) * (cols.stop - cols.start) + (col[idx] - cols.start)
            free_s = za[idx] < f_roi.ravel()[local]
            target = affected[idx]
            correction[s, target] += free_s.astype(np.int16) - base_a[idx]
            changed[s, target] |= ~free_s & ch_roi.ravel()[local]
    return _SceneVotes(base_count, correction, changed)


def label_scene(
    problem: PlacementProblem, cameras: Sequence[Camera], scene: int = 0, k: int = 1
) -> np.ndarray:
    """Voxel labels (N,) int8 of one target scene of ``problem`` (:class:`Label` values).

    Args:
        problem: The placement problem.
        cameras: The cameras.
        scene: Index of the target scene.
        k: k of the k-of-n rule (1: the plain rule).
    """
    prep = prepare(problem)
    if not 0 <= scene < len(prep.target_masks):
        raise PolyhullError(f"scene index {scene} out of range [0, {len(prep.target_masks)})")
    votes = _votes(prep, cameras)
    count = votes.base_count + votes.correction[scene]
    return fuse_labels(count, votes.changed[scene], k, prep.static_mask, prep.target_masks[scene])


def evaluate_cameras(problem: PlacementProblem, cameras: Sequence[Camera]) -> Objectives:
    """Score a set of cameras: f1 to f4 and the label volumes, means over the scenes.

    Args:
        problem: What the placement is scored on.
        cameras: The cameras (any number; none leaves all of Z undetectable).

    Returns:
        The objective values (see :class:`Objectives` for units).
    """
    prep = prepare(problem)
    params = problem.params
    vv = problem.grid.voxel_volume
    votes = _votes(prep, cameras)
    totals = np.zeros(10)
    for s, target_mask in enumerate(prep.target_masks):
        count = votes.base_count + votes.correction[s]
        plain = fuse_labels(count, votes.changed[s], 1, prep.static_mask, target_mask)
        strict = fuse_labels(count, votes.changed[s], params.k, prep.static_mask, target_mask)
        n = [np.count_nonzero(plain == lab) for lab in Label]
        nk = [np.count_nonzero(strict == lab) for lab in Label]
        undetectable = plain == Label.UNDETECTABLE
        totals += np.array(
            [
                n[Label.UNDETECTABLE],
                float(np.sum(prep.weights[undetectable])),
                params.w1 * n[Label.CHANGED] + params.w2 * n[Label.UNDETECTABLE],
                params.w1 * nk[Label.CHANGED] + params.w2 * nk[Label.UNDETECTABLE],
                *n,
                *nk,
            ],
            dtype=np.float64,
        )
    mean = totals * vv / len(prep.target_masks)
    return Objectives(*(float(x) for x in mean))
