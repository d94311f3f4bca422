"""``polyhull bench``: the reference workload, timed per stage, with its accuracy checks.

Four parts, on one monitor (the static model is built once):

1. the reference workload: the cell, the robot moving, one walking person, default sensor
   effects; frames rendered before timing, ``warmup`` untimed cycles, then ``cycles`` timed
   ones: the cycle's median and p99 [ms] and every stage's median [ms];
2. the person: over the walk, the true distance from the person's mesh to the robot's
   moving links against the reported distance (reported must never exceed true);
3. tightness and misses on the last person cycle, by a Monte-Carlo point oracle: the exact
   depth hull C of the cycle's frames against the engine's region R2;
4. the empty cell: nobody present, the robot moving, every sensor effect on: the dynamic
   pieces kept, and whether the distance departs from the static region's own distance;
5. with ``--peers N``: OctoMap on the frames of the last N timed cycles, side by side with
   the verdicts (:mod:`polyhull.peers`, the optional ``peers`` extra).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PolyhullError

__all__ = ["register", "run_bench", "ring_cameras", "rescale_camera", "parse_resolution"]

DT = 0.1
"""Simulated time between cycles [s]."""

WALK_SPEED = 1.2
"""Walking speed of the person [m/s]: a walk toward the robot and back, repeated."""

MAX_CAMERAS = 16
RING_RADIUS = 2.9  # [m], around the zone centre
RING_HEIGHT = 3.3  # [m]
RING_TARGET_Z = 1.0  # [m], the cameras look at the zone centre at this height
MAX_SIDE = 4096  # [px]
MIN_SIDE = 16  # [px]
MAX_SAMPLES = 10_000_000


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``bench`` sub-command."""
    p = subparsers.add_parser(
        "bench",
        help="time the surveillance cycle on the reference workload and check its accuracy",
        description=(
            "Time the cycle (frames in, verdict out) on the reference workload: the paper's "
            "cell, four 640x480 depth cameras, the 6-axis robot in motion, one walking person, "
            "default sensor effects (frames are rendered before timing). Then check the "
            "distance against the person's true distance, the tightness and misses of the "
            "region on the last cycle (Monte-Carlo point oracle), and the empty cell."
        ),
    )
    p.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    p.add_argument("--cycles", type=int, default=20, help="timed cycles (default 20)")
    p.add_argument("--warmup", type=int, default=2, help="untimed cycles first (default 2)")
    p.add_argument(
        "--empty-cycles", type=int, default=100, help="cycles of the empty cell (default 100; 0 skips)"
    )
    p.add_argument(
        "--tightness-samples",
        type=int,
        default=100_000,
        help="points sampled in the zone for the tightness and misses oracle (default 100000; 0 skips)",
    )
    p.add_argument(
        "--cameras",
        type=int,
        default=None,
        help=f"replace the cameras by a ring of N (1..{MAX_CAMERAS}) of the first camera's kind",
    )
    p.add_argument(
        "--resolution", default=None, metavar="WxH", help="rescale every camera's intrinsics to W x H px"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor effects and the samples (default 0)")
    p.add_argument(
        "--peers",
        type=int,
        nargs="?",
        const=3,
        default=0,
        metavar="N",
        help="also run OctoMap (fresh and incremental tree) on the last N timed cycles' frames and print "
        "the side-by-side table (N = 3 without a value; 5 to 10 s per cycle and tree; needs the 'peers' extra)",
    )
    p.add_argument("--peers-resolution", type=float, default=0.05, metavar="M", help="OctoMap voxel size [m] (default 0.05)")
    p.add_argument(
        "--peers-full-rays",
        action="store_true",
        help="OctoMap casts every point's own ray (as MoveIt does) instead of one per voxel (discretize, the faster)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object and nothing else")
    p.set_defaults(func=_run)


# -- the cameras ---------------------------------------------------------------------------
def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H) [px], or PolyhullError naming ``--resolution``."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if m is None:
        raise PolyhullError(f"--resolution must be WxH in pixels (e.g. 640x480), got {text!r}")
    w, h = int(m.group(1)), int(m.group(2))
    if not (MIN_SIDE <= w <= MAX_SIDE and MIN_SIDE <= h <= MAX_SIDE):
        raise PolyhullError(f"--resolution: width and height must be in {MIN_SIDE}..{MAX_SIDE} px, got {w}x{h}")
    return w, h


