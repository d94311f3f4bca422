"""``polyhull replay CELL RECORDING [--json-lines OUT] [--fast] [--plot OUT.png] [--html OUT.html]``:
the monitor over a recording."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from ..errors import MissingExtraError, PolyhullError

if TYPE_CHECKING:
    from ..recordings import Cycle

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``replay`` sub-command."""
    p = subparsers.add_parser(
        "replay",
        help="run the monitor over a recording (ROS bag or depth-image folder)",
        description=(
            "Run the monitor of CELL over RECORDING (a ROS bag: .mcap, .db3, .bag or a ROS 2 bag "
            "directory; or a folder of depth images, one sub-folder per camera). The cameras' "
            "frames are matched by time within safety.max_frame_age; the joint state comes from "
            "robot.joint_state_topic or --joints. Runs at recorded pace unless --fast, with a "
            "progress bar, and writes one JSON object per cycle with --json-lines, the timeline plot "
            "(distance, S_p: the protective separation distance of ISO/TS 15066, speed scale, cycle "
            "time, faults) with --plot, and the animated meshcat scene with --html."
        ),
        epilog=(
            "Exit status: 0 when the recording was replayed to its end (or --seconds); a cycle's "
            "faults are reported in its --json-lines record and counted in the summary, not in the "
            "exit status. 2 on bad input (a cell file, a recording or joint-state CSV, including a "
            "recording with no cycle to replay, a flag, or a missing optional extra); 130 when "
            "interrupted (Ctrl-C); 141 when the reader of the output went away (a closed pipe); "
            "1, with a traceback, is a bug in polyhull."
        ),
    )
    p.add_argument("cell", type=Path, help="cell file (TOML)")
    p.add_argument("recording", type=Path, help="ROS bag or folder of depth images")
    p.add_argument("--json-lines", type=Path, metavar="OUT", help="write one JSON object per cycle ('-': stdout)")
    p.add_argument("--fast", action="store_true", help="as fast as possible instead of at recorded pace")
    p.add_argument("--joints", type=Path, metavar="CSV", help="joint states from this CSV instead of the recording")
    p.add_argument("--seconds", type=float, metavar="S", help="replay only the first S seconds of the recording")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="write the timeline plot (PNG, needs matplotlib)")
    p.add_argument(
        "--html",
        type=Path,
        metavar="OUT.html",
        help="write the animated meshcat scene (viewer extra; builds every cycle's region mesh: slow)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary (everything else on stderr)")
    p.set_defaults(func=_run)


def _first_seconds(cycles: Iterator[Cycle], seconds: float) -> Iterator[Cycle]:
    """The cycles within ``seconds`` [s] of the first one."""
    first: float | None = None
    for cycle in cycles:
        first = cycle.stamp if first is None else first
        if cycle.stamp - first > seconds + 1e-6:
            return
        yield cycle


