"""``polyhull soak``: the reference workload for many cycles, watching memory and faults.

The workload is ``polyhull bench``'s (the default cell, the robot in motion, one walking
person, default sensor effects). A small ring of frame sets is rendered once; the cycles
replay it forth and back (0, 1, ..., R-1, R-2, ..., 1, 0, 1, ...) so that the robot and the
person move without jumps, each frame stamped anew with the cycle's time (strictly
increasing, as the monitor requires). After ``warmup`` cycles, the resident set size (RSS)
is sampled every cycle; its growth per 1,000 cycles is the least-squares slope over the
measured cycles. Memory counts as flat when that slope stays under ``GROWTH_LIMIT_MB``.

The default warm-up is ``DEFAULT_WARMUP`` cycles: on the reference workload the RSS steps up
by ~17 MB between cycles 100 and 250 (allocator pools and the engine's bounded caches
filling) and then stays on a plateau, so a shorter warm-up measures the filling, not a leak.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import PolyhullError

__all__ = ["register", "run_soak", "ring_order", "growth_per_1000", "GROWTH_LIMIT_MB", "DEFAULT_WARMUP"]

GROWTH_LIMIT_MB = 1.0
"""Largest RSS growth [MB per 1,000 cycles] after the warm-up that counts as flat."""

DEFAULT_WARMUP = 300
"""Cycles run before the measurement (see the module docstring)."""

TRACE_EVERY = 50
"""The JSON's RSS trace holds one sample every this many measured cycles."""

