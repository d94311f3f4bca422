"""``polyhull bench``: the reference workload, timed per stage, with its accuracy checks.

Five parts, on one monitor (the static model is built once):

1. the reference workload: the cell, the robot moving, one walking person, default sensor
   effects; frames rendered before timing, ``warmup`` untimed cycles, then ``cycles`` timed
   ones: the cycle's median and p99 [ms] and every stage's median [ms]; and the new
   monitor's first two cycles [ms] (what a controller sees after starting it); each timed
   cycle's record (``cycles``: its time by stage, the pieces, the reported and true
   distance), which ``--plot OUT.png`` draws (:mod:`polyhull.benchplot`);
2. the person: over the walk, the true distance from the person's mesh to the robot's
   moving links against the reported distance (reported must never exceed true), and both
   against the distance of the exact depth hull's part that holds the person
   (:class:`polyhull.oracles.ExactHullGap`: the gap no conservative region from these cameras can close),
   or of the static region R3_static where it is nearer (blind space, static shadows and
   the noise sheets a person could stand in, such as the one in front of the rack: the
   engine's region always contains it);
3. tightness and misses on the last person cycle, by a Monte-Carlo point oracle: the exact
   depth hull C of the cycle's frames against the engine's region R2, and R2 against the
   exact hull with the static band (the engine's declared tolerance, :func:`polyhull.oracles.banded_free`);
4. the empty cell: nobody present, the robot moving, every sensor effect on: its cycle time
   (as many cycles as the person's, back to back), the dynamic pieces kept, their volume
   outside the static hull C_static (:func:`polyhull.oracles.dynamic_volume_outside_static`), and whether
   the distance departs from the static region's own distance;
5. with ``--peers N``: OctoMap on the frames of the last N timed cycles, side by side with
   the verdicts (:mod:`polyhull.peers`, the optional ``peers`` extra).

With ``--pace HZ`` the walk's cycles start at that rate, the thread sleeping between them as
a controller waiting for its frames does (by default they run back to back): on a machine
whose idle CPU wakes up slowly, the cycles take longer than back to back. With ``--repeat N``
the walk is timed N times on the same frames (the monitor reset in between) and its cycles
pooled; each pass's median is reported too, as the spread between passes shows how much of
a difference between two runs is the machine's (on the 2-core virtual machine the README's
figures come from, passes of one run differ by up to a third, and days by a factor of two).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PolyhullError
from ..oracles import (
    GAP_GRID,
    ExactHullGap,
    dynamic_volume_outside_static,
    exact_hull,
    tightness_and_misses,
)
from . import counted, require_extra

__all__ = ["register", "run_bench", "ring_cameras", "rescale_camera", "parse_resolution"]

DT = 0.1
"""Simulated time between cycles [s]."""

WALK_SPEED = 1.2
"""Walking speed of the person [m/s]: a walk toward the robot and back, repeated."""

MAX_CAMERAS = 16
RING_RADIUS = 2.9  # [m], around the zone centre
RING_HEIGHT = 3.3  # [m]
RING_TARGET_Z = 1.6  # [m], the cameras look at the zone centre at this height (as the default cell's)
MAX_SIDE = 4096  # [px]
MIN_SIDE = 16  # [px]
MAX_SAMPLES = 10_000_000
MAX_PACE = 1000.0  # [Hz]
MAX_REPEAT = 50


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``bench`` sub-command."""
    p = subparsers.add_parser(
        "bench",
        help="time the surveillance cycle on the reference workload and check its accuracy",
        description=(
            "Time the cycle (frames in, verdict out) on the reference workload: the paper's "
            "cell, four 640x480 depth cameras, the 6-axis robot in motion, one walking person, "
            "default sensor effects (frames are rendered before timing). Then check the "
            "distance against the person's true distance and against the exact depth hull's "
            "part that holds the person (2.5 cm grid, about 1 s per cycle), the tightness and "
            "misses of the region on the last cycle against the exact hull and the exact hull "
            "with the static band (Monte-Carlo point oracle), and the empty cell."
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
        help=f"replace the cameras by a ring of N (1..{MAX_CAMERAS}) of the first camera's kind "
        "(default: the cell's cameras)",
    )
    p.add_argument(
        "--resolution", default=None, metavar="WxH",
        help=f"rescale every camera's intrinsics to W x H px ({MIN_SIDE}..{MAX_SIDE} px per side; default: the cell's)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor effects and the samples (default 0)")
    p.add_argument(
        "--repeat", type=int, default=1, metavar="N",
        help=f"time the walk N times on the same frames, the monitor reset in between, and pool the "
        f"cycles (default 1, at most {MAX_REPEAT}); the accuracy checks use the last pass",
    )
    p.add_argument(
        "--pace", type=float, default=None, metavar="HZ",
        help="run the walk's cycles at HZ, sleeping until each cycle's tick as a controller "
        "waiting for its frames does (default: back to back); an idle CPU wakes up slower",
    )
    p.add_argument(
        "--spin", action="store_true",
        help="with --pace: wait for each tick in a busy loop instead of sleeping (keeps the CPU awake)",
    )
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
    p.add_argument(
        "--peers-resolution", type=float, default=None, metavar="M",
        help="with --peers: OctoMap voxel size [m] (default 0.05)",
    )
    p.add_argument(
        "--peers-full-rays",
        action="store_true",
        help="with --peers: OctoMap casts every point's own ray (as MoveIt does) instead of one per voxel "
        "(discretize, the faster)",
    )
    p.add_argument(
        "--plot", type=Path, default=None, metavar="OUT.png",
        help="also draw every timed cycle: its time split by stage against the targets, the pieces "
        "carved and the person's distance (needs the 'placement' extra)",
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
    pace: float | None = None,
    spin: bool = False,
    repeat: int = 1,
) -> dict[str, Any]:
    """Run the benchmark and its checks; return the figures (see the module docstring).

    Raises:
        PolyhullError: a bad argument (named after its flag) or a cell without a robot.
    """
    from ..monitor import Monitor
    from ..simulator import Simulator

    path, cell = _bench_cell(cell_path, cameras, resolution)
    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    assert monitor.robot is not None and monitor._distance_model is not None  # the cell has a robot
    n = warmup + cycles

    # 1. the reference workload: frames first, then the cycles
    inputs = _render_walk(monitor, sim, n, seed, progress)
    comparison = None  # OctoMap on the last ``peers`` timed cycles, alternating with the monitor
    if peers > 0:
        from ..peers import PeerComparison

        comparison = PeerComparison(
            monitor, lambda frames, points: exact_hull(monitor, frames, points),
            options=peers_options, samples=tightness_samples or 100_000, seed=seed,
        )
    stages: dict[str, list[float]] = {}
    pass_medians = []
    first: list[float] = []
    pass_timings: list[list[dict[str, float]]] = []  # every pass's timed cycles' timings
    for k in range(max(int(repeat), 1)):
        if k:
            monitor.reset()  # the same walk again, from a monitor without history
        last = k == repeat - 1
        times, first_k, verdicts = _time_walk(
            monitor, inputs, warmup, min(peers, cycles) if last else 0, comparison if last else None, progress, pace, spin
        )
        if k == 0:
            first = first_k  # a new monitor's (a reset one keeps its warm caches)
        pass_medians.append(float(np.median(times["total"])))
        pass_timings.append([dict(v.timings) for v in verdicts[warmup:]])
        for stage, ms in times.items():
            stages.setdefault(stage, []).extend(ms)
    total = np.asarray(stages.pop("total"))

    # 2. the person's distances; 3. tightness and misses on the last person cycle (before
    # the monitor moves on)
    person, trues = _person_figures(monitor, sim, inputs, verdicts, seed, progress)
    per_cycle = _per_cycle(inputs[warmup:], verdicts[warmup:], pass_timings, trues[warmup:])
    tightness = None
    if tightness_samples > 0 and verdicts[-1]._geometry is not None:
        tightness = tightness_and_misses(monitor, inputs[-1][0], verdicts[-1], tightness_samples, seed)
    del inputs

    # 4. the empty cell: the robot moving, every sensor effect on
    empty = _empty_cell(monitor, sim, empty_cycles, min(empty_cycles, n), warmup, seed, progress) if empty_cycles > 0 else None

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
            "pace_hz": pace,
            "pace_wait": None if pace is None else ("spin" if spin else "sleep"),
            "seed": seed,
            "repeat": int(repeat),
            "targets": f"one person walking at {WALK_SPEED} m/s toward the robot and back",
            "robot": "6-axis arm in motion",
            "sensor_effects": "default (noise, dropouts, out of range, flying pixels)",
            "empty_cell_sensor_effects": "all (default and uint16 millimetres)",
        },
        "cycle_ms": {
            "median": float(np.median(total)),
            "p99": float(np.percentile(total, 99)),
            "max": float(total.max()),
            "pass_medians": pass_medians,
        },
        "machine": {"cpu": _cpu_model(), "logical_cpus": os.cpu_count()},
        "first_cycles_ms": first,
        "stages_ms_median": {s: float(np.median(v)) for s, v in stages.items()},
        "stages_cycles": {s: len(v) for s, v in stages.items()},
        "cycles": per_cycle,
        "person": person,
        "tightness": tightness,
        "empty_cell": empty,
        "peers": None if comparison is None else comparison.result(),
    }


