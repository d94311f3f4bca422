"""OctoMap as a peer: the same depth frames through an occupancy octree, measured like polyhull.

What a user would otherwise build, the way MoveIt's occupancy map monitor does it:

- every camera's valid pixels become a point cloud in the world frame, with the camera
  centre as the sensor origin (a +inf "no return" pixel clears its ray up to ``far``, the
  other invalid pixels insert nothing, as they free nothing in polyhull);
- a **self filter** like MoveIt's ``ShapeMask``: points inside the robot's collision pieces
  grown by the cell's ``robot.padding`` are model points; their rays clear space but their
  end cells are set to the clamping minimum (free) instead of being hit;
- the clouds go into an ``octomap.OcTree`` (octomap-python) with ``insertPointCloud``
  (``lazy_eval``, then one ``updateInnerOccupancy``), either into a **fresh** tree per cycle
  or into one **incremental** tree kept across cycles;
- **region extraction**: every voxel whose centre lies in the zone Z is looked up; the
  occupied and the unknown ones are possibly occupied (a person may stand where no camera
  looked); voxels whose centre lies in the padded robot are dropped (the self filter);
- **distance**: from the region's voxel centres to the moving links (python-fcl, the
  engine's own link models), minus half a voxel diagonal, so that it is a lower bound of
  the distance to anything inside the voxels.

:class:`PeerComparison` runs this next to the monitor's verdicts on the same frames and reports
speed, tightness against the exact depth hull and conservativeness (the share of the
person's interior and of the robot's links that each method marks free).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import MissingExtraError, PolyhullError
from .typed import ArrayBool, ArrayF64

__all__ = [
    "OctomapOptions",
    "SelfFilter",
    "CameraCloud",
    "OctomapPeer",
    "PeerCycle",
    "require_octomap",
    "frame_clouds",
    "PeerComparison",
    "format_table",
]

PERSON_SAMPLES = 20_000
"""Points sampled inside the person (and inside the robot's links) for the free shares."""

_EPS_CUBE = 1e-5  # [m] half-size of the tiny cube that stands for a voxel centre in FCL


def require_octomap() -> Any:
    """The ``octomap`` module of octomap-python, or MissingExtraError naming the extra."""
    try:
        import octomap
    except ImportError as exc:
        raise MissingExtraError("the OctoMap peer comparison (bench --peers)", "peers") from exc
    return octomap


@dataclass(frozen=True)
class OctomapOptions:
    """How OctoMap is run.

    Attributes:
        resolution: Voxel edge [m] (> 0).
        discretize: ``insertPointCloud(discretize=True)``: end points are snapped to voxel
            centres and each voxel's ray is cast once (faster; rays end at the centre, so a
            little less is cleared or hit exactly where the point was). False casts every
            point's own ray, as MoveIt's updater does.
        lazy_eval: Skip the inner-node update per insertion; one ``updateInnerOccupancy``
            runs after all cameras.
    """

    resolution: float = 0.05
    discretize: bool = True
    lazy_eval: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution) and 0.005 <= self.resolution <= 1.0):
            raise PolyhullError(f"--peers-resolution must be in [0.005, 1] m, got {self.resolution!r}")


# -- the self filter -----------------------------------------------------------------------
class SelfFilter:
    """MoveIt-style self filter: which points lie in the robot's convex pieces grown by the
    padding (the engine's padded pieces, a Minkowski sum with a cube of half-size padding).
    """

    def __init__(self, links: Sequence[str], hull_vertices: Sequence[ArrayF64]) -> None:
        """Args:
        links: Link name of every padded piece.
        hull_vertices: Vertices (K_i, 3) of every padded convex piece, link frame [m].
        """
        from scipy.spatial import ConvexHull

        self._links = tuple(links)
        self._planes = [np.asarray(ConvexHull(v).equations, dtype=np.float64) for v in hull_vertices]  # (F, 4)
        self._boxes = [(np.min(v, axis=0), np.max(v, axis=0)) for v in hull_vertices]
        self._vertices = [np.asarray(v, dtype=np.float64) for v in hull_vertices]

    @classmethod
    def from_monitor(cls, monitor: Any) -> SelfFilter:
        """The self filter of a monitor's padded robot (``robot.padding`` of its cell)."""
        padded = monitor._padded
        if padded is None:
            raise PolyhullError("the OctoMap peer needs a cell with a [robot]")
        return cls(padded.links, padded.vertices)

    def inside(self, points_world: ArrayF64, T_world_links: Mapping[str, ArrayF64]) -> ArrayBool:
        """(P,) whether each point lies in some padded piece at the given link poses."""
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(p), dtype=bool)
        world = [v @ T_world_links[n][:3, :3].T + T_world_links[n][:3, 3] for n, v in zip(self._links, self._vertices, strict=True)]
        if not world or len(p) == 0:
            return out
        allv = np.concatenate(world)
        lo_w, hi_w = allv.min(axis=0) - 1e-9, allv.max(axis=0) + 1e-9
        near = np.flatnonzero(np.all((p >= lo_w) & (p <= hi_w), axis=1))  # in the robot's box
        for name, planes, (lo, hi) in zip(self._links, self._planes, self._boxes, strict=True):
            if near.size == 0:
                break
            T = T_world_links[name]
            local = (p[near] - T[:3, 3]) @ T[:3, :3]  # world -> link frame
            cand = np.flatnonzero(np.all((local >= lo - 1e-9) & (local <= hi + 1e-9), axis=1))
            if cand.size:
                d = local[cand] @ planes[:, :3].T + planes[:, 3]
                out[near[cand[np.all(d <= 1e-9, axis=1)]]] = True
        return out


