"""Replaying a recording through the monitor, at recorded pace or as fast as possible.

:func:`replay` steps a :class:`~polyhull.monitor.Monitor` once per matched cycle and
yields the cycle with its verdict; :func:`cycle_record` turns the pair into one JSON-ready
object without building the verdict's regions (they cost a mesh build each).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any

from .base import Cycle

if TYPE_CHECKING:
    from ..monitor import Monitor, Verdict

__all__ = ["replay", "cycle_record"]


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def cycle_record(cycle: Cycle, verdict: Verdict, cameras: Iterable[str] = ()) -> dict[str, Any]:
    """One cycle as a JSON-ready object (no region is built).

    Keys: ``stamp`` [s], ``cameras`` (names with a frame), ``missing`` (the given
    ``cameras`` without one), ``q`` [rad] and ``q_stamp`` [s] (None when absent),
    ``min_distance`` [m] (None: nothing to measure), ``closest_link``, ``closest_points``
    [m], ``separation_distance`` S_p [m], ``speed_scale`` in [0, 1], ``allowed_speed``
    [m/s], ``faults``, ``warnings``, ``cycle_ms`` (the monitor's total), ``timings_ms`` and
    ``counts``.
    """
    present = sorted(cycle.frames)
    return {
        "stamp": cycle.stamp,
        "cameras": present,
        "missing": [c for c in cameras if c not in cycle.frames],
        "q": None if cycle.q is None else [float(x) for x in cycle.q],
        "q_stamp": cycle.q_stamp,
        "min_distance": _finite(verdict.min_distance),
        "closest_link": verdict.closest_link,
        "closest_points": None if verdict.closest_points is None else verdict.closest_points.tolist(),
        "separation_distance": _finite(verdict.separation_distance),
        "speed_scale": float(verdict.speed_scale),
        "allowed_speed": float(verdict.allowed_speed),
        "faults": list(verdict.faults),
        "warnings": list(verdict.warnings),
        "cycle_ms": float(verdict.timings.get("total", math.nan)),
        "timings_ms": {k: float(v) for k, v in verdict.timings.items()},
        "counts": {k: int(v) for k, v in verdict.counts.items()},
    }


def replay(
    monitor: Monitor,
    cycles: Iterable[Cycle],
    *,
    fast: bool = False,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[tuple[Cycle, Verdict]]:
    """Step ``monitor`` on every cycle, in order.

    Args:
        monitor: The monitor of the recording's cell.
        cycles: The matched cycles (:func:`polyhull.recordings.recording_cycles`).
        fast: As fast as possible; otherwise each cycle is handed to the monitor no earlier
            than its stamp's offset from the first cycle (recorded pace; a slow monitor
            falls behind, it never skips a cycle).
        clock: Monotonic clock [s] (tests give their own).
        sleep: Sleep function [s].
    """
    t_wall0: float | None = None
    t_rec0 = 0.0
    for cycle in cycles:
        if not fast:
            now = clock()
            if t_wall0 is None:
                t_wall0, t_rec0 = now, cycle.stamp
            wait = t_wall0 + (cycle.stamp - t_rec0) - now
            if wait > 0:
                sleep(wait)
        verdict = monitor.step(cycle.frames, cycle.q, stamp=cycle.stamp, q_stamp=cycle.q_stamp)
        yield cycle, verdict