def _cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else :func:`platform.processor`."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _bench_cell(cell_path: Path | None, cameras: int | None, resolution: tuple[int, int] | None) -> tuple[Path, Any]:
    """The cell file's path and the cell, with ``--cameras`` and ``--resolution`` applied."""
    from ..cellfile import default_cell_path, load_cell
    from ..errors import CellError

    path = cell_path or default_cell_path()
    cell = load_cell(path)
    if cell.robot is None:
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
    return path, cell


def _robot_at(monitor: Any, t: float) -> np.ndarray:
    """The robot's joint positions at time ``t`` [s] (the demo's motion)."""
    from .demo import robot_motion

    robot = monitor.robot
    return robot_motion(np.asarray(monitor.cell.robot.q, dtype=np.float64), robot.lower, robot.upper, t)  # type: ignore[no-any-return]


def _render_walk(monitor: Any, sim: Any, n: int, seed: int, progress: bool) -> list[tuple[Any, np.ndarray, float, Any]]:
    """(frames, q, t, person mesh) of the walk's ``n`` cycles."""
    person_at = _walk(monitor.cell)
    inputs = []
    with _progress(n, "rendering", progress) as bar:
        for k in range(n):
            t = k * DT
            q = _robot_at(monitor, t)
            person = person_at(t)
            inputs.append((sim.render(q, targets=[person], seed=seed + k, stamp=t), q, t, person))
            bar.update()
    return inputs