# -- the clouds ----------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CameraCloud:
    """One camera's frame as OctoMap takes it.

    Attributes:
        camera: Camera name.
        origin: Sensor origin, the camera centre in the world [m], (3,).
        points: End points in the world [m], (N, 3).
        maxrange: Rays are cleared up to this length [m] (the camera's ``far``); a longer
            ray (a "no return" pixel) marks no end point.
    """

    camera: str
    origin: ArrayF64
    points: ArrayF64
    maxrange: float


def frame_clouds(cameras: Sequence[Any], frames: Mapping[str, Any]) -> list[CameraCloud]:
    """Point clouds of every camera's frame (polyhull's validity rules, REP 117).

    A valid reading (finite, in ``[near, far]``) is an end point; +inf ("no return") is a
    point at twice ``far`` on the pixel's ray, cleared up to ``far`` only; 0, NaN, -inf and
    out-of-range readings insert nothing. A camera without a frame inserts nothing.
    """
    out = []
    for cam in cameras:
        frame = frames.get(cam.name)
        if frame is None:
            continue
        d = np.asarray(frame.depth, dtype=np.float64)
        no_return = np.isposinf(d)
        with np.errstate(invalid="ignore"):
            ok = (np.isfinite(d) & (d >= cam.near) & (d <= cam.far)) | no_return
        v, u = np.nonzero(ok)
        z = np.where(no_return[v, u], 2.0 * cam.far, d[v, u])
        pts = cam.unproject(np.column_stack([u, v]).astype(np.float64), z)
        out.append(CameraCloud(cam.name, np.asarray(cam.center, dtype=np.float64), pts, float(cam.far)))
    return out


# -- the peer ------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PeerCycle:
    """One OctoMap cycle.

    Attributes:
        timings: ``clouds`` (pixels to points and the self filter), ``insert`` (all cameras
            and ``updateInnerOccupancy``), ``region`` (voxel look-up in Z and the self
            filter), ``distance`` and ``total`` [ms].
        points: End points inserted (model points included).
        model_points: Points the self filter took for the robot.
        region_voxels: Voxels of the region (occupied or unknown, outside the padded robot).
        min_distance: Distance from the region to the moving links [m] (inf: empty region).
        link: The closest link, or None.
    """

    timings: dict[str, float]
    points: int
    model_points: int
    region_voxels: int
    min_distance: float
    link: str | None