def rescale_camera(camera: Any, width: int, height: int) -> Any:
    """The camera with its intrinsics rescaled to ``width`` x ``height`` px (same field of view)."""
    from ..camera import Intrinsics

    k = camera.intrinsics
    sx, sy = width / k.width, height / k.height
    # pixel centres sit at integers: the image edge -0.5 maps to -0.5
    scaled = Intrinsics(width, height, k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5, (k.cy + 0.5) * sy - 0.5)
    return replace(camera, intrinsics=scaled)


def ring_cameras(cell: Any, n: int) -> tuple[Any, ...]:
    """``n`` cameras like the cell's first one, evenly on a circle of radius ``RING_RADIUS``
    around the zone centre at height ``RING_HEIGHT``, looking at the zone centre at
    ``RING_TARGET_Z`` (the first one in the zone's min-x, min-y direction)."""
    from ..camera import look_at_rotation

    base = cell.cameras[0]
    centre = np.asarray(cell.zone.min) + 0.5 * cell.zone.size
    target = np.array([centre[0], centre[1], RING_TARGET_Z])
    cams = []
    for i in range(n):
        a = -0.75 * np.pi + 2.0 * np.pi * i / n
        pos = np.array([centre[0] + RING_RADIUS * np.cos(a), centre[1] + RING_RADIUS * np.sin(a), RING_HEIGHT])
        T = np.eye(4)
        T[:3, :3] = look_at_rotation(pos, target)
        T[:3, 3] = pos
        cams.append(replace(base, name=f"ring{i}", T_world_camera=T))
    return tuple(cams)


# -- the oracles ---------------------------------------------------------------------------
def _pixels(camera: Any, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixel (u, v) of each point (nearest pixel centre), its z-depth, and whether it is in
    the image in front of the camera."""
    uv, z = camera.project(points)
    H, W = camera.shape
    with np.errstate(invalid="ignore"):
        px = np.floor(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0) + 0.5).astype(np.int64)
    inside = (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
    u = np.where(inside, px[:, 0], 0)
    v = np.where(inside, px[:, 1], 0)
    return u, v, z, inside


def _in_pieces(points: np.ndarray, pieces: np.ndarray) -> np.ndarray:
    """(P,) whether each point lies in some convex hexahedron of ``pieces`` (N, 8, 3)."""
    from scipy.spatial import cKDTree

    from ..distance import points_in_hexahedra

    out = np.zeros(len(points), dtype=bool)
    if len(points) == 0 or len(pieces) == 0:
        return out
    centres = 0.5 * (pieces.min(axis=1) + pieces.max(axis=1))
    radii = np.linalg.norm(pieces - centres[:, None, :], axis=2).max(axis=1)
    near = cKDTree(points).query_ball_point(centres, radii)  # candidate points of each piece
    for i, idx in enumerate(near):
        if idx:
            out[idx] |= points_in_hexahedra(points[idx], pieces[i : i + 1])
    return out


def exact_hull(monitor: Any, frames: Mapping[str, Any], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P,) whether each point lies in the exact depth hull C of the frames (outside the solid
    obstacles), and (P,) whether it lies in a solid obstacle.

    A point frees in a camera when in the image, ``z >= near`` and ``z <= f[v, u]`` with the
    exact per-pixel free depth f; it is in C when fewer than k cameras free it.
    """
    from ..regions import free_depth

    cell = monitor.cell
    freed = np.zeros(len(points), dtype=np.int64)
    for s in monitor.static.cameras:
        cam = s.camera
        u, v, z, inside = _pixels(cam, points)
        f = free_depth(cam, frames[cam.name].depth, s.reference)
        freed += inside & (z >= cam.near) & (z <= f[v, u])
    solid = np.zeros(len(points), dtype=bool)
    for o in cell.solid_obstacles:  # boxes
        b = o.mesh.bounds
        solid |= np.all((points >= b[0]) & (points <= b[1]), axis=1)
    return (freed < cell.reconstruction.k_of_n) & ~solid, solid


def tightness_and_misses(monitor: Any, frames: dict, verdict: Any, samples: int, seed: int) -> dict[str, Any]:  # type: ignore[type-arg]
    """Monte-Carlo comparison of the exact depth hull C with the engine's R2 (last cycle).

    - exact C: :func:`exact_hull`;
    - engine R2: C_static (the static model's point oracle) outside the solid obstacles,
      or inside one of the cycle's dynamic pieces (before the plausibility rules);
    - padded robot shadow: for some camera the point falls on a pixel the padded robot
      covers, at or behind ``shadow_start`` (the engine's declared robot-occlusion tolerance).

    Both volumes leave out the solid obstacles (nobody can be inside them). ``misses`` are
    exact-C points outside R2 and outside the padded robot shadow (must be 0);
    ``misses_unexcused`` counts them without the shadow excuse.
    """
    cell = monitor.cell
    k = cell.reconstruction.k_of_n
    lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    p = np.random.default_rng(seed).uniform(lo, hi, size=(samples, 3))
    exact, solid = exact_hull(monitor, frames, p)
    shadow = np.zeros(samples, dtype=bool)
    for s in monitor.static.cameras:
        r = monitor.last_images.raster.get(s.camera.name)
        if r is not None:
            u, v, z, inside = _pixels(s.camera, p)
            shadow |= inside & r.covered[v, u] & (z >= r.shadow_start[v, u])
    r2 = (monitor.static.hull_contains(p, k) & ~solid) | _in_pieces(p, verdict._geometry.pieces)
    zone = cell.zone.volume
    v_exact = zone * float(exact.mean())
    v_r2 = zone * float(r2.mean())
    v_exact_out = zone * float((exact & ~shadow).mean())
    return {
        "samples": samples,
        "volume_zone_m3": zone,
        "volume_exact_hull_m3": v_exact,
        "volume_engine_r2_m3": v_r2,
        "excess_percent": 100.0 * (v_r2 / v_exact - 1.0) if v_exact > 0 else math.inf,
        "volume_exact_hull_outside_robot_shadow_m3": v_exact_out,
        "excess_outside_robot_shadow_percent": 100.0 * (v_r2 / v_exact_out - 1.0) if v_exact_out > 0 else math.inf,
        "misses": int((exact & ~r2 & ~shadow).sum()),
        "misses_unexcused": int((exact & ~r2).sum()),
    }


# -- the workloads -------------------------------------------------------------------------
def _stats(values: Sequence[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {"median": math.nan, "min": math.nan, "max": math.nan}
    return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max())}


def _progress(total: int, desc: str, enabled: bool) -> Any:
    from tqdm import tqdm

    # to stderr, and only on a terminal (disable=None), so --json keeps stdout clean
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=None if enabled else True, leave=False)


