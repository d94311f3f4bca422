"""``polyhull demo``: a person walks through the embedded default cell while the robot works."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MissingExtraError, PolyhullError
from . import counted, require_extra

__all__ = ["register", "robot_motion", "person_path", "TrueDistance"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``demo`` sub-command."""
    p = subparsers.add_parser(
        "demo",
        help="simulate a person walking through the default cell while the robot works",
        description=(
            "Simulate the embedded default cell (the paper's 6 m x 6 m x 3.5 m cell, four depth "
            "cameras): a person walks in from the boundary, comes close to the working robot and "
            "leaves. Prints a line per cycle (distance, speed scale, cycle time), a summary, "
            "writes an animated standalone HTML meshcat scene (viewer extra) and a timeline plot "
            "(PNG: distance, protective separation distance, the person's true distance, speed "
            "scale and cycle time against time; placement extra)."
        ),
    )
    p.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    p.add_argument(
        "--cycles", type=int, default=48,
        help="number of cycles (default 48). The person walks in and out over the first three quarters "
        "of the run (cycles x dt), so a shorter run is a faster walk: the default walks at about 1.5 m/s",
    )
    p.add_argument(
        "--dt", type=float, default=0.1, help="simulated time between cycles [s] (default 0.1: a 10 Hz controller)"
    )
    p.add_argument(
        "--scene-dt", type=float, default=0.3, metavar="S",
        help="time between the HTML scene's frames [s] (default 0.3; 0 draws every cycle, a larger "
        "file)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--html", type=Path, default=Path("polyhull-demo.html"), help="animated HTML output (default: %(default)s)")
    p.add_argument("--no-html", action="store_true", help="do not write the HTML scene")
    p.add_argument(
        "--plot", type=Path, default=Path("polyhull-demo.png"), metavar="OUT.png", help="timeline plot, PNG (default: %(default)s)"
    )
    p.add_argument("--no-plot", action="store_true", help="do not write the timeline plot")
    p.add_argument(
        "--records", type=Path, default=None, metavar="OUT.json",
        help="also write the timeline records (one JSON object per cycle) to this file",
    )
    p.set_defaults(func=_run)


class TrueDistance:
    """The true distance [m] between a target mesh and the robot's moving links (python-fcl).

    A link is moving when its pose changes with q (checked at two joint vectors inside the
    limits); fixed links (the base) are static solids the monitor does not measure to.
    """

    def __init__(self, robot: Any) -> None:
        from ..distance import RobotDistanceModel

        lower, upper = np.asarray(robot.lower, dtype=np.float64), np.asarray(robot.upper, dtype=np.float64)
        lo = np.where(np.isfinite(lower), lower, -1.0)
        hi = np.where(np.isfinite(upper), upper, 1.0)
        a = robot.link_transforms(lo + 0.3 * (hi - lo))
        b = robot.link_transforms(lo + 0.7 * (hi - lo))
        moving = {name for name in a if not np.allclose(a[name], b[name], atol=1e-9)}
        geometry = robot.link_geometry()
        self._robot = robot
        self._model = RobotDistanceModel({n: m for n, m in geometry.items() if n in moving})

    def __call__(self, q: np.ndarray, target: Any) -> float:
        """Distance [m] from ``target`` (a trimesh in the world frame) to the robot at ``q``."""
        from ..cell import mesh_to_manifold

        return float(
            self._model.distance(self._robot.link_transforms(q), region=mesh_to_manifold(target, "person")).distance
        )


def robot_motion(q0: np.ndarray, lower: np.ndarray, upper: np.ndarray, t: float) -> np.ndarray:
    """A working motion around ``q0`` [rad] at time ``t`` [s], kept inside the joint limits."""
    amp = np.zeros_like(q0)
    amp[: min(3, len(q0))] = [0.8, 0.25, 0.2][: min(3, len(q0))]
    q = q0 + amp * np.sin(2 * np.pi * t / np.array([6.0, 4.0, 5.0] + [1.0] * (len(q0) - 3))[: len(q0)])
    return np.clip(q, lower + 1e-6, upper - 1e-6)


