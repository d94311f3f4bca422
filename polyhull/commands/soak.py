"""``polyhull soak``: the reference workload for many cycles, watching memory and faults.

The workload is ``polyhull bench``'s (the default cell, the robot in motion, one walking
person, default sensor effects). A small ring of frame sets is rendered once; the cycles
replay it forth and back (0, 1, ..., R-1, R-2, ..., 1, 0, 1, ...) so that the robot and the
person move without jumps, each frame stamped anew with the cycle's time (strictly
increasing, as the monitor requires). After ``warmup`` cycles, memory is sampled every
cycle into arrays allocated before the run (the soak itself allocates nothing that lasts);
each figure's growth per 1,000 cycles is the least-squares slope over the measured cycles.

Two figures, because they answer different questions:

- **heap in use** (glibc ``mallinfo2()``: ``uordblks`` + ``hblkhd``, the bytes of every live
  ``malloc`` block, mmapped ones included): what the engine and its C/C++ libraries (numpy
  data, manifold3d, python-fcl, numba) hold. Memory counts as flat when its slope stays under
  ``GROWTH_LIMIT_MB``. This is the figure that grows without bound when something leaks.
- **resident set size** (RSS), reported alongside: heap in use plus what glibc keeps after
  ``free`` (its arenas grow by fragmentation, in steps of 0.1 to 2 MB, and return memory to
  the system only from their top) plus Python's own small-object arenas and the code; it
  depends on how the threads' allocations interleave, so it varies from run to run.

Measured on the reference workload (2-core machine shared with other runs, warm-up 300,
then 500 to 2,700 cycles). The heap in use grows a steady 0.045 MB per 1,000 cycles; it is
python-fcl's (0.7.0.11) leak: ``CollisionObject.__dealloc__`` releases its C++ object with
``free()`` instead of ``delete``, so the destructor never runs and the ``shared_ptr`` control
block of its geometry (32 bytes) stays allocated, once for every ``CollisionObject`` ever
made; ``polyhull.distance`` makes 1.35 a cycle for the dynamic region's BVHs (0.043 MB per
1,000 cycles), and python-fcl's API cannot give an existing object new geometry. Before
``StaticModel.boxes_meet`` became a compiled test it made 15.4 python-fcl boxes a cycle
besides, and the heap in use grew 0.60 MB per 1,000 cycles (0.57 to 0.62 in every 500-cycle
window of a 3,000-cycle run; with those boxes reusing one object, on a copy of that engine,
0.11), while the RSS grew 0.8 to 6 MB per 1,000 cycles from run to run: the RSS alone could
not tell that leak from the allocator. The rest of the RSS growth is memory glibc keeps after
``free``, and it levels off: in 2,700 measured cycles the RSS grew 2.1 MB per 1,000 cycles over
the first 500, then 0.45, 0.28, 0.41 and 0, and glibc's free bytes stayed between 19.4 and
20.8 MB; ``malloc_trim(0)`` every 10 cycles took the RSS down by 8 to 17 MB each time, and
``MALLOC_ARENA_MAX=1`` (no per-thread arenas) changed neither figure. Python's
allocated-block count rose by ~2 blocks a cycle and stopped rising after ~2,000 cycles.

Without glibc's ``mallinfo2`` (other C libraries) the heap is not measured and the verdict
falls back to the RSS slope against ``RSS_GROWTH_LIMIT_MB``, saying so.

The default warm-up is ``DEFAULT_WARMUP`` cycles: on the reference workload the RSS steps up
by ~17 MB between cycles 100 and 250 (allocator pools and the engine's bounded caches
filling) and then stays on a plateau, so a shorter warm-up measures the filling, not a leak.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import math
import os
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import PolyhullError

__all__ = [
    "register",
    "run_soak",
    "ring_order",
    "growth_per_1000",
    "heap_reader",
    "HeapSample",
    "GROWTH_LIMIT_MB",
    "RSS_GROWTH_LIMIT_MB",
    "DEFAULT_WARMUP",
]

GROWTH_LIMIT_MB = 0.25
"""Largest growth of the heap in use [MB per 1,000 cycles] after the warm-up that counts as
flat (~260 bytes a cycle). It is what a 500-cycle run tells from noise (the slope varies by
~0.03 MB between 500-cycle windows of one run, ~0.05 between runs under load), not a
budget: at 10 Hz it is still 9 MB an hour."""

RSS_GROWTH_LIMIT_MB = 1.0
"""Largest RSS growth [MB per 1,000 cycles] that counts as flat where the heap cannot be
measured (no glibc ``mallinfo2``); the RSS also holds what the allocator keeps after free."""

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
            "frame sets rendered once (restamped every cycle). Reports the heap in use (glibc "
            "mallinfo2: live malloc blocks) and the RSS after the warm-up and at the end, their "
            "growth per 1,000 cycles (least-squares slope over the measured cycles), the cycle "
            "time p50/p99/max and every fault raised. Exits 1 when the heap in use grows "
            f"{GROWTH_LIMIT_MB:g} MB per 1,000 cycles or more (a leak; the RSS also holds what "
            "the allocator keeps after free), or, without glibc, when the RSS grows "
            f"{RSS_GROWTH_LIMIT_MB:g} MB per 1,000 cycles or more."
        ),
    )
    p.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    p.add_argument(
        "--cycles", type=int, default=500, help="measured cycles after the warm-up, at least 2 (default 500)"
    )
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


class _MallInfo2(ctypes.Structure):
    _fields_ = [  # glibc's struct mallinfo2
        (name, ctypes.c_size_t)
        for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost"
        )
    ]


class HeapSample(NamedTuple):
    """glibc's heap at one instant (``mallinfo2()``, all arenas).

    Attributes:
        in_use: Bytes in live ``malloc`` blocks, mmapped ones included (uordblks + hblkhd).
        held: Bytes the allocator holds from the system (arena + hblkhd): in use plus free.
    """

    in_use: int
    held: int


def heap_reader() -> Callable[[], HeapSample] | None:
    """A function sampling glibc's heap (see :class:`HeapSample`), None without glibc 2.33+."""
    try:
        libc = ctypes.CDLL(None)
        mallinfo2 = libc.mallinfo2
    except (OSError, AttributeError):
        return None
    mallinfo2.restype = _MallInfo2
    mallinfo2.argtypes = []

    def sample() -> HeapSample:
        m = mallinfo2()
        return HeapSample(int(m.uordblks + m.hblkhd), int(m.arena + m.hblkhd))

    return sample


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
    heap: Callable[[], HeapSample] | None | bool = True,
) -> dict[str, Any]:
    """Run the soak; return its figures (see the module docstring).

    Args:
        heap: True: sample glibc's heap when available; None or False: do not (the verdict
            is then the RSS's); or a function sampling it.

    Raises:
        PolyhullError: a cell without a robot or cameras, or RSS not readable.
    """
    from ..cellfile import default_cell_path, load_cell
    from ..monitor import Monitor
    from ..simulator import Simulator
    from .bench import DT, _progress, _walk
    from .demo import robot_motion

    rss = rss_reader()
    heap_sample = heap_reader() if heap is True else (heap or None)
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
    # every measured cycle's figures go into arrays made now: nothing the soak keeps grows
    times_ms = np.zeros(cycles)
    scales = np.zeros(cycles)
    mem = np.zeros((cycles, 3), dtype=np.int64)  # RSS, heap in use, heap held [bytes]
    faults: Counter[str] = Counter()
    first_fault: dict[str, int] = {}
    warnings: Counter[str] = Counter()  # by kind (the text before its first ':')
    warning_last: dict[str, str] = {}
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
                k = i - warmup
                times_ms[k] = ms
                scales[k] = v.speed_scale
                mem[k, 0] = rss()
                if heap_sample is not None:
                    mem[k, 1:] = heap_sample()
            elif i == warmup - 1:
                bar.set_postfix_str("measuring")
            bar.update()

    measured = list(range(warmup, total))
    trace_at = sorted({*range(0, cycles, TRACE_EVERY), cycles - 1})

    def figures(col: int) -> dict[str, Any]:
        x = mem[:, col]
        return {
            "start": x[0] / MB,
            "end": x[-1] / MB,
            "max": x.max() / MB,
            "end_minus_start": (x[-1] - x[0]) / MB,
            "growth_per_1000_cycles": growth_per_1000(measured, x.tolist()),
        }

    rss_mb = figures(0)
    rss_mb["trace"] = [[measured[k], mem[k, 0] / MB] for k in trace_at]
    heap_mb: dict[str, Any] | None = None
    if heap_sample is not None:
        heap_mb = {
            "in_use": figures(1),
            "held": figures(2),
            "trace": [[measured[k], mem[k, 1] / MB, mem[k, 2] / MB] for k in trace_at],
        }
        judged, growth, limit = "heap in use", heap_mb["in_use"]["growth_per_1000_cycles"], GROWTH_LIMIT_MB
    else:
        judged, growth, limit = "RSS", rss_mb["growth_per_1000_cycles"], RSS_GROWTH_LIMIT_MB
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
        "rss_mb": rss_mb,
        "heap_mb": heap_mb,
        "judged": judged,
        "growth_mb_per_1000_cycles": growth,
        "growth_limit_mb_per_1000_cycles": limit,
        "memory_flat": bool(math.isfinite(growth) and growth < limit),
        "cycle_ms": {
            "p50": float(np.percentile(times_ms, 50)),
            "p99": float(np.percentile(times_ms, 99)),
            "max": float(times_ms.max()),
        },
        "speed_scale": {"median": float(np.median(scales)), "min": float(scales.min())},
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
    growth, limit = result["growth_mb_per_1000_cycles"], result["growth_limit_mb_per_1000_cycles"]
    limit_line = (
        f"polyhull soak: memory not flat: the {result['judged']} grew {growth:.3f} MB per 1,000 cycles "
        f"after the warm-up (limit {limit:g})"
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
    h = result["heap_mb"]
    if h is not None:
        u, held = h["in_use"], h["held"]
        print(f"heap in use: {u['start']:.1f} MB after the warm-up, {u['end']:.1f} MB at the end; "
              f"growth {u['growth_per_1000_cycles']:.3f} MB per 1,000 cycles (limit {limit:g})")
        print(f"heap held (in use + free kept by malloc): {held['start']:.1f} -> {held['end']:.1f} MB; "
              f"growth {held['growth_per_1000_cycles']:.3f} MB per 1,000 cycles")
    else:
        print("heap in use: not measured (no glibc mallinfo2); judging the RSS", file=sys.stderr)
    rss_limit = f" (limit {limit:g})" if h is None else ""
    print(f"RSS: {r['start']:.1f} MB after the warm-up, {r['end']:.1f} MB at the end (max {r['max']:.1f}); "
          f"growth {r['growth_per_1000_cycles']:.3f} MB per 1,000 cycles{rss_limit}")
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
