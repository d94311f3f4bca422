"""The fault matrix (README, "Never raises, never silent"): one row per failure.

Every row drives the small-cell monitor into one failure and checks the whole contract:
the cycle stops the robot (``speed_scale == 0``), one fault names the failure in words a
person reads (the camera or the joint state, and what went wrong), the fault latches
through a following clean cycle, and only ``reset()`` clears it (after which a clean cycle
runs with no fault). A cycle over its deadline is the one row that is a warning, not a
fault: it does not stop the robot and does not latch.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

import polyhull.monitor as monitor_module
from polyhull.distance import DistanceResult, RobotDistanceModel
from polyhull.errors import GeometryError
from polyhull.frames import DepthFrame
from polyhull.monitor import Monitor, Verdict
from polyhull.simulator import Simulator

_EXACT: dict[str, np.ndarray] = {}
T0 = 10.0  # stamp of the failing cycle [s]


@pytest.fixture(autouse=True)
def _depths(small_sim: Simulator) -> None:
    """Noise-free depth of the empty cell with the robot at its default q (cached)."""
    if not _EXACT:
        _EXACT.update(small_sim.render_exact())


def _frames(stamp: float, depths: dict[str, np.ndarray] | None = None, **override: Any) -> dict[str, Any]:
    """Frames of ``depths`` (default: the empty cell) at ``stamp`` [s]; ``override`` replaces
    (or, with None, drops) one camera's frame."""
    depths = depths or _EXACT
    out: dict[str, Any] = {
        name: DepthFrame(camera=name, depth=np.where(np.isfinite(d), d, np.inf).astype(np.float32), stamp=stamp)
        for name, d in depths.items()
    }
    for name, frame in override.items():
        if frame is None:
            del out[name]
        else:
            out[name] = frame
    return out


def _q(m: Monitor) -> np.ndarray:
    return np.asarray(m.cell.robot.q, dtype=np.float64)  # type: ignore[union-attr]


def _clean_step(m: Monitor, stamp: float) -> Verdict:
    v = m.step(_frames(stamp), _q(m), stamp)
    assert v.faults == (), v.faults
    return v


def _depth(name: str, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    d = np.where(np.isfinite(_EXACT[name]), _EXACT[name], np.inf).astype(np.float32)
    return fn(d).astype(np.float32)


def _contaminated(d: np.ndarray) -> np.ndarray:
    d = d.copy()
    d[np.random.default_rng(0).uniform(size=d.shape) < 0.5] = 0.0
    return d


@dataclass(frozen=True)
class Row:
    """One failure: ``cycle(m)`` runs whatever precedes it and returns the failing step's
    arguments; ``words`` must all appear in one fault (case-insensitive regexes)."""

    cycle: Callable[[Monitor], dict[str, Any]]
    words: tuple[str, ...]
    patch: Callable[[pytest.MonkeyPatch], None] | None = None


def _after_clean(m: Monitor, **kwargs: Any) -> dict[str, Any]:
    _clean_step(m, T0 - 0.1)
    return kwargs


def _contact(*args: object, **kwargs: object) -> DistanceResult:
    # what the distance model answers when a piece overlaps a link (FCL's -1/0 in collision)
    return DistanceResult(0.0, None, "link_3")


def _raise_geometry(*args: object, **kwargs: object) -> None:
    raise GeometryError("FCL distance query failed on link 'link6'")


def _raise_beside(*args: object, **kwargs: object) -> None:
    """A failure on the pool thread beside the distance stage (the legs' sheets)."""
    time.sleep(0.05)  # still running when the stage itself is done
    raise GeometryError("legs' columns failed")


ROWS: dict[str, Row] = {
    "frame missing": Row(
        lambda m: {"frames": _frames(T0, sw=None), "q": _q(m), "stamp": T0}, ("sw", "frame missing")
    ),
    "frame stale": Row(
        lambda m: {"frames": _frames(T0, sw=_frames(T0 - 0.5)["sw"]), "q": _q(m), "stamp": T0},
        ("sw", r"stale \(0\.5000 s old > 0\.2000 s\)"),
    ),
    "frame duplicated": Row(
        lambda m: _after_clean(m, frames=_frames(T0 - 0.1), q=_q(m), stamp=T0), ("sw", "duplicated")
    ),
    "frame out of order": Row(
        lambda m: _after_clean(m, frames=_frames(T0 - 0.15), q=_q(m), stamp=T0), ("sw", "out of order")
    ),
    "blind from the start (all NaN)": Row(
        lambda m: {"frames": _frames(T0, sw=DepthFrame("sw", _depth("sw", lambda d: np.full_like(d, np.nan)), T0)), "q": _q(m), "stamp": T0},
        ("sw", "blind or masked", "no depth"),
    ),
    "blind from the start (all zero)": Row(
        lambda m: {"frames": _frames(T0, ne=DepthFrame("ne", _depth("ne", np.zeros_like), T0)), "q": _q(m), "stamp": T0},
        ("ne", "blind or masked"),
    ),
    "contamination jump": Row(
        lambda m: _after_clean(
            m, frames=_frames(T0, ne=DepthFrame("ne", _depth("ne", _contaminated), T0)), q=_q(m), stamp=T0
        ),
        ("ne", "contamination or masking", "jumped"),
    ),
    "camera moved": Row(
        lambda m: {"frames": _frames(T0, sw=DepthFrame("sw", _depth("sw", lambda d: d + 0.5), T0)), "q": _q(m), "stamp": T0},
        ("sw", "moved or miscalibrated"),
    ),
    "joint state missing": Row(lambda m: {"frames": _frames(T0), "q": None, "stamp": T0}, ("joint state", "missing")),
    "joint state stale": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m), "stamp": T0, "q_stamp": T0 - 0.5},
        ("joint state", r"stale \(0\.5000 s old > 0\.1000 s\)"),
    ),
    "joint state outside limits": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m) + np.array([0, 100.0, 0, 0, 0, 0]), "stamp": T0},
        ("joint state", "invalid", "limits"),
    ),
    "joint state not finite": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m) * np.array([1, 1, np.nan, 1, 1, 1]), "stamp": T0},
        ("joint state", "invalid", "not finite"),
    ),
    "joint state wrong length": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m)[:4], "stamp": T0}, ("joint state", "invalid", "6 values")
    ),
    "coverage lost (no camera)": Row(
        lambda m: {"frames": {}, "q": _q(m), "stamp": T0}, ("coverage lost", "no usable camera")
    ),
    "coverage lost (free share)": Row(
        lambda m: {
            "frames": {n: DepthFrame(n, _depth(n, lambda d: np.full_like(d, 0.35)), T0) for n in _EXACT},
            "q": _q(m),
            "stamp": T0,
        },
        ("coverage lost", "surely seen free"),
    ),
    "contact": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m), "stamp": T0},
        ("contact", "touches robot link 'link_3'"),
        patch=lambda mp: mp.setattr(RobotDistanceModel, "distance", _contact),
    ),
    "geometry failure": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m), "stamp": T0},
        ("GeometryError", "FCL distance query failed"),
        patch=lambda mp: mp.setattr(RobotDistanceModel, "distance", _raise_geometry),
    ),
    "failure beside the distance stage": Row(
        lambda m: {"frames": _frames(T0), "q": _q(m), "stamp": T0},
        ("GeometryError", "legs' columns failed"),
        patch=lambda mp: mp.setattr(monitor_module, "hidden_legs", _raise_beside),
    ),
}