def _walk(cell: Any) -> Any:
    """Person mesh at time t [s]: from a zone corner to 1 m in front of the robot and back,
    at ``WALK_SPEED``, repeated."""
    from .demo import person_path

    zmin, zmax = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    robot_xy = np.asarray(cell.robot.base[:2])
    length = max(float(np.linalg.norm(robot_xy - (zmin[:2] + 0.35))) - 1.0, 0.1)
    period = 2.0 * length / WALK_SPEED
    walk = person_path(zmin, zmax, robot_xy, period)
    return lambda t: walk(t % period)  # type: ignore[operator]


def run_bench(
    cell_path: Path | None = None,
    cycles: int = 20,
    warmup: int = 2,
    empty_cycles: int = 100,
    tightness_samples: int = 100_000,
    cameras: int | None = None,
    resolution: tuple[int, int] | None = None,
    seed: int = 0,
    progress: bool = False,
    peers: int = 0,
    peers_options: Any = None,
) -> dict[str, Any]:
    """Run the benchmark and its checks; return the figures (see the module docstring).

    Raises:
        PolyhullError: a bad argument (named after its flag) or a cell without a robot.
    """
    from ..cell import mesh_to_manifold
    from ..cellfile import default_cell_path, load_cell
    from ..errors import CellError
    from ..monitor import Monitor
    from ..simulator import SensorEffects, Simulator
    from .demo import robot_motion

    path = cell_path or default_cell_path()
    cell = load_cell(path)
    spec = cell.robot
    if spec is None:
        raise PolyhullError(f"{path}: the benchmark needs a cell with a [robot]")
    if not cell.cameras:
        raise PolyhullError(f"{path}: the benchmark needs a cell with cameras")
    try:
        if cameras is not None:
            cell = replace(cell, cameras=ring_cameras(cell, cameras))
    except CellError as exc:
        raise PolyhullError(f"--cameras: {exc}") from exc
    if resolution is not None:
        cell = replace(cell, cameras=tuple(rescale_camera(c, *resolution) for c in cell.cameras))

    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    robot, distance_model = monitor.robot, monitor._distance_model
    assert robot is not None and distance_model is not None  # the cell has a robot
    q0 = np.asarray(spec.q, dtype=np.float64)
    person_at = _walk(cell)
    n = warmup + cycles

    # 1. the reference workload: frames first, then the cycles
    inputs = []
    with _progress(n, "rendering", progress) as bar:
        for k in range(n):
            t = k * DT
            q = robot_motion(q0, robot.lower, robot.upper, t)
            person = person_at(t)
            inputs.append((sim.render(q, targets=[person], seed=seed + k, stamp=t), q, t, person))
            bar.update()
    stages: dict[str, list[float]] = {}
    verdicts = []
    comparison = None  # OctoMap on the last ``peers`` timed cycles, alternating with the monitor
    if peers > 0:
        from ..peers import PeerComparison

        comparison = PeerComparison(
            monitor, lambda frames, points: exact_hull(monitor, frames, points),
            options=peers_options, samples=tightness_samples or 100_000, seed=seed,
        )
    with _progress(n, "cycles", progress) as bar:
        for k, (frames, q, t, person) in enumerate(inputs):
            v = monitor.step(frames, q, stamp=t)
            verdicts.append(v)
            if comparison is not None and k >= n - min(peers, cycles):
                bar.set_postfix_str("and OctoMap")
                comparison.add(frames, q, person, v)
            if k >= warmup:
                for stage, ms in v.timings.items():
                    stages.setdefault(stage, []).append(ms)
            bar.update()
    total = np.asarray(stages.pop("total"))

    # 2. the person: true distance (person mesh to the moving links) against the reported one
    gaps, above = [], 0
    for (_, q, _, person), v in zip(inputs, verdicts, strict=True):
        true = distance_model.distance(
            robot.link_transforms(q), region=mesh_to_manifold(person, "person")
        ).distance
        if math.isfinite(true) and math.isfinite(v.min_distance):
            gaps.append(true - v.min_distance)
        above += int(v.min_distance > true + 1e-6)
    person_faults = sorted({f for v in verdicts for f in v.faults})

    # 3. tightness and misses on the last person cycle (before the monitor moves on)
    tightness = None
    if tightness_samples > 0 and verdicts[-1]._geometry is not None:
        tightness = tightness_and_misses(monitor, inputs[-1][0], verdicts[-1], tightness_samples, seed)
    del inputs

    # 4. the empty cell: the robot moving, every sensor effect on
    empty: dict[str, Any] | None = None
    if empty_cycles > 0:
        effects = SensorEffects(uint16=True)
        monitor.reset()
        kept: list[int] = []
        dists: list[float] = []
        scales: list[float] = []
        faults: set[str] = set()
        off = 0
        with _progress(empty_cycles, "empty cell", progress) as bar:
            for k in range(empty_cycles):
                t = k * DT
                q = robot_motion(q0, robot.lower, robot.upper, t)
                v = monitor.step(sim.render(q, seed=seed + 10_000 + k, stamp=t, effects=effects), q, stamp=t)
                static = distance_model.distance(
                    robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains
                ).distance
                kept.append(v.counts.get("kept_pieces", 0))
                off += int(not (v.min_distance == static or abs(v.min_distance - static) <= 0.01))
                dists.append(v.min_distance)
                scales.append(v.speed_scale)
                faults.update(v.faults)
                bar.update()
        empty = {
            "cycles": empty_cycles,
            "kept_pieces": _stats(kept),
            "cycles_with_kept_pieces": int(np.count_nonzero(kept)),
            "cycles_distance_off_static": off,
            "distance_m": _stats(dists),
            "speed_scale": _stats(scales),
            "faults": sorted(faults),
        }

    cams = cell.cameras
    return {
        "workload": {
            "cell": str(path),
            "cameras": len(cams),
            "camera_layout": "ring" if cameras is not None else "cell",
            "resolution": [cams[0].intrinsics.width, cams[0].intrinsics.height],
            "cycles": cycles,
            "warmup": warmup,
            "dt_s": DT,
            "seed": seed,
            "targets": f"one person walking at {WALK_SPEED} m/s toward the robot and back",
            "robot": "6-axis arm in motion",
            "sensor_effects": "default (noise, dropouts, out of range, flying pixels)",
            "empty_cell_sensor_effects": "all (default and uint16 millimetres)",
        },
        "cycle_ms": {"median": float(np.median(total)), "p99": float(np.percentile(total, 99)), "max": float(total.max())},
        "stages_ms_median": {s: float(np.median(v)) for s, v in stages.items()},
        "stages_cycles": {s: len(v) for s, v in stages.items()},
        "person": {
            "cycles": len(verdicts),
            "true_minus_reported_m": {k: v for k, v in _stats(gaps).items() if k != "min"},
            "cycles_reported_above_true": above,
            "distance_m": _stats([v.min_distance for v in verdicts]),
            "speed_scale": _stats([v.speed_scale for v in verdicts]),
            "faults": person_faults,
        },
        "tightness": tightness,
        "empty_cell": empty,
        "peers": None if comparison is None else comparison.result(),
    }