class OctomapPeer:
    """OctoMap over a cell's zone, fed frame by frame; fresh or incremental."""

    def __init__(self, monitor: Any, options: OctomapOptions | None = None, *, incremental: bool = False) -> None:
        """Args:
        monitor: The polyhull monitor of the cell (its cameras, zone, padded robot and
            link distance models are reused).
        options: How OctoMap is run.
        incremental: Keep one tree across cycles instead of a fresh one per cycle.

        Raises:
            MissingExtraError: octomap-python is not installed.
            PolyhullError: the cell has no robot.
        """
        self._octomap = require_octomap()
        self.options = options or OctomapOptions()
        self.incremental = incremental
        self._monitor = monitor
        self._robot = monitor.robot
        self._distance_model = monitor._distance_model
        if self._robot is None or self._distance_model is None:
            raise PolyhullError("the OctoMap peer needs a cell with a [robot]")
        self.self_filter = SelfFilter.from_monitor(monitor)
        res = self.options.resolution
        zone = monitor.cell.zone
        lo, hi = np.asarray(zone.min, dtype=np.float64), np.asarray(zone.max, dtype=np.float64)
        # OctoMap's voxels are [k res, (k + 1) res); those whose centre is in Z
        axes = [(np.arange(math.ceil(lo[i] / res - 0.5), math.floor(hi[i] / res - 0.5) + 1) + 0.5) * res for i in range(3)]
        self.centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)  # (V, 3)
        self.tree: Any = None
        self.region_centres: ArrayF64 = np.zeros((0, 3))

    def _new_tree(self) -> Any:
        return self._octomap.OcTree(self.options.resolution)

    def step(self, frames: Mapping[str, Any], q: ArrayF64) -> PeerCycle:
        """Frames in, distance out: insert the frames, extract the region, measure the distance."""
        opt = self.options
        t0 = time.perf_counter()
        T_links = self._robot.link_transforms(q)
        clouds = frame_clouds(self._monitor.cell.cameras, frames)
        models = [self.self_filter.inside(c.points, T_links) for c in clouds]
        t1 = time.perf_counter()
        if self.tree is None or not self.incremental:
            self.tree = self._new_tree()
        tree = self.tree
        # MoveIt sets the model cells to the clamping minimum after the hits: an update of
        # (min - max) log-odds clamps any cell to the minimum
        to_min = float(tree.getClampingThresMinLog() - tree.getClampingThresMaxLog())
        for cloud, model in zip(clouds, models, strict=True):
            if len(cloud.points):
                tree.insertPointCloud(
                    cloud.points, cloud.origin, maxrange=cloud.maxrange, lazy_eval=opt.lazy_eval, discretize=opt.discretize
                )
            if model.any():
                tree.updateNodes(cloud.points[model], to_min, lazy_eval=opt.lazy_eval)
        if opt.lazy_eval:
            tree.updateInnerOccupancy()
        t2 = time.perf_counter()
        labels = tree.getLabels(self.centres)  # -1 unknown, 0 free, 1 occupied
        region = self.centres[labels != 0]
        region = region[~self.self_filter.inside(region, T_links)]
        self.region_centres = region
        t3 = time.perf_counter()
        d, link = voxel_distance(self._distance_model, T_links, region, opt.resolution)
        t4 = time.perf_counter()
        ms = {
            "clouds": 1e3 * (t1 - t0),
            "insert": 1e3 * (t2 - t1),
            "region": 1e3 * (t3 - t2),
            "distance": 1e3 * (t4 - t3),
            "total": 1e3 * (t4 - t0),
        }
        return PeerCycle(
            ms, int(sum(len(c.points) for c in clouds)), int(sum(int(m.sum()) for m in models)), len(region), d, link
        )

    def labels(self, points_world: ArrayF64) -> np.ndarray:
        """OctoMap's label of each point's voxel in the current tree: -1 unknown, 0 free, 1 occupied."""
        if self.tree is None:
            raise PolyhullError("OctomapPeer.labels: no tree yet; call step(frames, q) first")
        p = np.ascontiguousarray(np.asarray(points_world, dtype=np.float64).reshape(-1, 3))
        return np.asarray(self.tree.getLabels(p))

    def in_region(self, points_world: ArrayF64, T_world_links: Mapping[str, ArrayF64]) -> ArrayBool:
        """(P,) whether each point's voxel is in the region (occupied or unknown, centre
        outside the padded robot)."""
        res = self.options.resolution
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        centres = (np.floor(p / res) + 0.5) * res
        return (self.labels(p) != 0) & ~self.self_filter.inside(centres, T_world_links)


def voxel_distance(
    distance_model: Any, T_world_links: Mapping[str, ArrayF64], centres: ArrayF64, resolution: float
) -> tuple[float, str | None]:
    """Distance [m] from voxel centres (V, 3) to the robot links, minus half a voxel diagonal
    (clamped at 0), and the closest link; (inf, None) without voxels.

    Voxels that cannot be nearer than the nearest centre-to-link-interior distance are
    skipped (bounding spheres); the rest go to python-fcl as tiny cubes around the centres.
    """
    if len(centres) == 0:
        return math.inf, None
    half_diag = 0.5 * math.sqrt(3.0) * resolution
    inner = distance_model.inner_points(T_world_links)
    spheres = distance_model._spheres
    lower = np.full(len(centres), np.inf)
    upper = math.inf
    for name, p_in in inner.items():
        c, r = spheres[name]
        T = T_world_links[name]
        lower = np.minimum(lower, np.linalg.norm(centres - (T[:3, :3] @ c + T[:3, 3]), axis=1) - r)
        upper = min(upper, float(np.linalg.norm(centres - p_in, axis=1).min()))
    cand = centres[lower <= upper]
    cubes = cand[:, None, :] + _EPS_CUBE * _CUBE_CORNERS[None, :, :]  # (C, 8, 3)
    best = distance_model.distance(T_world_links, pieces=cubes)
    if not math.isfinite(best.distance):
        return math.inf, None
    return max(0.0, best.distance - half_diag), best.link