def _time_walk(
    monitor: Any,
    inputs: list[tuple[Any, np.ndarray, float, Any]],
    warmup: int,
    peers: int,
    comparison: Any,
    progress: bool,
    pace: float | None = None,
    spin: bool = False,
) -> tuple[dict[str, list[float]], list[float], list[Any]]:
    """The walk's cycles back to back (with ``pace`` [Hz], each started at its tick, the
    thread sleeping until then, or with ``spin`` waiting in a busy loop): every stage's
    times [ms] after the ``warmup`` cycles, the first two cycles' [ms] (the warm-up's
    effect) and the verdicts (only the last one with its regions). With ``comparison``,
    OctoMap on the last ``peers`` cycles."""
    n = len(inputs)
    stages: dict[str, list[float]] = {}
    first: list[float] = []
    verdicts = []
    with _progress(n, "cycles", progress) as bar:
        for k, (frames, q, t, person) in enumerate(inputs):
            if k == 0:
                start = time.perf_counter()  # cycle k's tick: k / pace after the first's
            elif pace is not None:
                tick = start + k / pace
                if spin:
                    while time.perf_counter() < tick:
                        pass
                else:
                    time.sleep(max(tick - time.perf_counter(), 0.0))
            v = monitor.step(frames, q, stamp=t)
            if comparison is not None and k >= n - peers:
                bar.set_postfix_str("and OctoMap")
                comparison.add(frames, q, person, v)
            # as a controller does, no verdict's regions are kept but the last one's (a
            # kept verdict keeps its cycle's images, and the monitor allocates new ones)
            if k < 2:
                first.append(v.timings["total"])
            if k >= warmup:
                for stage, ms in v.timings.items():
                    stages.setdefault(stage, []).append(ms)
            verdicts.append(v if k == n - 1 else replace(v, _geometry=None))
            del v
            bar.update()
    return stages, first, verdicts