def _walk_ends(zone_min: np.ndarray, robot_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The demo walk's start (a corner of the zone) and goal (1 m in front of the robot)."""
    start = zone_min[:2] + 0.35
    direction = robot_xy - start
    dist = float(np.linalg.norm(direction))
    return start, start + direction / max(dist, 1e-9) * max(dist - 1.0, 0.1)


def walk_speed(zone_min: np.ndarray, robot_xy: np.ndarray, duration: float) -> float:
    """The speed [m/s] of :func:`person_path`'s walk in and back over ``duration`` [s]."""
    start, goal = _walk_ends(zone_min, robot_xy)
    return 2.0 * float(np.linalg.norm(goal - start)) / max(duration, 1e-3)


def person_path(zone_min: np.ndarray, zone_max: np.ndarray, robot_xy: np.ndarray, duration: float) -> object:
    """A walk from a corner of the zone to 1 m in front of the robot and back."""
    from ..person import PersonTrack

    start, goal = _walk_ends(zone_min, robot_xy)
    speed = walk_speed(zone_min, robot_xy, duration)
    half = duration / 2.0
    walk_in = PersonTrack(start=tuple(start), end=tuple(goal), speed=speed, floor_z=float(zone_min[2]))
    walk_out = PersonTrack(start=tuple(goal), end=tuple(start), speed=speed, t0=half, floor_z=float(zone_min[2]))
    return lambda t: walk_in.mesh(t) if t < half else walk_out.mesh(t)


WALK_SHARE = 0.75
"""Share of the demo's run during which the person is in the cell (then they have left)."""

FAST_WALK = 2.0
"""ISO 13855's approach speed [m/s]: a demo walk faster than this is warned about."""

FULL_SPEED = 0.95
"""A speed scale at least this is called full speed in the behaviour line."""


def behaviour(records: list[dict[str, Any]]) -> str:
    """The run's speed phases in words, e.g. ``full speed 0.0-0.6 s, slower 0.6-1.2 s,
    stop 1.2-2.7 s, full speed 3.6-4.5 s``, from timeline records."""
    phases: list[list[Any]] = []
    for r in records:
        s = r["speed_scale"]
        name = "stop" if s <= 0.0 else "full speed" if s >= FULL_SPEED else "slower"
        if phases and phases[-1][0] == name:
            phases[-1][2] = r["stamp"]
        else:
            phases.append([name, r["stamp"], r["stamp"]])
    return ", ".join(f"{n} {a:.1f}-{b:.1f} s" if b > a else f"{n} at {a:.1f} s" for n, a, b in phases) or "no cycle"


def _run(args: argparse.Namespace) -> int:
    from ..cellfile import default_cell_path, load_cell
    from ..monitor import Monitor
    from ..robot import Robot
    from ..simulator import Simulator
    from ..timeline import plot_timeline, record_of

    if args.cycles < 1:
        raise PolyhullError(f"--cycles must be >= 1, got {args.cycles}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")
    if not (math.isfinite(args.dt) and args.dt > 0):
        raise PolyhullError(f"--dt must be > 0 s, got {args.dt}")
    if not (math.isfinite(args.scene_dt) and args.scene_dt >= 0):
        raise PolyhullError(f"--scene-dt must be >= 0 s, got {args.scene_dt}")
    if not args.no_plot:
        if args.plot.suffix.lower() != ".png":
            raise PolyhullError(f"--plot {args.plot}: the timeline plot is a PNG; give a path ending in .png")
        require_extra("matplotlib", "the demo's timeline plot (or pass --no-plot)", "placement")
    cell_path = args.cell or default_cell_path()
    cell = load_cell(cell_path)
    if cell.robot is None:
        raise PolyhullError(f"{cell_path}: the demo needs a cell with a [robot]")
    recorder_class = None
    if not args.no_html:
        try:
            from polyhull_viewer import DemoRecorder
        except ImportError as exc:
            raise MissingExtraError("the demo's HTML scene (or pass --no-html)", "viewer") from exc
        recorder_class = DemoRecorder
    print(f"polyhull demo: {cell.name} ({len(cell.cameras)} cameras), {counted(args.cycles, 'cycle')}", flush=True)
    t_start = t0 = time.perf_counter()
    robot = Robot.from_spec(cell.robot)
    sim = Simulator(cell, robot=robot)
    monitor = Monitor(cell, references=sim.reference(), robot=robot)
    true_distance = TrueDistance(robot)
    recorder = None if recorder_class is None else recorder_class(cell, robot=robot, static_region=monitor.static.region)
    print(f"precomputed references and static regions in {time.perf_counter() - t0:.1f} s", flush=True)
    q0 = np.asarray(cell.robot.q, dtype=np.float64)
    # The person walks in and back over the first WALK_SHARE of the run, then has left.
    duration = args.cycles * args.dt
    walk_for = WALK_SHARE * duration
    zone_min, robot_xy = np.asarray(cell.zone.min), np.asarray(cell.robot.base[:2])
    person_at = person_path(zone_min, np.asarray(cell.zone.max), robot_xy, walk_for)
    speed = walk_speed(zone_min, robot_xy, walk_for)
    print(f"the person walks in and out at {speed:.2f} m/s over the first {walk_for:.1f} s, then has left", flush=True)
    if speed > FAST_WALK:
        print(
            f"polyhull demo: warning: {speed:.1f} m/s is faster than a person walks ({FAST_WALK:g} m/s, "
            "ISO 13855); give more --cycles or a larger --dt",
            file=sys.stderr, flush=True,
        )
    print("distance: region to robot; true: the person's body to robot (- once gone); speed: 0 stop, 1 full", flush=True)
    records: list[dict[str, Any]] = []
    scene_t: float | None = None  # the last cycle drawn in the HTML scene
    print(f"{'t [s]':>6} {'distance [m]':>12} {'true [m]':>8} {'closest link':>13} {'speed':>6} {'cycle [ms]':>10}  faults")
    for k in range(args.cycles):
        t = k * args.dt
        q = robot_motion(q0, robot.lower, robot.upper, t)
        people = [person_at(t)] if t < walk_for else []  # type: ignore[operator]
        frames = sim.render(q, targets=people, seed=args.seed + k, stamp=t)
        verdict = monitor.step(frames, q, stamp=t)
        record = record_of(verdict, true_distance=true_distance(q, people[0]) if people else None)
        records.append(record)
        ms = record["cycle_ms"] if record["cycle_ms"] is not None else math.nan
        d = "inf" if record["min_distance"] is None else f"{record['min_distance']:.3f}"
        true = "-" if record["true_distance"] is None else f"{record['true_distance']:.3f}"
        faults = "; ".join(verdict.faults) if verdict.faults else "-"
        print(f"{t:6.2f} {d:>12} {true:>8} {verdict.closest_link or '-':>13} {verdict.speed_scale:6.2f} {ms:10.0f}  {faults}", flush=True)
        if recorder is not None and (scene_t is None or t >= scene_t + args.scene_dt - 1e-9):
            recorder.add_cycle(t, q, people, verdict)
            scene_t = t
    cycle_ms = [r["cycle_ms"] for r in records if r["cycle_ms"] is not None]
    finite = [r["min_distance"] for r in records if r["min_distance"] is not None]
    scales = [r["speed_scale"] for r in records]
    above = sum(
        1
        for r in records
        if r["min_distance"] is not None and r["true_distance"] is not None and r["min_distance"] > r["true_distance"] + 1e-6
    )
    print(
        f"summary: min distance {min(finite) if finite else math.inf:.3f} m "
        f"(above the true distance in {above} of {len(records)} cycles), "
        f"speed scale min {min(scales):.2f} / mean {float(np.mean(scales)):.2f}, "
        f"cycle median {float(np.median(cycle_ms)) if cycle_ms else math.nan:.0f} ms "
        f"(max {max(cycle_ms) if cycle_ms else math.nan:.0f} ms)"
    )
    print(f"behaviour: {behaviour(records)}")
    if args.records is not None:
        try:
            args.records.parent.mkdir(parents=True, exist_ok=True)
            args.records.write_text(json.dumps(records, indent=1) + "\n", encoding="utf-8")
        except OSError as exc:
            raise PolyhullError(f"--records {args.records}: cannot write ({exc})") from exc
        print(f"wrote {args.records}")
    if not args.no_plot:
        path = plot_timeline(records, args.plot, title=f"polyhull demo: {cell.name}")
        print(f"wrote {path} (timeline plot)")
    if recorder is not None:
        path = recorder.write_html(args.html)
        print(f"wrote {path} (open it in a browser; no server needed)")
    print(f"demo took {time.perf_counter() - t_start:.0f} s")
    sys.stdout.flush()
    return 0
