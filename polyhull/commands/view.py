"""``polyhull view CELL [--frames F.npz] [--html OUT.html]``: look at a cell in meshcat.

With ``--html`` the scene is written as a standalone HTML file (it opens from disk, no
server) and the command exits. Without it, a meshcat server starts, its URL is printed, and
the command serves until Ctrl-C, then stops the server. It never waits for a browser.

With ``--frames`` the recorded frames are drawn as point clouds (hidden at first), and the
monitor runs one cycle on them: the region R (its dynamic part saturated, the part no
camera read, a dropout patch's rays, pale, its static part faint near the robot), the
closest-distance segment and its label are shown; the cameras'
regions C(i), the hull C, the robot occlusion M and the removed components are drawn
hidden, each switched on in meshcat's controls.

The viewer is an optional extra (``polyhull_viewer``); it is imported only when this
command runs.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ..errors import MissingExtraError, PolyhullError

SIGNAL_POLL_S = 0.2
"""[s] The longest the server waits before it acts on Ctrl-C or SIGTERM (see :func:`_serve`)."""

__all__ = ["register"]


def register(subparsers: Any) -> None:
    """Add the ``view`` sub-command to ``subparsers``."""
    p = subparsers.add_parser(
        "view",
        help="inspect a cell, its frames and the monitor's regions in meshcat",
        description=(
            "Draw a cell (zone, obstacles, robot, camera frustums) in meshcat. With --frames, "
            "also run the monitor once: the region R (what moved in a saturated red, a "
            "dropout patch's rays no camera read in pale pink, the static blind space as a "
            "faint tint near the robot) and the closest distance are "
            "shown; the point clouds, C(i) (each camera's occluded region: the zone it does not "
            "see free), C (the depth hull), M (the robot occlusion) and the removed parts are "
            "drawn hidden (toggle them in meshcat's 'Open Controls'). With --html, write a standalone "
            "HTML file and exit; otherwise serve the scene until Ctrl-C."
        ),
    )
    p.add_argument("cell", type=Path, metavar="CELL", help="cell file (.toml)")
    p.add_argument(
        "--frames",
        type=Path,
        metavar="F.npz",
        help="frames file: one depth array per camera, q and stamp",
    )
    p.add_argument(
        "--html",
        type=Path,
        metavar="OUT.html",
        help="write a standalone HTML scene to this file and exit (no server)",
    )
    p.add_argument(
        "--max-points",
        type=int,
        default=5_000,
        metavar="N",
        help="most points drawn per camera frame, inside the zone (default: %(default)s)",
    )
    # For tests: serve this many seconds, then stop as if Ctrl-C had been pressed.
    p.add_argument("--serve-seconds", type=float, default=None, help=argparse.SUPPRESS)
    p.set_defaults(func=_run)


def _import_viewer() -> Any:
    try:
        import polyhull_viewer
    except ImportError as exc:
        raise MissingExtraError("the viewer", "viewer") from exc
    return polyhull_viewer


def _run(args: argparse.Namespace) -> int:
    from ..cellfile import load_cell
    from ..frames import check_cameras, load_frames

    if args.max_points < 1:
        raise PolyhullError(f"--max-points must be >= 1, got {args.max_points}")
    if args.serve_seconds is not None and not args.serve_seconds >= 0:
        raise PolyhullError(f"--serve-seconds must be >= 0, got {args.serve_seconds}")
    pv = _import_viewer()
    cell = load_cell(args.cell)

    frames = verdict = camera_regions = static_region = None
    q = None
    if args.frames is not None:
        recorded = load_frames(args.frames)
        check_cameras(args.frames, recorded, (c.name for c in cell.cameras))
        frames, q = recorded.frames, recorded.q
        try:
            from ..monitor import Monitor
        except ImportError as exc:
            print(
                f"polyhull view: the monitor is not available ({exc}); drawing the frames "
                "as point clouds only",
                file=sys.stderr,
            )
        else:
            monitor = Monitor(cell)
            verdict = monitor.step(frames, q, stamp=recorded.stamp)
            camera_regions = monitor.camera_regions(frames)
            static_region = monitor.static.region
            _report(verdict)

    def draw(vis: Any) -> None:
        if verdict is not None:
            print(
                "polyhull view: building the hull C and the robot occlusion M for their hidden "
                "layers (manifold booleans: seconds to a minute)",
                file=sys.stderr,
                flush=True,
            )
        pv.draw_scene(
            vis,
            cell,
            q=q,
            frames=frames,
            verdict=verdict,
            camera_regions=camera_regions,
            static_region=static_region,
            max_points=args.max_points,
        )

    if args.html is not None:
        vis = pv.StaticVisualizer()
        draw(vis)
        out = pv.write_html(vis, args.html, title=f"polyhull: {cell.name}")
        print(f"polyhull view: wrote {out} (open it in a browser; no server needed)")
        return 0

    # SIGTERM is handled like Ctrl-C from before the server starts (a signal sent as soon as
    # the URL is printed must not find the default handler).
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _raise_interrupt) if in_main else None
    try:
        with pv.LiveViewer() as live:
            draw(live.vis)
            print(f"polyhull view: serving {cell.name!r} at {live.url} (Ctrl-C to stop)", flush=True)
            _serve(args.serve_seconds)
    except KeyboardInterrupt:
        pass
    finally:
        if in_main:
            signal.signal(signal.SIGTERM, previous)
    print("polyhull view: server stopped", flush=True)
    return 0


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _serve(seconds: float | None) -> None:
    """Sleep until Ctrl-C or SIGTERM (or for ``seconds`` [s]); the caller closes the server.

    The caller handles SIGTERM like Ctrl-C so that ``kill`` also stops the meshcat server,
    which runs in its own session and would otherwise outlive this process.

    It sleeps in short slices: the kernel may deliver the signal to another thread that does
    not block it (one of the ZeroMQ context's I/O threads; macOS does, Linux prefers the main
    thread), which sets Python's flag without interrupting the main thread's sleep, and the
    handler (KeyboardInterrupt) runs only when the main thread next runs Python code: after
    up to an hour with one long sleep.

    A process started with SIGINT ignored (in the background by a shell without job
    control) keeps ignoring Ctrl-C, as POSIX asks; SIGTERM still stops it.
    """
    end = math.inf if seconds is None else time.monotonic() + seconds
    try:
        while (left := end - time.monotonic()) > 0:
            time.sleep(min(left, SIGNAL_POLL_S))
    except KeyboardInterrupt:
        pass


def _report(verdict: Any) -> None:
    """One line about the verdict: distance, closest link, speed scale, faults."""
    distance = verdict.min_distance
    text = f"{distance:.3f} m" if distance != float("inf") else "inf (no region)"
    link = f" to {verdict.closest_link}" if verdict.closest_link else ""
    faults = "; faults: " + ", ".join(verdict.faults) if verdict.faults else ""
    print(f"polyhull view: distance {text}{link}, speed scale {verdict.speed_scale:.2f}{faults}")