def _per_cycle(
    inputs: list[tuple[Any, np.ndarray, float, Any]],
    verdicts: list[Any],
    pass_timings: list[list[dict[str, float]]],
    trues: list[float],
) -> list[dict[str, Any]]:
    """One record per timed cycle: its time and every stage's [ms] (the median over the
    passes; a stage that did not run counts 0), the last pass's piece counts and distance,
    and the person's true distance."""
    out = []
    for i, ((_, _, t, _), v, true) in enumerate(zip(inputs, verdicts, trues, strict=True)):
        runs = [p[i] for p in pass_timings]
        names = [s for s in dict.fromkeys(k for r in runs for k in r) if s != "total"]  # every pass's, in order
        out.append({
            "cycle": i,
            "stamp_s": float(t),
            "total_ms": float(np.median([r["total"] for r in runs])),
            "stages_ms": {s: float(np.median([r.get(s, 0.0) for r in runs])) for s in names},
            "unexplained_pixels": int(v.counts.get("unexplained_pixels", 0)),
            "pieces": int(v.counts.get("pieces", 0)),
            "kept_pieces": int(v.counts.get("kept_pieces", 0)),
            "refined_pieces": int(v.counts.get("refined_pieces", 0)),
            "distance_m": float(v.min_distance),
            "true_distance_m": float(true),
            "speed_scale": float(v.speed_scale),
        })
    return out


def _person_figures(
    monitor: Any, sim: Any, inputs: list[tuple[Any, np.ndarray, float, Any]], verdicts: list[Any], seed: int, progress: bool
) -> tuple[dict[str, Any], list[float]]:
    """The true distance (person mesh to the moving links) against the reported one, and
    the exact hull's own gap: its part that holds the person, against the links; and the
    true distance of every cycle [m]."""
    from ..cell import mesh_to_manifold

    robot, distance_model = monitor.robot, monitor._distance_model
    trues, above = [], 0
    gap_of: list[float] = []  # per cycle (NaN where a distance is not finite)
    for (_, q, _, person), v in zip(inputs, verdicts, strict=True):
        true = distance_model.distance(robot.link_transforms(q), region=mesh_to_manifold(person, "person")).distance
        gap_of.append(true - v.min_distance if math.isfinite(true) and math.isfinite(v.min_distance) else math.nan)
        above += int(v.min_distance > true + 1e-6)
        trues.append(true)
    gaps = [g for g in gap_of if math.isfinite(g)]

    started = time.perf_counter()
    moving = set(distance_model.link_names)
    oracle = ExactHullGap(monitor, {n: m for n, m in robot.link_geometry().items() if n in moving}, seed=seed)
    exact_gaps, engine_losses, clipped, static_nearer = [], [], 0, 0
    decides: list[tuple[float, float]] = []  # (engine gap, exact gap) where the person's part is nearer
    with _progress(len(inputs), "exact hull gap", progress) as bar:
        for (frames, q, _, person), v, true, gap in zip(inputs, verdicts, trues, gap_of, strict=True):
            d, cut = oracle.measure(frames, sim.render_exact(q), robot.link_transforms(q), person)
            clipped += int(cut)
            # the static region (blind space, static shadows, kept noise sheets) is in the
            # engine's region every cycle: where it is nearer than the person's part, it
            # decides the distance
            static = distance_model.distance(
                robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains
            ).distance
            static_nearer += int(static < d)
            if d <= static and math.isfinite(d) and math.isfinite(true) and math.isfinite(gap):
                decides.append((gap, true - d))
            d = min(d, static)
            if math.isfinite(d) and math.isfinite(true):
                exact_gaps.append(true - d)
            if math.isfinite(d) and math.isfinite(v.min_distance):
                engine_losses.append(d - v.min_distance)
            bar.update()
    return {
        "cycles": len(verdicts),
        "true_minus_reported_m": {k: v for k, v in _stats(gaps).items() if k != "min"},
        "cycles_reported_above_true": above,
        "exact_hull_gap_m": {k: v for k, v in _stats(exact_gaps).items() if k != "min"},
        "engine_minus_exact_m": {k: v for k, v in _stats(engine_losses).items() if k != "min"},
        "exact_hull_cycles": len(exact_gaps),
        "exact_hull_cycles_clipped": clipped,
        "exact_hull_cycles_static_nearer": static_nearer,
        # the cycles where the exact hull's part that holds the person is nearer than the
        # static region: the person decides the distance the engine can report (elsewhere
        # the static region does, and the engine's gap is at least its)
        "person_decides": {
            "cycles": len(decides),
            "true_minus_reported_m": {k: v for k, v in _stats([a for a, _ in decides]).items() if k != "min"},
            "exact_hull_gap_m": {k: v for k, v in _stats([b for _, b in decides]).items() if k != "min"},
        },
        "exact_hull_grid_m": GAP_GRID,
        "exact_hull_seconds": time.perf_counter() - started,
        "distance_m": _stats([v.min_distance for v in verdicts]),
        "speed_scale": _stats([v.speed_scale for v in verdicts]),
        "faults": sorted({f for v in verdicts for f in v.faults}),
    }, trues