MB = 1024.0 * 1024.0
MAX_RING = 1000


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``soak`` sub-command."""
    p = subparsers.add_parser(
        "soak",
        help="run the reference workload for many cycles; check that memory stays flat",
        description=(
            "Run the benchmark's reference workload (the default cell, the robot in motion, one "
            "walking person, default sensor effects) for many cycles, replaying a small ring of "
            "frame sets rendered once (restamped every cycle). Reports the RSS after the warm-up "
            "and at the end, its growth per 1,000 cycles (least-squares slope over the measured "
            "cycles), the cycle time p50/p99/max and every fault raised. Exits 1 when the growth "
            f"is {GROWTH_LIMIT_MB:g} MB per 1,000 cycles or more."
        ),
    )
    p.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    p.add_argument("--cycles", type=int, default=500, help="measured cycles after the warm-up (default 500)")
    p.add_argument(
        "--warmup",
        type=int,
        default=DEFAULT_WARMUP,
        help=f"cycles run first, not measured (default {DEFAULT_WARMUP}: the RSS reaches its plateau)",
    )
    p.add_argument(
        "--ring", type=int, default=20, help=f"frame sets rendered once and replayed (2..{MAX_RING}; default 20)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor effects (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object and nothing else")
    p.set_defaults(func=_run)


# -- the parts -----------------------------------------------------------------------------
def ring_order(ring: int, cycle: int) -> int:
    """Index into a ring of ``ring`` frame sets replayed forth and back, at ``cycle``."""
    period = 2 * (ring - 1)
    k = cycle % period
    return k if k < ring else period - k


def rss_reader() -> Callable[[], int]:
    """A function returning this process's resident set size [bytes].

    psutil when installed, else ``/proc/self/statm`` (Linux); PolyhullError when neither.
    """
    try:
        import psutil
    except ImportError:
        pass
    else:
        proc = psutil.Process()
        return lambda: int(proc.memory_info().rss)
    statm = Path("/proc/self/statm")
    if not statm.exists():
        raise PolyhullError("soak: cannot read the resident set size: install psutil (pip install psutil)")
    page = os.sysconf("SC_PAGE_SIZE")
    return lambda: int(statm.read_text().split()[1]) * page


def growth_per_1000(cycles: Sequence[int], rss: Sequence[int]) -> float:
    """Least-squares slope of ``rss`` [bytes] over ``cycles``, in MB per 1,000 cycles."""
    if len(cycles) < 2:
        return math.nan
    slope = np.polyfit(np.asarray(cycles, dtype=np.float64), np.asarray(rss, dtype=np.float64) / MB, 1)[0]
    return float(slope) * 1000.0


def run_soak(
    cell_path: Path | None = None,
    cycles: int = 500,
    warmup: int = DEFAULT_WARMUP,
    ring: int = 20,
    seed: int = 0,
    progress: bool = False,
) -> dict[str, Any]:
    """Run the soak; return its figures (see the module docstring).

    Raises:
        PolyhullError: a cell without a robot or cameras, or RSS not readable.
    """
    from ..cellfile import default_cell_path, load_cell
    from ..monitor import Monitor
    from ..simulator import Simulator
    from .bench import DT, _progress, _walk
    from .demo import robot_motion

    rss = rss_reader()
    path = cell_path or default_cell_path()
    cell = load_cell(path)
    if cell.robot is None:
        raise PolyhullError(f"{path}: the soak needs a cell with a [robot]")
    if not cell.cameras:
        raise PolyhullError(f"{path}: the soak needs a cell with cameras")
    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    robot = monitor.robot
    assert robot is not None  # the cell has a robot
    q0 = np.asarray(cell.robot.q, dtype=np.float64)
    person_at = _walk(cell)

    frame_sets = []
    with _progress(ring, "rendering", progress) as bar:
        for k in range(ring):
            t = k * DT
            q = robot_motion(q0, robot.lower, robot.upper, t)
            frame_sets.append((sim.render(q, targets=[person_at(t)], seed=seed + k), q))
            bar.update()

    total = warmup + cycles
    times_ms: list[float] = []
    samples_cycle: list[int] = []
    samples_rss: list[int] = []
    faults: Counter[str] = Counter()
    first_fault: dict[str, int] = {}
    warnings: Counter[str] = Counter()  # by kind (the text before its first ':')
    warning_last: dict[str, str] = {}
    scales: list[float] = []
    with _progress(total, "soak", progress) as bar:
        for i in range(total):
            t = i * DT
            frames, q = frame_sets[ring_order(ring, i)]
            stamped = {name: replace(f, stamp=t, seq=i) for name, f in frames.items()}
            t0 = time.perf_counter()
            v = monitor.step(stamped, q, stamp=t)
            ms = (time.perf_counter() - t0) * 1e3
            for f in v.faults:
                faults[f] += 1
                first_fault.setdefault(f, i)
            for w in v.warnings:
                kind = w.split(":", 1)[0]
                warnings[kind] += 1
                warning_last[kind] = w
            if i >= warmup:
                times_ms.append(ms)
                scales.append(v.speed_scale)
                samples_cycle.append(i)
                samples_rss.append(rss())
            elif i == warmup - 1:
                bar.set_postfix_str("measuring")
            bar.update()

    growth = growth_per_1000(samples_cycle, samples_rss)
    ms_arr = np.asarray(times_ms)
    start, end = samples_rss[0], samples_rss[-1]
    return {
        "workload": {
            "cell": str(path),
            "cameras": len(cell.cameras),
            "ring": ring,
            "cycles": cycles,
            "warmup": warmup,
            "dt_s": DT,
            "seed": seed,
            "replay": "the ring forth and back, every frame restamped with the cycle's time",
        },
        "rss_mb": {
            "start": start / MB,
            "end": end / MB,
            "max": max(samples_rss) / MB,
            "end_minus_start": (end - start) / MB,
            "trace": [
                [c, r / MB] for k, (c, r) in enumerate(zip(samples_cycle, samples_rss, strict=True))
                if k % TRACE_EVERY == 0 or k == len(samples_rss) - 1
            ],
        },
        "growth_mb_per_1000_cycles": growth,
        "growth_limit_mb_per_1000_cycles": GROWTH_LIMIT_MB,
        "memory_flat": bool(math.isfinite(growth) and growth < GROWTH_LIMIT_MB),
        "cycle_ms": {
            "p50": float(np.percentile(ms_arr, 50)),
            "p99": float(np.percentile(ms_arr, 99)),
            "max": float(ms_arr.max()),
        },
        "speed_scale": {"median": float(np.median(scales)), "min": float(min(scales))},
        "faults": [{"fault": f, "cycles": n, "first_cycle": first_fault[f]} for f, n in faults.most_common()],
        "warnings": [
            {"warning": w, "cycles": n, "last": warning_last[w]} for w, n in warnings.most_common()
        ],
    }


# -- the command ---------------------------------------------------------------------------
def _check(args: argparse.Namespace) -> None:
    if args.cycles < 2:
        raise PolyhullError(f"--cycles must be >= 2 (the growth is a slope), got {args.cycles}")
    if args.warmup < 0:
        raise PolyhullError(f"--warmup must be >= 0, got {args.warmup}")
    if not 2 <= args.ring <= MAX_RING:
        raise PolyhullError(f"--ring must be in 2..{MAX_RING} frame sets, got {args.ring}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")


def _run(args: argparse.Namespace) -> int:
    _check(args)
    # anything the engine prints goes to stderr: with --json, stdout holds the object only
    with contextlib.redirect_stdout(sys.stderr):
        result = run_soak(args.cell, args.cycles, args.warmup, args.ring, args.seed, progress=True)
    growth = result["growth_mb_per_1000_cycles"]
    limit_line = (
        f"polyhull soak: memory not flat: RSS grew {growth:.3f} MB per 1,000 cycles after the warm-up "
        f"(limit {GROWTH_LIMIT_MB:g})"
    )
    if args.json:
        from .bench import _finite

        print(json.dumps(_finite(result), indent=2))
        if not result["memory_flat"]:
            print(limit_line, file=sys.stderr)
        return 0 if result["memory_flat"] else 1
    w, r, c = result["workload"], result["rss_mb"], result["cycle_ms"]
    print(f"polyhull soak: {w['cameras']} cameras, {w['cycles']} cycles after {w['warmup']} warm-up, "
          f"ring of {w['ring']} frame sets")
    print(f"RSS: {r['start']:.1f} MB after the warm-up, {r['end']:.1f} MB at the end (max {r['max']:.1f}); "
          f"growth {growth:.3f} MB per 1,000 cycles (limit {GROWTH_LIMIT_MB:g})")
    print(f"cycle [ms]: p50 {c['p50']:.1f}, p99 {c['p99']:.1f}, max {c['max']:.1f}")
    s = result["speed_scale"]
    print(f"speed scale: median {s['median']:.2f}, min {s['min']:.2f}")
    if result["faults"]:
        print("faults (cycles with it, first cycle):")
        for f in result["faults"]:
            print(f"  {f['cycles']:6d}  from {f['first_cycle']:6d}  {f['fault']}")
    else:
        print("faults: none")
    for wn in result["warnings"]:
        print(f"warning in {wn['cycles']} cycles: {wn['warning']} (last: {wn['last']})")
    if not result["memory_flat"]:
        print(limit_line, file=sys.stderr)
        return 1
    return 0