# hexahedron corner order of polyhull.distance (bottom face 0-3, top face 4-7)
_CUBE_CORNERS = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64
)


# -- the comparison ------------------------------------------------------------------------
def _sample_inside(mesh: Any, count: int, rng: np.random.Generator) -> ArrayF64:
    """About ``count`` points uniformly inside a watertight mesh (rejection in its box)."""
    lo, hi = mesh.bounds
    fill = max(float(mesh.volume) / float(np.prod(hi - lo)), 1e-3)
    p = rng.uniform(lo, hi, size=(int(count / fill) + 1, 3))
    return p[mesh.contains(p)]


def _summary(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {"median": math.nan, "p99": math.nan, "min": math.nan, "max": math.nan}
    return {
        "median": float(np.median(a)),
        "p99": float(np.percentile(a, 99)),
        "min": float(a.min()),
        "max": float(a.max()),
    }


class PeerComparison:
    """polyhull's verdicts against OctoMap (a fresh and an incremental tree) on the same frames.

    Feed it each compared cycle right after the monitor's step on those frames
    (:meth:`add`), so that both are timed alternately under the same machine load; then
    read :meth:`result`. The figures other than the timings are computed in :meth:`add`,
    after both methods ran.
    """

    def __init__(
        self,
        monitor: Any,
        exact_hull: Callable[[Mapping[str, Any], ArrayF64], tuple[ArrayBool, ArrayBool]],
        *,
        options: OctomapOptions | None = None,
        samples: int = 100_000,
        seed: int = 0,
    ) -> None:
        """Args:
        monitor: The monitor whose verdicts are compared (cell, static model, robot).
        exact_hull: ``(frames, points) -> (in exact C, in a solid obstacle)``: the bench's
            exact depth hull oracle.
        options: How OctoMap is run.
        samples: Points sampled in Z per cycle for the volumes (Monte-Carlo, the same
            points for every method).
        seed: Seed of the samples.

        Raises:
            MissingExtraError: octomap-python is not installed.
            PolyhullError: the cell has no robot.
        """
        self.options = options or OctomapOptions()
        self._monitor = monitor
        self._exact_hull = exact_hull
        self._samples = samples
        self._peers = {
            "octomap_fresh": OctomapPeer(monitor, self.options),
            "octomap_incremental": OctomapPeer(monitor, self.options, incremental=True),
        }
        self._rng = np.random.default_rng(seed)
        self._names = ("polyhull", *self._peers)
        self._rows: dict[str, dict[str, list[float]]] = {n: {} for n in self._names}
        self._stage_ms: dict[str, dict[str, list[float]]] = {n: {} for n in self._peers}
        self._exact_volumes: list[float] = []
        self._exact_person_free: list[float] = []
        self._true_distances: list[float] = []

    def _add(self, method: str, key: str, value: float) -> None:
        self._rows[method].setdefault(key, []).append(value)

    def add(self, frames: Mapping[str, Any], q: ArrayF64, person: Any, verdict: Any) -> None:
        """One cycle: OctoMap on ``frames`` (timed), then every figure of both methods.

        Args:
            frames: The frames the monitor's ``verdict`` came from.
            q: The joint positions of that cycle [rad].
            person: The person's mesh (world frame, watertight) in those frames.
            verdict: The monitor's verdict on those frames.
        """
        from .cell import mesh_to_manifold
        from .distance import points_in_hexahedra

        geo = verdict._geometry
        if geo is None:
            raise PolyhullError(f"the monitor gave no region in the peer cycle at t = {verdict.stamp} s: {verdict.faults}")
        cycles = {name: peer.step(frames, q) for name, peer in self._peers.items()}  # right after polyhull's

        monitor, rng = self._monitor, self._rng
        robot, distance_model = monitor.robot, monitor._distance_model
        cell = monitor.cell
        k_of_n = cell.reconstruction.k_of_n
        lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
        zone = float(cell.zone.volume)
        T_links = robot.link_transforms(q)
        p = rng.uniform(lo, hi, size=(self._samples, 3))
        exact, solid = self._exact_hull(frames, p)
        self._exact_volumes.append(zone * float(exact.mean()))
        person_pts = _sample_inside(person, PERSON_SAMPLES, rng)
        person_pts = person_pts[np.all((person_pts >= lo) & (person_pts <= hi), axis=1)]  # in Z
        exact_person, _ = self._exact_hull(frames, person_pts)
        self._exact_person_free.append(100.0 * float((~exact_person).mean()))
        links = robot.link_meshes(q)
        link_pts = np.concatenate([_sample_inside(m, PERSON_SAMPLES // max(len(links), 1), rng) for m in links.values()])
        true = distance_model.distance(T_links, region=mesh_to_manifold(person, "person")).distance
        self._true_distances.append(true)

        # polyhull: C by its point oracles; R3 (the region its distance uses) exactly
        full = geo.full_pieces().vertices
        in_c = (monitor.static.hull_contains(p, k_of_n) | points_in_hexahedra(p, full)) & ~solid
        person_m = mesh_to_manifold(person, "person") ^ geo.zone  # the person's part in Z
        outside = person_m - verdict.region
        robot_in_c = monitor.static.hull_contains(link_pts, k_of_n) | points_in_hexahedra(link_pts, full)
        self._add("polyhull", "cycle_ms", float(verdict.timings["total"]))
        self._add("polyhull", "volume_m3", zone * float(in_c.mean()))
        self._add("polyhull", "exact_hull_free_m3", zone * float((exact & ~in_c).mean()))
        self._add("polyhull", "person_free_percent", 100.0 * outside.volume() / person_m.volume())
        self._add("polyhull", "robot_free_percent", 100.0 * float((~robot_in_c).mean()))
        self._add("polyhull", "distance_m", float(verdict.min_distance))
        self._add("polyhull", "true_minus_reported_m", true - float(verdict.min_distance))

        for name, peer in self._peers.items():
            c = cycles[name]
            for stage, ms in c.timings.items():
                self._stage_ms[name].setdefault(stage, []).append(ms)
            occ = (peer.labels(p) != 0) & ~solid  # occupied or unknown: the map's C
            self._add(name, "cycle_ms", c.timings["total"])
            self._add(name, "volume_m3", zone * float(occ.mean()))
            self._add(name, "exact_hull_free_m3", zone * float((exact & ~occ).mean()))
            self._add(name, "person_free_percent", 100.0 * float((~peer.in_region(person_pts, T_links)).mean()))
            self._add(name, "robot_free_percent", 100.0 * float((peer.labels(link_pts) == 0).mean()))
            self._add(name, "distance_m", c.min_distance)
            self._add(name, "true_minus_reported_m", true - c.min_distance)

    def result(self) -> dict[str, Any]:
        """The figures over the cycles added, JSON-ready.

        ``methods`` (polyhull, octomap_fresh, octomap_incremental), each with ``cycle_ms``
        (median, p99), OctoMap's ``stages_ms_median``, ``volume_m3``, ``excess_percent``
        against the exact hull, ``exact_hull_free_m3``, ``person_free_percent``,
        ``robot_free_percent``, ``distance_m``, ``true_minus_reported_m`` and
        ``cycles_reported_above_true``; the ``speed_ratio`` of each OctoMap variant; the exact
        hull's volume and person free share; the person's true distance; the options.

        Raises:
            PolyhullError: no cycle was added.
        """
        if not self._exact_volumes:
            raise PolyhullError("the peer comparison needs at least one cycle")
        exact_median = float(np.median(self._exact_volumes))
        methods: dict[str, Any] = {}
        for name in self._names:
            r = self._rows[name]
            vol = float(np.median(r["volume_m3"]))
            gaps = np.asarray(r["true_minus_reported_m"])
            methods[name] = {
                "cycle_ms": {k: x for k, x in _summary(r["cycle_ms"]).items() if k in ("median", "p99")},
                "volume_m3": vol,
                "excess_percent": 100.0 * (vol / exact_median - 1.0) if exact_median > 0 else math.inf,
                "exact_hull_free_m3": float(np.median(r["exact_hull_free_m3"])),
                "person_free_percent": _summary(r["person_free_percent"]),
                "robot_free_percent": float(np.median(r["robot_free_percent"])),
                "distance_m": float(np.median(r["distance_m"])),
                "true_minus_reported_m": float(np.median(gaps)) if np.isfinite(gaps).any() else math.nan,
                "cycles_reported_above_true": int(np.sum(gaps < -1e-6)),
            }
            if name in self._stage_ms:
                methods[name]["stages_ms_median"] = {
                    k: float(np.median(x)) for k, x in self._stage_ms[name].items() if k != "total"
                }
        base = methods["polyhull"]["cycle_ms"]["median"]
        o = self.options
        return {
            "cycles": len(self._exact_volumes),
            "samples": self._samples,
            "options": {
                "library": f"octomap-python {_version()}",
                "resolution_m": o.resolution,
                "discretize": o.discretize,
                "lazy_eval": o.lazy_eval,
                "self_filter_padding_m": float(self._monitor._padding),
            },
            "volume_exact_hull_m3": exact_median,
            "exact_hull_person_free_percent": _summary(self._exact_person_free),
            "true_distance_m": _summary(self._true_distances),
            "methods": methods,
            "speed_ratio": {n: methods[n]["cycle_ms"]["median"] / base if base > 0 else math.inf for n in self._peers},
        }


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("octomap-python")
    except PackageNotFoundError:
        return "?"


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _pct(x: float | None) -> str:
    """A share [%] with two decimals; a positive share below 0.005 % is "<0.01", not 0.00."""
    if x is not None and 0.0 < x < 0.005:
        return "<0.01"
    return _fmt(x, ".2f")


def format_table(result: Mapping[str, Any]) -> str:
    """The side-by-side table of :meth:`PeerComparison.result` as text (one method per column)."""
    m = result["methods"]
    names = ("polyhull", "octomap_fresh", "octomap_incremental")
    heads = ("polyhull", "OctoMap fresh", "OctoMap incr.")
    o = result["options"]
    rows: list[tuple[str, list[str]]] = [
        ("cycle median [ms]", [_fmt(m[n]["cycle_ms"]["median"], ".0f") for n in names]),
        ("cycle p99 [ms]", [_fmt(m[n]["cycle_ms"]["p99"], ".0f") for n in names]),
        ("  of which insertion [ms]", ["-"] + [_fmt(m[n]["stages_ms_median"]["insert"], ".0f") for n in names[1:]]),
        ("speed ratio (x polyhull)", ["1"] + [_fmt(result["speed_ratio"][n], ".1f") for n in names[1:]]),
        ("possibly occupied in Z [m^3]", [_fmt(m[n]["volume_m3"], ".1f") for n in names]),
        ("  vs exact hull [%]", [_fmt(m[n]["excess_percent"], "+.0f") for n in names]),
        ("exact hull marked free [m^3]", [_fmt(m[n]["exact_hull_free_m3"], ".2f") for n in names]),
        ("person marked free [%] median", [_pct(m[n]["person_free_percent"]["median"]) for n in names]),
        ("person marked free [%] max", [_pct(m[n]["person_free_percent"]["max"]) for n in names]),
        ("robot links marked free [%]", [_fmt(m[n]["robot_free_percent"], ".1f") for n in names]),
        (f"min distance [m] median (true {_fmt(result['true_distance_m']['median'], '.2f')})", [_fmt(m[n]["distance_m"], ".2f") for n in names]),
        ("true - reported [m] median", [_fmt(m[n]["true_minus_reported_m"], "+.2f") for n in names]),
        ("cycles reported > true", [str(m[n]["cycles_reported_above_true"]) for n in names]),
    ]
    w = max(len(r[0]) for r in rows) + 2
    lines = [
        f"peers: {result['cycles']} cycles on the same frames; {o['library']} at {o['resolution_m']:g} m "
        f"(discretize={o['discretize']}, lazy_eval={o['lazy_eval']}), self filter padding {o['self_filter_padding_m']:g} m; "
        f"exact depth hull {result['volume_exact_hull_m3']:.1f} m^3 ({result['samples']} samples); it marks "
        f"{_fmt(result['exact_hull_person_free_percent']['median'], '.2f')} % of the person free in the median "
        f"(max {_fmt(result['exact_hull_person_free_percent']['max'], '.2f')} %)",
        f"{'':<{w}}" + "".join(f"{h:>16}" for h in heads),
    ]
    lines += [f"{label:<{w}}" + "".join(f"{c:>16}" for c in cells) for label, cells in rows]
    return "\n".join(lines)
