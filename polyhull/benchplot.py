"""The benchmark's cycles in one picture: where each cycle's time goes, and why.

``polyhull bench --plot OUT.png`` draws the ``cycles`` of its result (one record per timed
cycle, see :func:`polyhull.commands.bench.run_bench`) in two panels over the walk:

- the cycle time [ms] as stacked bars, one colour per engine stage (the two image stages
  in one; what the stages do is in the README's "The engine" section), with the targets' lines: a 10 ms median, and
  the fallback of one frame at 30 Hz, 33 ms;
- the dynamic pieces carved (bars, left axis) and the person's true and reported distance to
  the robot [m] (lines, right axis): the cost follows how much of the images the person
  fills, which grows as they come near the robot.

The plot is matplotlib (the ``placement`` extra).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .errors import MissingExtraError, PolyhullError

__all__ = ["STAGES", "TARGET_MS", "FALLBACK_MS", "plot_stages", "stages_figure"]

STAGES = ("robot_raster", "pixels", "pieces", "memory", "plausibility", "distance")
"""The stages drawn, in the cycle's order; the rest of a cycle (frames, kinematics, speed
and what lies between the stages) is drawn as "other"."""

_BARS = (
    ("images (robot raster, pixel classes)", ("robot_raster", "pixels")),
    ("pieces", ("pieces",)),
    ("shadow memory", ("memory",)),
    ("plausibility", ("plausibility",)),
    ("distance", ("distance",)),
)
"""One bar segment per entry, of these stages' sum. The two image stages share one: each
camera's raster and pixels run as one task on two threads, so the raster stage's time
(until the last raster is done) holds the first cameras' pixel work too."""

TARGET_MS = 10.0
"""The cycle median the engine aims at [ms]."""

FALLBACK_MS = 33.0
"""One frame at 30 Hz [ms]: the cycle median's fallback target."""


def _number(record: Mapping[str, Any], key: str, i: int) -> float:
    value = record.get(key)
    if value is None:
        return math.nan
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PolyhullError(f"bench cycle record {i}: '{key}' must be a number or None, got {value!r}") from None
    return x if math.isfinite(x) else math.nan


def stages_figure(cycles: Sequence[Mapping[str, Any]], *, title: str | None = None) -> Any:
    """The matplotlib ``Figure`` of :func:`plot_stages` (900 x 600 px), not written.

    Each record needs ``total_ms`` and ``stages_ms`` (stage -> ms); ``pieces``,
    ``distance_m`` and ``true_distance_m`` are drawn when present (None: a gap).

    Raises:
        PolyhullError: No record, or a record without ``total_ms`` or ``stages_ms``.
        MissingExtraError: matplotlib is not installed.
    """
    if len(cycles) == 0:
        raise PolyhullError("no bench cycle to plot")
    names = [name for name, _ in _BARS] + ["other"]
    totals: list[float] = []
    parts: dict[str, list[float]] = {name: [] for name in names}
    for i, c in enumerate(cycles):
        stages = c.get("stages_ms")
        total = _number(c, "total_ms", i)
        if not isinstance(stages, Mapping) or math.isnan(total):
            raise PolyhullError(f"bench cycle record {i}: needs 'total_ms' and 'stages_ms' (from polyhull bench --json)")
        drawn = 0.0
        for name, members in _BARS:
            ms = sum(float(stages.get(s) or 0.0) for s in members)
            parts[name].append(ms)
            drawn += ms
        parts["other"].append(max(total - drawn, 0.0))
        totals.append(total)
    pieces = [_number(c, "pieces", i) for i, c in enumerate(cycles)]
    reported = [_number(c, "distance_m", i) for i, c in enumerate(cycles)]
    true = [_number(c, "true_distance_m", i) for i, c in enumerate(cycles)]
    try:
        from matplotlib.figure import Figure
        from matplotlib.ticker import MaxNLocator
    except ImportError as exc:
        raise MissingExtraError("the bench plot", "placement") from exc

    x = list(range(len(cycles)))
    fig = Figure(figsize=(9.0, 6.0), dpi=100)
    ax_t, ax_p = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [1.6, 1.0]})
    bottom = [0.0] * len(x)
    for k, name in enumerate(names):
        colour = "0.75" if name == "other" else f"C{k}"
        ax_t.bar(x, parts[name], bottom=bottom, color=colour, width=0.8, label=name)
        bottom = [b + h for b, h in zip(bottom, parts[name], strict=True)]
    ax_t.axhline(TARGET_MS, color="k", linestyle="--", linewidth=1.0)
    ax_t.axhline(FALLBACK_MS, color="k", linestyle=":", linewidth=1.0)
    right = len(x) - 0.45
    box = {"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.0}
    ax_t.text(right, TARGET_MS, f"target median {TARGET_MS:g} ms", va="bottom", ha="right", fontsize=8, bbox=box)
    ax_t.text(right, FALLBACK_MS, f"one frame at 30 Hz, {FALLBACK_MS:g} ms", va="bottom", ha="right", fontsize=8, bbox=box)
    ax_t.set_ylabel("cycle time [ms]")
    ax_t.set_ylim(0.0, max(max(totals), FALLBACK_MS) * 1.08)
    ax_t.legend(fontsize=8, loc="upper left", ncol=3)

    bars = ax_p.bar(x, [0.0 if math.isnan(p) else p for p in pieces], color="0.6", width=0.8, label="pieces carved")
    ax_p.set_ylabel("dynamic pieces carved")
    ax_p.set_xlabel("timed cycle of the walk")
    ax_d = ax_p.twinx()
    marker = "o" if len(x) <= 60 else None
    lines = []
    if not all(math.isnan(d) for d in true):
        lines += ax_d.plot(x, true, color="k", linestyle="--", marker=marker, ms=3, label="person's true distance")
    lines += ax_d.plot(x, reported, color="C0", marker=marker, ms=3, label="reported distance")
    ax_d.set_ylabel("distance to the robot [m]")
    ax_d.set_ylim(bottom=0.0)
    ax_p.legend([bars, *lines], [bars.get_label(), *(h.get_label() for h in lines)], fontsize=8, loc="upper left")
    for ax in (ax_t, ax_p):
        ax.grid(True, alpha=0.3, axis="y")
        ax.set_xlim(-0.6, len(x) - 0.4)
    ax_p.xaxis.set_major_locator(MaxNLocator(integer=True))
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_stages(cycles: Sequence[Mapping[str, Any]], out: str | Path, *, title: str | None = None) -> Path:
    """Draw the bench's cycles (:func:`stages_figure`) and write a PNG.

    Raises:
        PolyhullError: No record, a record without its times, a path that does not end in
            ``.png``, or a file that cannot be written.
        MissingExtraError: matplotlib is not installed.
    """
    path = Path(out)
    if path.suffix.lower() != ".png":
        raise PolyhullError(f"{path}: the bench plot is written as PNG; give a path ending in .png")
    fig = stages_figure(cycles, title=title)
    try:
        fig.savefig(path, format="png")
    except OSError as exc:
        raise PolyhullError(f"{path}: cannot write the bench plot ({exc})") from exc
    return path
