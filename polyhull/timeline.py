"""A run's timeline: one small record per cycle, and a plot of them against time.

A record is a plain dict (JSON-ready) made from a verdict without reading its regions, so
making one costs nothing on the controller's loop::

    records = [timeline.record_of(monitor.step(frames, q, stamp=t)) for frames, q, t in run]
    timeline.plot_timeline(records, "timeline.png")

The plot (matplotlib, the ``placement`` extra) has three panels over time [s]: the reported
distance to the robot, the protective separation distance S_p and, when simulated, the
person's true distance (dashed) [m]; the speed scale [0, 1]; the cycle time [ms] (log
scale: the first cycle compiles the engine's kernels). Cycles with faults are marked.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .errors import MissingExtraError, PolyhullError

__all__ = ["RECORD_KEYS", "record_of", "plot_timeline", "timeline_figure"]

# The keys of a record, in the order they are written.
RECORD_KEYS = (
    "stamp",
    "min_distance",
    "separation_distance",
    "speed_scale",
    "closest_link",
    "faults",
    "cycle_ms",
    "true_distance",
)


def _finite_or_none(value: Any) -> float | None:
    x = float(value)
    return x if math.isfinite(x) else None


def record_of(verdict: Any, *, true_distance: float | None = None) -> dict[str, Any]:
    """The timeline record of one verdict (never reads the lazily built regions).

    Args:
        verdict: A :class:`polyhull.verdict.Verdict`.
        true_distance: The true distance of the target to the robot [m], when known
            (a simulation); None otherwise.

    Returns:
        ``{"stamp" [s], "min_distance" [m] (None if inf), "separation_distance" [m] (None
        if inf), "speed_scale" in [0, 1], "closest_link", "faults" (list of str),
        "cycle_ms" (``timings['total']``, None if absent), "true_distance" [m] (None unless
        given or not finite)}``.
    """
    cycle_ms = verdict.timings.get("total")
    return {
        "stamp": float(verdict.stamp),
        "min_distance": _finite_or_none(verdict.min_distance),
        "separation_distance": _finite_or_none(verdict.separation_distance),
        "speed_scale": float(verdict.speed_scale),
        "closest_link": verdict.closest_link,
        "faults": [str(f) for f in verdict.faults],
        "cycle_ms": None if cycle_ms is None else float(cycle_ms),
        "true_distance": None if true_distance is None else _finite_or_none(true_distance),
    }


def _column(records: Sequence[Mapping[str, Any]], key: str, *, required: bool) -> list[float]:
    """One key of every record as floats (None and missing optional keys are NaN)."""
    out = []
    for i, record in enumerate(records):
        if key not in record:
            if required:
                raise PolyhullError(
                    f"timeline record {i}: the key '{key}' is missing (a record has "
                    f"{', '.join(RECORD_KEYS)}; make it with polyhull.timeline.record_of)"
                )
            out.append(math.nan)
            continue
        value = record[key]
        if value is None:
            out.append(math.nan)
            continue
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise PolyhullError(
                f"timeline record {i}: '{key}' must be a number or None, got {value!r}"
            ) from None
        out.append(x if math.isfinite(x) else math.nan)
    return out


def plot_timeline(
    records: Sequence[Mapping[str, Any]], out: str | Path, *, title: str | None = None
) -> Path:
    """Plot the records of a run against time and write a PNG.

    Args:
        records: Timeline records (:func:`record_of`), in time order.
        out: The PNG file to write (parent directories are created).
        title: The plot's title.

    Returns:
        The path written.

    Raises:
        PolyhullError: No record, a record without a stamp or with a value that is not a
            number, a path that does not end in ``.png``, or a file that cannot be written.
        MissingExtraError: matplotlib is not installed.
    """
    path = Path(out)
    if path.suffix.lower() != ".png":
        raise PolyhullError(f"{path}: the timeline plot is written as PNG; give a path ending in .png")
    if len(records) == 0:
        raise PolyhullError(f"{path}: no timeline record to plot (the run has no cycle)")
    fig = timeline_figure(records, title=title)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, format="png")
    except OSError as exc:
        raise PolyhullError(f"{path}: cannot write the timeline plot ({exc})") from exc
    return path


def timeline_figure(records: Sequence[Mapping[str, Any]], *, title: str | None = None) -> Any:
    """The matplotlib ``Figure`` of :func:`plot_timeline` (800 x 560 px), not written.

    Its three axes, top to bottom: distances [m] (lines labelled "distance to the robot",
    "protective separation S_p" and, dashed, "true distance (simulated)"), the speed scale
    (faults marked "fault") and the cycle time [ms]. Records without a value leave gaps.
    """
    if len(records) == 0:
        raise PolyhullError("no timeline record to plot (the run has no cycle)")
    stamps = _column(records, "stamp", required=True)
    if any(math.isnan(t) for t in stamps):
        raise PolyhullError("timeline records: every 'stamp' must be a finite time [s]")
    # time since the first cycle: recorded stamps are often seconds since 1970
    t_first = float(stamps[0])
    stamps = [t - t_first for t in stamps]
    distance = _column(records, "min_distance", required=True)
    separation = _column(records, "separation_distance", required=False)
    true = _column(records, "true_distance", required=False)
    speed = _column(records, "speed_scale", required=True)
    cycle_ms = _column(records, "cycle_ms", required=False)
    faulted = [bool(r.get("faults")) for r in records]
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise MissingExtraError("the timeline plot", "placement") from exc

    # A Figure without pyplot: no global backend or state is touched (Agg renders the PNG).
    fig = Figure(figsize=(8.0, 5.6), dpi=100)
    ax_d, ax_s, ax_c = fig.subplots(
        3, 1, sharex=True, gridspec_kw={"height_ratios": [2.2, 1.0, 1.0]}
    )
    marker = "o" if len(records) <= 60 else None
    ax_d.plot(stamps, distance, color="C0", marker=marker, ms=3, label="distance to the robot")
    if not all(math.isnan(x) for x in separation):
        ax_d.plot(stamps, separation, color="C3", marker=marker, ms=3, label="protective separation S_p")
    if not all(math.isnan(x) for x in true):
        ax_d.plot(stamps, true, color="k", linestyle="--", label="true distance (simulated)")
    ax_d.set_ylabel("distance [m]")
    ax_d.set_ylim(bottom=0.0)
    ax_d.legend(fontsize=8, loc="upper right")

    ax_s.step(stamps, speed, where="post", color="C2", label="speed scale")
    ax_s.set_ylim(-0.05, 1.05)
    ax_s.set_ylabel("speed scale")
    fault_t = [t for t, f in zip(stamps, faulted, strict=True) if f]
    if fault_t:
        ax_s.plot(fault_t, [0.0] * len(fault_t), "x", color="C3", ms=8, mew=2, label="fault")
        ax_s.legend(fontsize=8, loc="upper right")

    finite_ms = [x for x in cycle_ms if not math.isnan(x) and x > 0]
    ax_c.plot(stamps, cycle_ms, color="C4", marker=marker, ms=3, label="cycle time")
    if finite_ms:
        from matplotlib.ticker import FuncFormatter, LogLocator

        ax_c.set_yscale("log")
        # plain numbers (20, 50, 100), not powers of ten with minor-tick labels
        ax_c.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax_c.yaxis.set_minor_formatter(FuncFormatter(lambda y, _: ""))
        ax_c.yaxis.set_major_formatter(FuncFormatter(lambda y, _: f"{y:g}"))
    ax_c.set_ylabel("cycle [ms]")
    ax_c.set_xlabel("time since the first cycle [s]" if t_first != 0.0 else "time [s]")
    for ax in (ax_d, ax_s, ax_c):
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