def _empty_cell(monitor: Any, sim: Any, cycles: int, timed: int, warmup: int, seed: int, progress: bool) -> dict[str, Any]:
    """The empty cell, the robot moving, every sensor effect on: the cost of its first
    ``timed`` cycles back to back (frames rendered before, as the person's cycles: the
    checks below run manifold booleans between cycles), then ``cycles`` cycles checked
    against the static region."""
    from ..simulator import SensorEffects

    robot, distance_model = monitor.robot, monitor._distance_model
    effects = SensorEffects(uint16=True)

    def empty_frames(k: int) -> tuple[Any, np.ndarray, float]:
        t = k * DT
        q = _robot_at(monitor, t)
        return sim.render(q, seed=seed + 10_000 + k, stamp=t, effects=effects), q, t

    with _progress(timed, "empty cell, timed", progress) as bar:
        frames_q_t = []
        for k in range(timed):
            frames_q_t.append(empty_frames(k))
            bar.update()
    monitor.reset()
    empty_ms = []
    for k, (frames, q, t) in enumerate(frames_q_t):
        v = monitor.step(frames, q, stamp=t)
        if k >= min(warmup, timed - 1):
            empty_ms.append(v.timings["total"])
    del frames_q_t, v
    monitor.reset()
    kept: list[int] = []
    added: list[float] = []
    dists: list[float] = []
    scales: list[float] = []
    faults: set[str] = set()
    off = 0
    with _progress(cycles, "empty cell", progress) as bar:
        for k in range(cycles):
            frames, q, t = empty_frames(k)
            v = monitor.step(frames, q, stamp=t)
            static = distance_model.distance(
                robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains
            ).distance
            kept.append(v.counts.get("kept_pieces", 0))
            added.append(dynamic_volume_outside_static(monitor, v))
            off += int(not (v.min_distance == static or abs(v.min_distance - static) <= 0.01))
            dists.append(v.min_distance)
            scales.append(v.speed_scale)
            faults.update(v.faults)
            bar.update()
    min_volume = monitor.cell.plausibility.min_volume
    return {
        "cycles": cycles,
        "cycle_ms": {
            "median": float(np.median(empty_ms)),
            "p99": float(np.percentile(empty_ms, 99)),
            "max": float(np.max(empty_ms)),
            "cycles": len(empty_ms),
        },
        "kept_pieces": _stats(kept),
        "cycles_with_kept_pieces": int(np.count_nonzero(kept)),
        "dynamic_volume_outside_static_l": _stats([1e3 * a for a in added]),
        "min_volume_l": 1e3 * min_volume,
        "cycles_dynamic_volume_over_min_volume": int(sum(a > min_volume for a in added)),
        "cycles_distance_off_static": off,
        "distance_m": _stats(dists),
        "speed_scale": _stats(scales),
        "faults": sorted(faults),
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
    if args.pace is not None and not (math.isfinite(args.pace) and 0.0 < args.pace <= MAX_PACE):
        raise PolyhullError(f"--pace must be a rate in (0, {MAX_PACE:g}] Hz, got {args.pace}")
    if not 1 <= args.repeat <= MAX_REPEAT:
        raise PolyhullError(f"--repeat must be in 1..{MAX_REPEAT}, got {args.repeat}")
    if args.spin and args.pace is None:
        raise PolyhullError("--spin waits for --pace's ticks: give --pace HZ too")
    if args.peers_resolution is not None and not args.peers:
        raise PolyhullError("--peers-resolution is the voxel size of --peers' OctoMap: give --peers too")
    if args.peers_full_rays and not args.peers:
        raise PolyhullError("--peers-full-rays sets how --peers' OctoMap casts rays: give --peers too")
    if args.plot is not None:
        if args.plot.suffix.lower() != ".png":
            raise PolyhullError(f"--plot {args.plot}: the bench plot is a PNG; give a path ending in .png")
        if not args.plot.parent.is_dir():
            raise PolyhullError(f"--plot {args.plot}: the directory {args.plot.parent} does not exist")
        require_extra("matplotlib", "the bench plot (--plot)", "placement")
    return None if args.resolution is None else parse_resolution(args.resolution)


def _fmt(x: float | None, spec: str = ".3f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _run(args: argparse.Namespace) -> int:
    resolution = _check(args)
    peers_options = None
    if args.peers:
        from ..peers import OctomapOptions, require_octomap

        require_octomap()  # before any work: a missing extra is one line
        voxel = OctomapOptions.resolution if args.peers_resolution is None else args.peers_resolution
        peers_options = OctomapOptions(resolution=voxel, discretize=not args.peers_full_rays)
    # anything the engine prints goes to stderr: with --json, stdout holds the object only
    with contextlib.redirect_stdout(sys.stderr):
        result = run_bench(
            args.cell, args.cycles, args.warmup, args.empty_cycles, args.tightness_samples,
            args.cameras, resolution, args.seed, progress=True, peers=args.peers, peers_options=peers_options,
            pace=args.pace, spin=args.spin, repeat=args.repeat,
        )
    if args.plot is not None:
        from ..benchplot import plot_stages

        w, c = result["workload"], result["cycle_ms"]
        title = (f"polyhull bench: {w['cameras']} cameras {w['resolution'][0]}x{w['resolution'][1]}, "
                 f"cycle median {c['median']:.1f} ms, p99 {c['p99']:.1f} ms")
        plot_stages(result["cycles"], args.plot, title=title)
    if args.json:
        print(json.dumps(_finite(result), indent=2))
        if args.plot is not None:
            print(f"wrote {args.plot}", file=sys.stderr)
        return 0
    w, c = result["workload"], result["cycle_ms"]
    paced = "back to back" if w["pace_hz"] is None else f"paced at {w['pace_hz']:g} Hz ({w['pace_wait']})"
    passes = "" if w["repeat"] == 1 else f", {w['repeat']} passes pooled"
    print(f"polyhull bench: {w['cameras']} cameras {w['resolution'][0]}x{w['resolution'][1]}, "
          f"{counted(w['cycles'], 'cycle')} after {w['warmup']} warm-up, {paced}{passes}")
    m = result["machine"]
    print(f"machine: {m['cpu']}, {m['logical_cpus']} logical CPUs")
    print(f"{'stage':<16}{'median [ms]':>12}")
    for stage, ms in result["stages_ms_median"].items():
        ran, timed = result["stages_cycles"][stage], w["cycles"] * w["repeat"]
        note = "" if ran == timed else f"   (ran in {ran} of {timed} cycles)"
        print(f"{stage:<16}{ms:12.1f}{note}")
    print("  (robot_raster lasts until the last camera's raster is done: each camera's raster and pixel "
          "classes are one task on two threads, so it holds the first cameras' pixel classes too)")
    print(f"{'cycle median':<16}{c['median']:12.1f}")
    print(f"{'cycle p99':<16}{c['p99']:12.1f}")
    if w["repeat"] > 1:
        print("each pass's median: " + ", ".join(f"{ms:.1f}" for ms in c["pass_medians"]) + " ms")
    print("a new monitor's first cycles: " + ", ".join(f"{ms:.1f}" for ms in result["first_cycles_ms"]) + " ms")
    p = result["person"]
    g = p["true_minus_reported_m"]
    print(f"person: {counted(p['cycles'], 'cycle')}, true - reported distance median {_fmt(g['median'])} m, "
          f"max {_fmt(g['max'])} m; reported above true in {counted(p['cycles_reported_above_true'], 'cycle')}; "
          f"speed scale median {_fmt(p['speed_scale']['median'], '.2f')}, min {_fmt(p['speed_scale']['min'], '.2f')}")
    x, e = p["exact_hull_gap_m"], p["engine_minus_exact_m"]
    print(f"exact hull around the person ({p['exact_hull_grid_m'] * 100:.1f} cm grid, {counted(p['exact_hull_cycles'], 'cycle')}, "
          f"{p['exact_hull_seconds']:.1f} s): true distance - its distance median {_fmt(x['median'])} m, max "
          f"{_fmt(x['max'])} m (the least gap a conservative region from these cameras can have; an estimate; "
          f"the static region nearer in {counted(p['exact_hull_cycles_static_nearer'], 'cycle')})")
    print(f"engine against that exact hull: its distance - reported median {_fmt(e['median'])} m, "
          f"max {_fmt(e['max'])} m (what the engine loses to the exact hull)")
    pd = p["person_decides"]
    print(f"where the person decides (the exact hull's part that holds them nearer than the static region, "
          f"{pd['cycles']} of {p['exact_hull_cycles']} cycles): true - reported median "
          f"{_fmt(pd['true_minus_reported_m']['median'])} m, the exact hull's {_fmt(pd['exact_hull_gap_m']['median'])} m")
    if p["faults"]:
        print(f"  faults: {'; '.join(p['faults'])}")
    t = result["tightness"]
    if t is not None:
        print(f"tightness (last person cycle, {t['samples']} samples): exact C ~{t['volume_exact_hull_m3']:.3f} m^3, "
              f"engine R2 ~{t['volume_engine_r2_m3']:.3f} m^3, excess {_fmt(t['excess_percent'], '+.1f')} % "
              f"({_fmt(t['excess_outside_robot_shadow_percent'], '+.1f')} % against C outside the robot shadow)")
        print(f"R2 against the exact hull with the static band: {t['volume_engine_r2_m3']:.1f} vs "
              f"{t['volume_exact_banded_m3']:.1f} m^3 ({_fmt(t['excess_over_banded_percent'], '+.0f')} %)")
        print(f"misses: {t['misses']} (outside R2 and the padded robot's M), {t['misses_band']} in M only with the "
              f"static band, {t['misses_flying']} only with a static edge's flying pixels; "
              f"{t['misses_unexcused']} exact-hull points outside R2 in all, the others in M (the padding)")
    e = result["empty_cell"]
    if e is not None:
        c = e["cycle_ms"]
        print(f"empty cell: cycle median {c['median']:.1f} ms, p99 {c['p99']:.1f} ms ({counted(c['cycles'], 'cycle')} back to back)")
        print(f"empty cell: {counted(e['cycles'], 'cycle')}, kept pieces median {e['kept_pieces']['median']:.0f}, "
              f"max {e['kept_pieces']['max']:.0f} ({counted(e['cycles_with_kept_pieces'], 'cycle')} with any); distance "
              f"off the static region's by > 1 cm in {counted(e['cycles_distance_off_static'], 'cycle')}; distance median "
              f"{_fmt(e['distance_m']['median'])} m, min {_fmt(e['distance_m']['min'])} m; speed scale median "
              f"{_fmt(e['speed_scale']['median'], '.2f')}, min {_fmt(e['speed_scale']['min'], '.2f')}")
        a = e["dynamic_volume_outside_static_l"]
        print(f"empty cell: dynamic volume outside C_static median {_fmt(a['median'], '.1f')} l, max "
              f"{_fmt(a['max'], '.1f')} l; over the too-small threshold ({e['min_volume_l']:g} l) in "
              f"{e['cycles_dynamic_volume_over_min_volume']} of {e['cycles']} cycles")
        if e["faults"]:
            print(f"  faults: {'; '.join(e['faults'])}")
    if result["peers"] is not None:
        from ..peers import format_table

        print(format_table(result["peers"]))
    if args.plot is not None:
        print(f"wrote {args.plot}: each timed cycle's time by stage, the pieces carved and the person's distance")
    return 0