def _one_fault(v: Verdict, words: tuple[str, ...]) -> str:
    """The fault that holds every word (regexes); fails with the verdict's faults."""
    hits = [f for f in v.faults if all(re.search(w, f, re.IGNORECASE) for w in words)]
    assert hits, (words, v.faults)
    return hits[0]


@pytest.mark.parametrize("name", list(ROWS))
def test_fault_stops_is_named_latches_and_clears_on_reset(
    fresh_monitor: Monitor, monkeypatch: pytest.MonkeyPatch, name: str
) -> None:
    m, row = fresh_monitor, ROWS[name]
    args = row.cycle(m)
    if row.patch is not None:
        row.patch(monkeypatch)
    v = m.step(args.pop("frames"), args.pop("q"), args.pop("stamp"), **args)
    assert v.speed_scale == 0.0 and v.allowed_speed == 0.0
    fault = _one_fault(v, row.words)
    # words a person reads: no object reprs, addresses or bare exception names
    assert not re.search(r"<[^>]*object at 0x|Traceback|array\(", fault), fault
    assert len(fault) <= 300, fault
    monkeypatch.undo()

    # latched: a clean cycle after it still stops and still names it
    later = m.step(_frames(T0 + 1.0), _q(m), T0 + 1.0)
    assert later.speed_scale == 0.0 and later.allowed_speed == 0.0
    assert fault in later.faults, later.faults
    # only reset() clears it
    m.reset()
    cleared = _clean_step(m, T0 + 2.0)  # asserts no fault
    assert fault not in cleared.faults


def test_cycle_over_its_deadline_is_a_warning_not_a_fault(
    fresh_monitor: Monitor, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A cycle longer than ``safety.cycle_deadline`` is reported and its measured latency
    enters the stopping time T_r; it does not stop the robot and does not latch. (The
    small cell's default pose is 9 cm from the floor's region, so its ramp speed is 0
    even without a fault: the check is that the speed is the distance's decision.)"""
    m = fresh_monitor
    latencies: list[float] = []
    decide = monitor_module.decide_speed

    def spy(distance: float, safety: Any, latency: float, margin: float) -> Any:
        latencies.append(latency)
        return decide(distance, safety, latency, margin)

    monkeypatch.setattr(monitor_module, "decide_speed", spy)
    tight = replace(m.cell, safety=replace(m.cell.safety, cycle_deadline=1e-6))
    loose = replace(m.cell, safety=replace(m.cell.safety, cycle_deadline=1e6))

    monkeypatch.setattr(m, "cell", tight)
    v = m.step(_frames(T0), _q(m), T0)
    assert v.faults == ()
    # the speed is the distance's decision with the measured latency, not a stop
    assert v.speed_scale == decide(v.min_distance, tight.safety, latencies[-1], m._margin).speed_scale
    assert any(re.search(r"cycle over its deadline: [\d.]+ ms > 0 ms", w) for w in v.warnings), v.warnings
    assert latencies and latencies[-1] > 1e-6  # the measured latency went into the decision
    assert latencies[-1] * 1e3 <= v.timings["total"]

    monkeypatch.setattr(m, "cell", loose)
    nxt = m.step(_frames(T0 + 0.1), _q(m), T0 + 0.1)
    assert nxt.faults == ()
    assert not any("deadline" in w for w in nxt.warnings), nxt.warnings  # not latched