def _run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from ..cellfile import load_cell
    from ..monitor import Monitor
    from ..recordings import open_recording, recording_cycles
    from ..recordings.replay import cycle_record, replay
    from ..timeline import plot_timeline, record_of

    to_stdout = args.json_lines is not None and str(args.json_lines) == "-"
    log = sys.stderr if (args.json or to_stdout) else sys.stdout
    if args.json and to_stdout:
        raise PolyhullError("--json and --json-lines - both want stdout; write the lines to a file")
    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0):
        raise PolyhullError(f"--seconds must be a time > 0 s, got {args.seconds}")
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise PolyhullError(f"--plot {args.plot}: the timeline plot is a PNG; give a path ending in .png")
    cell = load_cell(args.cell)
    recorder_class = None
    if args.html is not None:
        try:
            from polyhull_viewer import DemoRecorder
        except ImportError as exc:
            raise MissingExtraError("replay --html", "viewer") from exc
        recorder_class = DemoRecorder
    recording = open_recording(args.recording, cell, joints_csv=args.joints)
    names = tuple(c.name for c in cell.cameras)
    absent = [n for n in names if n not in recording.cameras]
    if absent:
        print(f"warning: {args.recording} holds no frames of cameras {absent}: every cycle faults them as missing", file=sys.stderr)
    if cell.robot is not None and not recording.has_joints:
        print(f"warning: {args.recording} holds no joint state ({cell.robot.joint_state_topic}): the monitor stops the robot", file=sys.stderr)
    out: IO[str] | None = None
    if args.json_lines is not None:
        if to_stdout:
            out = sys.stdout
        else:
            try:
                args.json_lines.parent.mkdir(parents=True, exist_ok=True)
                out = args.json_lines.open("w", encoding="utf-8")
            except OSError as exc:
                raise PolyhullError(f"--json-lines {args.json_lines}: cannot write ({exc})") from None
    print(f"building the monitor of {cell.name} ...", file=sys.stderr, flush=True)
    monitor = Monitor(cell)
    records: list[dict[str, object]] = []
    recorder = None if recorder_class is None else recorder_class(cell, static_region=monitor.static.region)
    total = recording.frame_count(recording.cameras[0]) if args.seconds is None else None
    distances, scales, cycle_ms = [], [], []
    n_faulted = 0
    first_fault: str | None = None
    t0 = time.perf_counter()
    n = 0
    recorder_last = -math.inf
    try:
        with tqdm(total=total, unit="cycle", desc="replay", file=sys.stderr, disable=None) as bar:
            cycles = recording_cycles(recording, cell)
            if args.seconds is not None:
                cycles = _first_seconds(cycles, args.seconds)
            for cycle, verdict in replay(monitor, cycles, fast=args.fast):
                record = cycle_record(cycle, verdict, names)
                if args.plot is not None:
                    records.append(record_of(verdict))
                if recorder is not None and len(verdict.q) and (
                    recorder.cycle_count == 0 or verdict.stamp > recorder_last
                ):
                    recorder.add_cycle(verdict.stamp, verdict.q, [], verdict)
                    recorder_last = verdict.stamp
                if out is not None:
                    out.write(json.dumps(record) + "\n")
                n += 1
                if record["min_distance"] is not None:
                    distances.append(record["min_distance"])
                scales.append(record["speed_scale"])
                cycle_ms.append(record["cycle_ms"])
                if verdict.faults:
                    n_faulted += 1
                    first_fault = first_fault or verdict.faults[0]
                bar.update()
    finally:
        if out is not None and out is not sys.stdout:
            out.close()
    wall = time.perf_counter() - t0
    if n == 0:
        raise PolyhullError(f"{args.recording}: no cycle to replay (no frames of {recording.cameras[0]})")
    summary: dict[str, Any] = {
        "cycles": n,
        "seconds": wall,
        "cycles_per_second": n / wall if wall > 0 else None,
        "fast": bool(args.fast),
        "min_distance": {"min": min(distances), "median": float(np.median(distances))} if distances else None,
        "speed_scale": {"min": min(scales), "median": float(np.median(scales))},
        "cycle_ms": {"median": float(np.median(cycle_ms)), "max": max(cycle_ms)},
        "faulted_cycles": n_faulted,
        "first_fault": first_fault,
        "json_lines": None if args.json_lines is None else str(args.json_lines),
    }
    written = []
    if args.plot is not None:
        written.append(plot_timeline(records, args.plot, title=f"polyhull replay: {args.recording.name}"))
    if recorder is not None:
        if recorder.cycle_count < 2:
            print("warning: --html needs two cycles with a joint state; no scene written", file=sys.stderr)
        else:
            written.append(recorder.write_html(args.html, title=f"polyhull replay: {args.recording.name}"))
    summary["written"] = [str(p) for p in written]
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    print(f"replayed {n} cycles of {args.recording} in {wall:.1f} s ({n / wall:.1f} cycles/s{', --fast' if args.fast else ''})", file=log)
    if distances:
        print(f"min distance    {min(distances):.3f} m (median {np.median(distances):.3f} m)", file=log)
    print(f"speed scale     min {min(scales):.2f}, median {np.median(scales):.2f}", file=log)
    print(f"cycle           median {np.median(cycle_ms):.0f} ms, max {max(cycle_ms):.0f} ms", file=log)
    if n_faulted:
        print(f"faults          {n_faulted} of {n} cycles (first: {first_fault})", file=log)
    if args.json_lines is not None and not to_stdout:
        print(f"wrote {args.json_lines}", file=log)
    for path in written:
        print(f"wrote {path}", file=log)
    return 0
