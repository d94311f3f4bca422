"""Placement optimisation: CMA-ES over cameras on mounting surfaces (paper section 4).

**Parameters.** Each camera has four numbers, five with ``vary_fov``, all normalised to
``[0, 1]`` so that one step size fits all and the bounds are a box:

- ``s``: where on the mounting surfaces. The cell's surfaces are laid end to end on one
  axis: ``s * n_surfaces`` picks surface ``floor(s * n_surfaces)`` and its fractional
  part is the coordinate ``a`` along that surface's ``edge_u``. The discrete surface choice
  thus becomes part of a continuous position, and CMA-ES moves cameras along a surface and
  on to the next one. The alternative, one CMA-ES run per assignment of cameras to
  surfaces, costs ``n_surfaces ** n_cameras`` runs (625 for four cameras on five surfaces);
  the objective is piecewise continuous in ``s`` either way, which CMA-ES tolerates;
- ``b``: the coordinate along ``edge_v``;
- ``pan``: heading of the optical axis about world z, ``[-pi, pi]``;
- ``tilt``: angle of the optical axis below the horizontal, default ``[-0.35, pi / 2]``
  rad (straight down included: the image x axis stays horizontal, along ``pan - pi/2``);
- ``focal`` (with ``vary_fov``): scale of ``fx = fy`` on a log axis, default
  ``[0.5, 2]``, keeping the principal point (smaller scale, wider field of view).

The camera count is an outer loop (:func:`optimize_counts`): one run per count.

**Stopping.** On evaluations, on time, and on ``best - f_opt < eps`` (paper section 4,
"stopping criteria"). When CMA-ES converges before that, it restarts from the best point
with a doubled population (IPOP).

**Parallel.** Each generation is evaluated through a :class:`concurrent.futures.Executor`:
in-process, a local process pool, or a Dask cluster (``client.get_executor()``). A task is
the module-level :func:`evaluate_vector` with small picklable arguments; the ray-casting
scene is rebuilt once per worker process and cached (:func:`~polyhull.placement.objectives.prepare`).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..camera import Camera, Intrinsics
from ..cell import Cell, MountingSurface
from ..errors import CellError, MissingExtraError, PolyhullError
from ..typed import ArrayF64
from .objectives import (
    OBJECTIVES,
    ObjectiveName,
    Objectives,
    PlacementProblem,
    evaluate_cameras,
    prepare,
)

__all__ = [
    "CameraParameterisation",
    "CameraSetting",
    "StopCriteria",
    "OptimizationResult",
    "InlineExecutor",
    "make_executor",
    "evaluate_vector",
    "optimize",
    "optimize_counts",
    "pan_tilt_rotation",
]

Method = Literal["cma-es", "random"]

_BLAS_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
StopReason = Literal["evaluations", "time", "eps"]


def pan_tilt_rotation(pan: float, tilt: float) -> ArrayF64:
    """Rotation of ``T_world_camera`` for an optical axis at ``pan`` and ``tilt`` [rad].

    The optical axis (camera +z) is ``(cos tilt cos pan, cos tilt sin pan, -sin tilt)``;
    the image x axis is horizontal, ``(sin pan, -cos pan, 0)``, so image up is world up
    projected onto the image plane whenever the axis is not vertical, and the rotation is
    well defined at ``tilt = pi / 2`` (straight down).

    Returns:
        (3, 3) rotation whose columns are the camera axes in the world frame.
    """
    ct, st = np.cos(tilt), np.sin(tilt)
    cp, sp = np.cos(pan), np.sin(pan)
    z_axis = np.array([ct * cp, ct * sp, -st])
    x_axis = np.array([sp, -cp, 0.0])
    y_axis = np.cross(z_axis, x_axis)
    return np.column_stack([x_axis, y_axis, z_axis])


@dataclass(frozen=True)
class CameraSetting:
    """The decoded parameters of one camera.

    Attributes:
        surface: Name of the mounting surface.
        a: Coordinate along the surface's ``edge_u``, in [0, 1].
        b: Coordinate along ``edge_v``, in [0, 1].
        position: Camera centre [m], world frame.
        pan: Heading of the optical axis [rad].
        tilt: Angle of the optical axis below the horizontal [rad].
        focal_scale: Scale of the focal length (1: the template's).
    """

    surface: str
    a: float
    b: float
    position: tuple[float, float, float]
    pan: float
    tilt: float
    focal_scale: float


@dataclass(frozen=True, eq=False)
class CameraParameterisation:
    """Maps a vector in ``[0, 1]^D`` to cameras on mounting surfaces (see the module doc).

    Attributes:
        surfaces: The mounting surfaces, in the order of the surface axis.
        templates: One camera per optimised camera: its name, kind, intrinsics, range and
            noise are kept; its pose (and focal length with ``vary_fov``) is optimised.
        vary_fov: Also optimise a focal length scale per camera.
        tilt_range: Bounds of the tilt [rad] (angle below the horizontal).
        focal_range: Bounds of the focal length scale.
    """

    surfaces: tuple[MountingSurface, ...]
    templates: tuple[Camera, ...]
    vary_fov: bool = False
    tilt_range: tuple[float, float] = (-0.35, float(np.pi / 2))
    focal_range: tuple[float, float] = (0.5, 2.0)

    def __post_init__(self) -> None:
        if not self.surfaces:
            raise CellError(
                "placement needs at least one [[mounting]] surface (origin, edge_u, edge_v) "
                "where cameras may hang"
            )
        if not self.templates:
            raise PolyhullError("placement needs at least one camera to optimise")
        lo, hi = self.tilt_range
        if not (-np.pi / 2 <= lo < hi <= np.pi / 2):
            raise PolyhullError(f"tilt_range must satisfy -pi/2 <= lo < hi <= pi/2, got {self.tilt_range}")
        flo, fhi = self.focal_range
        if not (0 < flo <= fhi):
            raise PolyhullError(f"focal_range must satisfy 0 < lo <= hi, got {self.focal_range}")
        object.__setattr__(self, "surfaces", tuple(self.surfaces))
        object.__setattr__(self, "templates", tuple(self.templates))

    @classmethod
    def for_cell(cls, cell: Cell, count: int | None = None, vary_fov: bool = False) -> CameraParameterisation:
        """Parameterise ``count`` cameras (default: the cell's) on the cell's surfaces.

        Camera ``i`` takes its model (kind, intrinsics, range, noise) from the cell's camera
        ``i`` (cycled when ``count`` exceeds them) and is named after it, or ``cam<i>`` for
        the extra ones.
        """
        if not cell.cameras:
            raise CellError(f"cell '{cell.name}' has no camera to take the camera model from")
        n = len(cell.cameras) if count is None else int(count)
        if n < 1:
            raise PolyhullError(f"camera count must be >= 1, got {count}")
        names = {c.name for c in cell.cameras}
        templates = []
        for i in range(n):
            base = cell.cameras[i % len(cell.cameras)]
            name = base.name
            if i >= len(cell.cameras):
                name = f"cam{i + 1}"
                while name in names:
                    name += "_"
                names.add(name)
            templates.append(_with(base, name=name))
        if not cell.mounting:
            raise CellError(
                f"cell '{cell.name}' declares no [[mounting]] surfaces: add rectangles "
                "(origin, edge_u, edge_v) where cameras may hang"
            )
        return cls(surfaces=cell.mounting, templates=tuple(templates), vary_fov=vary_fov)

    @property
    def per_camera(self) -> int:
        """Parameters per camera."""
        return 5 if self.vary_fov else 4

    @property
    def dimension(self) -> int:
        """Length D of a parameter vector."""
        return self.per_camera * len(self.templates)

    @property
    def bounds(self) -> ArrayF64:
        """(D, 2) box bounds of the normalised parameters (all [0, 1])."""
        return np.tile([0.0, 1.0], (self.dimension, 1))

    def settings(self, x: ArrayF64) -> tuple[CameraSetting, ...]:
        """The decoded parameters of every camera for a vector ``x`` (D,) in [0, 1]."""
        x = self._check(x)
        n_s = len(self.surfaces)
        out = []
        for i in range(len(self.templates)):
            p = x[i * self.per_camera : (i + 1) * self.per_camera]
            t = p[0] * n_s
            idx = min(int(np.floor(t)), n_s - 1)
            a = float(min(max(t - idx, 0.0), 1.0))
            b = float(p[1])
            surface = self.surfaces[idx]
            pan = float(-np.pi + 2.0 * np.pi * p[2])
            tilt = float(self.tilt_range[0] + (self.tilt_range[1] - self.tilt_range[0]) * p[3])
            focal = 1.0
            if self.vary_fov:
                lo, hi = np.log(self.focal_range)
                focal = float(np.exp(lo + (hi - lo) * p[4]))
            pos = surface.point(a, b)
            out.append(
                CameraSetting(
                    surface=surface.name,
                    a=a,
                    b=b,
                    position=(float(pos[0]), float(pos[1]), float(pos[2])),
                    pan=pan,
                    tilt=tilt,
                    focal_scale=focal,
                )
            )
        return tuple(out)

    def decode(self, x: ArrayF64) -> tuple[Camera, ...]:
        """The cameras of a parameter vector ``x`` (D,) in [0, 1]."""
        cams = []
        for template, s in zip(self.templates, self.settings(x), strict=True):
            T = np.eye(4)
            T[:3, :3] = pan_tilt_rotation(s.pan, s.tilt)
            T[:3, 3] = s.position
            k = template.intrinsics
            intr = k
            if s.focal_scale != 1.0:
                intr = Intrinsics(k.width, k.height, k.fx * s.focal_scale, k.fy * s.focal_scale, k.cx, k.cy)
            cams.append(_with(template, T_world_camera=T, intrinsics=intr))
        return tuple(cams)

    def encode(self, cameras: Sequence[Camera]) -> ArrayF64:
        """The vector closest to given cameras: nearest surface point, their pan and tilt.

        Cameras beyond the given ones are put at the middle of the surface axis, looking
        down at 45 degrees. Focal scales are read against the templates' focal lengths.
        """
        n_s = len(self.surfaces)
        x = np.empty(self.dimension)
        for i, template in enumerate(self.templates):
            p = x[i * self.per_camera : (i + 1) * self.per_camera]
            if i >= len(cameras):
                p[:] = 0.5
                p[3] = (np.pi / 4 - self.tilt_range[0]) / (self.tilt_range[1] - self.tilt_range[0])
                continue
            cam = cameras[i]
            best = (np.inf, 0, 0.0, 0.0)
            for j, surface in enumerate(self.surfaces):
                a, b, d = _closest_on_surface(surface, cam.center)
                if d < best[0]:
                    best = (d, j, a, b)
            _, j, a, b = best
            p[0] = (j + min(a, 1.0 - 1e-9)) / n_s
            p[1] = b
            forward = cam.T_world_camera[:3, 2]
            pan = float(np.arctan2(forward[1], forward[0]))
            tilt = float(np.arcsin(np.clip(-forward[2], -1.0, 1.0)))
            p[2] = (pan + np.pi) / (2.0 * np.pi)
            p[3] = (tilt - self.tilt_range[0]) / (self.tilt_range[1] - self.tilt_range[0])
            if self.vary_fov:
                lo, hi = np.log(self.focal_range)
                scale = cam.intrinsics.fx / template.intrinsics.fx
                p[4] = (np.log(scale) - lo) / (hi - lo)
        return np.clip(x, 0.0, 1.0)

    def _check(self, x: ArrayF64) -> ArrayF64:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.dimension,) or not np.all(np.isfinite(x)):
            raise PolyhullError(
                f"parameter vector must be {self.dimension} finite numbers, got shape {x.shape}"
            )
        return np.clip(x, 0.0, 1.0)


def _with(camera: Camera, **changes: object) -> Camera:
    """A copy of ``camera`` with some constructor fields changed."""
    fields = {
        "name": camera.name,
        "kind": camera.kind,
        "intrinsics": camera.intrinsics,
        "T_world_camera": camera.T_world_camera,
        "near": camera.near,
        "far": camera.far,
        "noise": camera.noise,
        "tolerance_sigmas": camera.tolerance_sigmas,
        "tolerance_min": camera.tolerance_min,
    }
    fields.update(changes)
    return Camera(**fields)  # type: ignore[arg-type]


def _closest_on_surface(surface: MountingSurface, point: ArrayF64) -> tuple[float, float, float]:
    """Coordinates (a, b) in [0, 1]^2 of the surface point nearest ``point``, and the distance."""
    o = np.asarray(surface.origin)
    E = np.column_stack([surface.edge_u, surface.edge_v])  # (3, 2)
    ab, *_ = np.linalg.lstsq(E, np.asarray(point) - o, rcond=None)
    ab = np.clip(ab, 0.0, 1.0)
    # Clamping the least-squares solution is exact for rectangles; refine for safety.
    for _ in range(2):
        for axis in (0, 1):
            e = E[:, axis]
            rest = o + E[:, 1 - axis] * ab[1 - axis]
            ab[axis] = np.clip(float(e @ (np.asarray(point) - rest)) / float(e @ e), 0.0, 1.0)
    d = float(np.linalg.norm(o + E @ ab - point))
    return float(ab[0]), float(ab[1]), d


@dataclass(frozen=True)
class StopCriteria:
    """When an optimisation stops (whichever comes first).

    Attributes:
        max_evals: Number of evaluations, or None.
        max_seconds: Wall-clock time [s], or None (checked as evaluations complete;
            queued evaluations are cancelled).
        eps: Stop when ``best - f_opt < eps`` (units of the objective), or None.
    """

    max_evals: int | None = 200
    max_seconds: float | None = None
    eps: float | None = None

    def __post_init__(self) -> None:
        if self.max_evals is None and self.max_seconds is None and self.eps is None:
            raise PolyhullError("give at least one stopping criterion: evaluations, time or eps")
        if self.max_evals is not None and self.max_evals < 1:
            raise PolyhullError(f"max_evals must be >= 1, got {self.max_evals}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise PolyhullError(f"max_seconds must be > 0 s, got {self.max_seconds}")
        if self.eps is not None and not self.eps >= 0:
            raise PolyhullError(f"eps must be >= 0, got {self.eps}")


@dataclass(frozen=True, eq=False)
class OptimizationResult:
    """The outcome of one optimisation run.

    Attributes:
        method: ``"cma-es"`` or ``"random"`` (random search baseline).
        objective: The objective minimised.
        parameterisation: How vectors map to cameras.
        best_x: (D,) best parameter vector.
        best: All objective values of the best placement.
        optimum: The optimal values f_opt.
        values: (E,) the objective of every evaluation, in completion order.
        best_so_far: (E,) running minimum of ``values``.
        elapsed: (E,) wall-clock time of each completion since the start [s].
        seconds: Total wall-clock time [s].
        stop_reason: ``"evaluations"``, ``"time"`` or ``"eps"``.
        restarts: Number of CMA-ES restarts.
    """

    method: Method
    objective: ObjectiveName
    parameterisation: CameraParameterisation
    best_x: ArrayF64
    best: Objectives
    optimum: Objectives
    values: ArrayF64
    best_so_far: ArrayF64
    elapsed: ArrayF64
    seconds: float
    stop_reason: StopReason
    restarts: int = 0
    cameras: tuple[Camera, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "cameras", self.parameterisation.decode(self.best_x))

    @property
    def evaluations(self) -> int:
        """Number of evaluations."""
        return len(self.values)

    @property
    def best_value(self) -> float:
        """The best value of the objective."""
        return self.best[self.objective]

    @property
    def gap(self) -> float:
        """Distance of the best value to the optimum, ``best - f_opt``."""
        return self.best_value - self.optimum[self.objective]


class InlineExecutor(cf.Executor):
    """An executor that runs each task at once in the calling thread (no parallelism)."""

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def, override]
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - delivered through the future
            future.set_exception(exc)
        return future


@contextlib.contextmanager
def make_executor(workers: int = 1, scheduler: str | None = None) -> Iterator[cf.Executor]:
    """The executor of a placement run, shut down on exit.

    Args:
        workers: Worker processes of the local pool; 1 or less evaluates in-process.
        scheduler: Address of a Dask distributed scheduler (``tcp://host:8786``); when
            given, the evaluations run on that cluster and ``workers`` is ignored.

    Yields:
        A :class:`concurrent.futures.Executor`.
    """
    if scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError as exc:
            raise MissingExtraError("distributed placement (--scheduler)", "placement") from exc
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, TimeoutError, ValueError) as exc:
            raise PolyhullError(f"cannot connect to the Dask scheduler at {scheduler!r}: {exc}") from None
        try:
            yield client.get_executor()
        finally:
            client.close()
        return
    if workers <= 1:
        yield InlineExecutor()
        return
    # One BLAS thread per worker: the pool already keeps every core busy, and threaded
    # small matrix products only burn CPU. Workers are spawned (not forked: the parent
    # holds an Embree scene and threads) while the pool lives, and read this at start.
    limits = {name: "1" for name in _BLAS_THREAD_VARIABLES if name not in os.environ}
    os.environ.update(limits)
    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        for name in limits:
            os.environ.pop(name, None)


def evaluate_vector(
    problem: PlacementProblem, parameterisation: CameraParameterisation, x: ArrayF64
) -> Objectives:
    """Score the cameras of parameter vector ``x`` (the task sent to executors)."""
    return evaluate_cameras(problem, parameterisation.decode(x))


class _Cma:
    """CMA-ES with IPOP restarts from the best point."""

    def __init__(self, x0: ArrayF64, sigma0: float, bounds: ArrayF64, seed: int, popsize: int | None) -> None:
        try:
            import cmaes
        except ImportError as exc:
            raise MissingExtraError("placement optimisation (CMA-ES)", "placement") from exc
        self._cmaes = cmaes
        self._sigma0 = sigma0
        self._bounds = bounds
        self._seed = seed
        self.restarts = 0
        self._opt = cmaes.CMA(mean=x0, sigma=sigma0, bounds=bounds, seed=seed, population_size=popsize)

    @property
    def popsize(self) -> int:
        return int(self._opt.population_size)

    def ask(self) -> list[ArrayF64]:
        return [self._opt.ask() for _ in range(self.popsize)]

    def tell(self, xs: list[ArrayF64], values: list[float], best_x: ArrayF64) -> None:
        self._opt.tell(list(zip(xs, values, strict=True)))
        if self._opt.should_stop():
            self.restarts += 1
            self._opt = self._cmaes.CMA(
                mean=np.clip(best_x, 0.0, 1.0),
                sigma=self._sigma0,
                bounds=self._bounds,
                seed=self._seed + 7919 * self.restarts,
                population_size=2 * self.popsize,
            )


class _Random:
    """Uniform random search in the parameter box (the baseline)."""

    def __init__(self, dimension: int, seed: int, batch: int) -> None:
        self._rng = np.random.default_rng(seed)
        self._d = dimension
        self.popsize = batch
        self.restarts = 0

    def ask(self) -> list[ArrayF64]:
        return [self._rng.uniform(0.0, 1.0, self._d) for _ in range(self.popsize)]

    def tell(self, xs: list[ArrayF64], values: list[float], best_x: ArrayF64) -> None:
        return None


def optimize(
    problem: PlacementProblem,
    parameterisation: CameraParameterisation,
    objective: ObjectiveName = "f3",
    stop: StopCriteria | None = None,
    executor: cf.Executor | None = None,
    seed: int = 0,
    x0: ArrayF64 | None = None,
    sigma0: float = 0.15,
    popsize: int | None = None,
    method: Method = "cma-es",
    callback: Callable[[int, float, float], None] | None = None,
) -> OptimizationResult:
    """Minimise an objective over camera placements.

    Args:
        problem: What a placement is scored on.
        parameterisation: Vector-to-cameras map (mounting surfaces, camera models).
        objective: ``"f1"``, ``"f2"``, ``"f3"`` or ``"f4"``.
        stop: Stopping criteria (default: 200 evaluations).
        executor: Where evaluations run (default: in-process).
        seed: Seed of the sampler.
        x0: (D,) start vector in [0, 1]: the CMA-ES mean, evaluated first (by either method)
            so that the result is never worse than the start. Default: the centre of the box
            as the CMA-ES mean, not evaluated on its own.
        sigma0: Initial CMA-ES step size (in the normalised [0, 1] units).
        popsize: CMA-ES population (default: cmaes' ``4 + 3 ln D``); the batch size of
            random search.
        method: ``"cma-es"`` or ``"random"`` (uniform random search, the baseline).
        callback: Called after each evaluation with (evaluations, value, best value).

    Returns:
        The result, with the convergence history.
    """
    if objective not in OBJECTIVES:
        raise PolyhullError(f"unknown objective {objective!r}; choose one of {list(OBJECTIVES)}")
    if method not in ("cma-es", "random"):
        raise PolyhullError(f"unknown method {method!r}; choose 'cma-es' or 'random'")
    if not (np.isfinite(sigma0) and 0 < sigma0 <= 1):
        raise PolyhullError(f"sigma0 must be in (0, 1] (normalised units), got {sigma0!r}")
    if popsize is not None and popsize < 2:
        raise PolyhullError(f"popsize must be >= 2, got {popsize}")
    stop = stop or StopCriteria()
    executor = executor or InlineExecutor()
    optimum = prepare(problem).optimum
    target = optimum[objective]
    d = parameterisation.dimension
    start = np.full(d, 0.5) if x0 is None else np.clip(np.asarray(x0, dtype=np.float64), 0.0, 1.0)
    if start.shape != (d,):
        raise PolyhullError(f"x0 must have {d} entries, got shape {start.shape}")
    sampler: _Cma | _Random
    if method == "cma-es":
        sampler = _Cma(start, sigma0, parameterisation.bounds, seed, popsize)
    else:
        sampler = _Random(d, seed, popsize or max(4, int(4 + 3 * np.log(d))))

    t0 = time.perf_counter()
    values: list[float] = []
    elapsed: list[float] = []
    best_x = start.copy()
    best_obj: Objectives | None = None
    reason: StopReason = "evaluations"

    def budget_left() -> int | None:
        return None if stop.max_evals is None else stop.max_evals - len(values)

    def out_of_time() -> bool:
        return stop.max_seconds is not None and time.perf_counter() - t0 >= stop.max_seconds

    def record(x: ArrayF64, obj: Objectives) -> None:
        nonlocal best_x, best_obj
        v = obj[objective]
        values.append(v)
        elapsed.append(time.perf_counter() - t0)
        if best_obj is None or v < best_obj[objective]:
            best_obj, best_x = obj, np.asarray(x, dtype=np.float64).copy()
        if callback is not None:
            callback(len(values), v, best_obj[objective])

    def reached() -> bool:
        return stop.eps is not None and best_obj is not None and best_obj[objective] - target < stop.eps

    first = x0 is not None
    while True:
        left = budget_left()
        if left is not None and left <= 0:
            reason = "evaluations"
            break
        if reached():
            reason = "eps"
            break
        if out_of_time():
            reason = "time"
            break
        xs = [start] if first else sampler.ask()
        n = len(xs) if left is None else min(len(xs), left)
        futures = {executor.submit(evaluate_vector, problem, parameterisation, x): i for i, x in enumerate(xs[:n])}
        results: dict[int, Objectives] = {}
        timed_out = False
        pending = set(futures)
        while pending:
            timeout = None
            if stop.max_seconds is not None:
                timeout = max(0.0, stop.max_seconds - (time.perf_counter() - t0))
            done, pending = cf.wait(pending, timeout=timeout, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                i = futures[fut]
                results[i] = fut.result()
                record(xs[i], results[i])
            if pending and out_of_time():
                for fut in pending:
                    fut.cancel()
                timed_out = True
                break
        if not first and len(results) == len(xs):
            sampler.tell(xs, [results[i][objective] for i in range(len(xs))], best_x)
        first = False
        if timed_out:
            reason = "time"
            break
    if best_obj is None:
        raise PolyhullError("the optimisation stopped before any evaluation finished; raise the budget")
    vals = np.asarray(values)
    return OptimizationResult(
        method=method,
        objective=objective,
        parameterisation=parameterisation,
        best_x=best_x,
        best=best_obj,
        optimum=optimum,
        values=vals,
        best_so_far=np.minimum.accumulate(vals),
        elapsed=np.asarray(elapsed),
        seconds=time.perf_counter() - t0,
        stop_reason=reason,
        restarts=sampler.restarts,
    )


def optimize_counts(
    problem: PlacementProblem,
    cell: Cell,
    counts: Sequence[int],
    objective: ObjectiveName = "f3",
    stop: StopCriteria | None = None,
    executor: cf.Executor | None = None,
    seed: int = 0,
    vary_fov: bool = False,
    callback: Callable[[int, int, float, float], None] | None = None,
    method: Method = "cma-es",
    sigma0: float = 0.15,
) -> tuple[OptimizationResult, list[OptimizationResult]]:
    """One optimisation per camera count (the outer loop over counts).

    Each count gets the full ``stop`` budget and starts from the cell's cameras (extra ones
    mid-way along the surfaces). The chosen result is the smallest count within ``eps`` of
    f_opt when ``stop.eps`` is given and some count reaches it, else the lowest value
    (fewer cameras on ties).

    Args:
        problem: What a placement is scored on.
        cell: The cell (mounting surfaces, camera models, start placement).
        counts: Camera counts to try.
        objective: The objective.
        stop: Stopping criteria per count.
        executor: Where evaluations run.
        seed: Seed of the sampler.
        vary_fov: Also optimise the focal length.
        callback: Called after each evaluation with (count, evaluations, value, best).
        method: ``"cma-es"``, or ``"random"`` for the random search baseline.
        sigma0: Initial CMA-ES step size in the normalised [0, 1] units.

    Returns:
        The chosen result and the results of all counts (in the order of ``counts``).
    """
    if not counts:
        raise PolyhullError("give at least one camera count")
    stop = stop or StopCriteria()
    results = []
    for count in counts:
        param = CameraParameterisation.for_cell(cell, count, vary_fov)
        cb = None
        if callback is not None:
            def cb(n: int, v: float, b: float, _c: int = count) -> None:
                callback(_c, n, v, b)
        results.append(
            optimize(
                problem,
                param,
                objective,
                stop,
                executor,
                seed,
                x0=param.encode(cell.cameras),
                sigma0=sigma0,
                method=method,
                callback=cb,
            )
        )
    if stop.eps is not None:
        reaching = [r for r in results if r.gap < stop.eps]
        if reaching:
            return min(reaching, key=lambda r: len(r.cameras)), results
    return min(results, key=lambda r: (r.best_value, len(r.cameras))), results