# -- the command ---------------------------------------------------------------------------
def _finite(obj: Any) -> Any:
    """JSON-safe copy: non-finite floats become None."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _check(args: argparse.Namespace) -> tuple[int, int] | None:
    if args.cycles < 1:
        raise PolyhullError(f"--cycles must be >= 1, got {args.cycles}")
    if args.warmup < 0:
        raise PolyhullError(f"--warmup must be >= 0, got {args.warmup}")
    if args.empty_cycles < 0:
        raise PolyhullError(f"--empty-cycles must be >= 0, got {args.empty_cycles}")
    if not 0 <= args.tightness_samples <= MAX_SAMPLES:
        raise PolyhullError(f"--tightness-samples must be in 0..{MAX_SAMPLES}, got {args.tightness_samples}")
    if args.cameras is not None and not 1 <= args.cameras <= MAX_CAMERAS:
        raise PolyhullError(f"--cameras must be in 1..{MAX_CAMERAS}, got {args.cameras}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")
    if args.peers < 0:
        raise PolyhullError(f"--peers must be >= 0 cycles, got {args.peers}")
    return None if args.resolution is None else parse_resolution(args.resolution)


def _fmt(x: float | None, spec: str = ".3f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _run(args: argparse.Namespace) -> int:
    resolution = _check(args)
    peers_options = None
    if args.peers:
        from ..peers import OctomapOptions, require_octomap

        require_octomap()  # before any work: a missing extra is one line
        peers_options = OctomapOptions(resolution=args.peers_resolution, discretize=not args.peers_full_rays)
    # anything the engine prints goes to stderr: with --json, stdout holds the object only
    with contextlib.redirect_stdout(sys.stderr):
        result = run_bench(
            args.cell, args.cycles, args.warmup, args.empty_cycles, args.tightness_samples,
            args.cameras, resolution, args.seed, progress=True, peers=args.peers, peers_options=peers_options,
        )
    if args.json:
        print(json.dumps(_finite(result), indent=2))
        return 0
    w, c = result["workload"], result["cycle_ms"]
    print(f"polyhull bench: {w['cameras']} cameras {w['resolution'][0]}x{w['resolution'][1]}, "
          f"{w['cycles']} cycles after {w['warmup']} warm-up")
    print(f"{'stage':<16}{'median [ms]':>12}")
    for stage, ms in result["stages_ms_median"].items():
        ran = result["stages_cycles"][stage]
        note = "" if ran == w["cycles"] else f"   (ran in {ran} of {w['cycles']} cycles)"
        print(f"{stage:<16}{ms:12.1f}{note}")
    print(f"{'cycle median':<16}{c['median']:12.1f}")
    print(f"{'cycle p99':<16}{c['p99']:12.1f}")
    p = result["person"]
    g = p["true_minus_reported_m"]
    print(f"person: {p['cycles']} cycles, true - reported distance median {_fmt(g['median'])} m, "
          f"max {_fmt(g['max'])} m; reported above true in {p['cycles_reported_above_true']} cycles; "
          f"speed scale median {_fmt(p['speed_scale']['median'], '.2f')}, min {_fmt(p['speed_scale']['min'], '.2f')}")
    if p["faults"]:
        print(f"  faults: {'; '.join(p['faults'])}")
    t = result["tightness"]
    if t is not None:
        print(f"tightness (last person cycle, {t['samples']} samples): exact C ~{t['volume_exact_hull_m3']:.3f} m^3, "
              f"engine R2 ~{t['volume_engine_r2_m3']:.3f} m^3, excess {_fmt(t['excess_percent'], '+.1f')} % "
              f"({_fmt(t['excess_outside_robot_shadow_percent'], '+.1f')} % against C outside the robot shadow)")
        print(f"misses: {t['misses']} (outside R2 and the padded robot shadow), unexcused {t['misses_unexcused']}")
    e = result["empty_cell"]
    if e is not None:
        print(f"empty cell: {e['cycles']} cycles, kept pieces median {e['kept_pieces']['median']:.0f}, "
              f"max {e['kept_pieces']['max']:.0f} ({e['cycles_with_kept_pieces']} cycles with any); distance "
              f"off the static region's by > 1 cm in {e['cycles_distance_off_static']} cycles; distance median "
              f"{_fmt(e['distance_m']['median'])} m, min {_fmt(e['distance_m']['min'])} m; speed scale median "
              f"{_fmt(e['speed_scale']['median'], '.2f')}, min {_fmt(e['speed_scale']['min'], '.2f')}")
        if e["faults"]:
            print(f"  faults: {'; '.join(e['faults'])}")
    if result["peers"] is not None:
        from ..peers import format_table

        print(format_table(result["peers"]))
    return 0
