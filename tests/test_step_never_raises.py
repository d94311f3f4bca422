"""``Monitor.step`` never raises (README, "Never raises, never silent"), whatever the
controller passes it.

Hypothesis draws ``q``, ``stamp``, ``q_stamp`` and frame mappings of every wrong kind
(types, shapes, dtypes, NaN/inf, empty, huge, unknown cameras, values that are not
``DepthFrame``s) next to valid ones. Every call must return a :class:`Verdict` that either
stops the robot and names why, or is a valid verdict with no fault. One monitor (the
session's small-cell monitor) serves every example; it is reset before each.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from polyhull.frames import DepthFrame
from polyhull.monitor import Monitor, Verdict
from polyhull.simulator import Simulator

_EXACT: dict[str, np.ndarray] = {}
_CAMERAS = ("sw", "ne")  # the small cell's cameras
_Q0 = (0.0, -0.6, 1.2, 0.0, 0.8, 0.0)  # the small cell's robot q [rad]
_STAMP = 1.0

_SETTINGS = settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large],
)


@pytest.fixture(scope="module")
def exact(small_sim: Simulator) -> dict[str, np.ndarray]:
    """Noise-free depth of the empty small cell (with the robot at its default q)."""
    if not _EXACT:
        _EXACT.update(small_sim.render_exact())
    return _EXACT


def _clean_depth(name: str) -> np.ndarray:
    e = _EXACT[name]
    return np.where(np.isfinite(e), e, np.inf).astype(np.float32)


def _assert_valid(v: object) -> None:
    """A verdict that stops and names why, or a valid verdict without a fault."""
    assert isinstance(v, Verdict), type(v)
    assert isinstance(v.faults, tuple) and isinstance(v.warnings, tuple)
    assert all(isinstance(f, str) and f.strip() for f in v.faults), v.faults
    assert 0.0 <= v.speed_scale <= 1.0, v.speed_scale
    assert 0.0 <= v.allowed_speed
    assert isinstance(v.q, np.ndarray) and v.q.dtype == np.float64 and v.q.ndim == 1
    assert isinstance(v.stamp, float)
    if v.faults:
        assert v.speed_scale == 0.0 and v.allowed_speed == 0.0, v.faults
    else:
        assert math.isfinite(v.stamp)
        assert v.q.shape == (len(_Q0),)
        assert v.min_distance >= 0.0


# -- strategies --------------------------------------------------------------------------
_weird_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(),
    st.text(max_size=8),
    st.binary(max_size=8),
    st.just(object()),
    st.just({}),
    st.just([]),
)

_dtypes = st.one_of(
    hnp.floating_dtypes(), hnp.integer_dtypes(), hnp.unsigned_integer_dtypes(),
    hnp.complex_number_dtypes(), hnp.boolean_dtypes(), st.just(np.dtype(object)), hnp.unicode_string_dtypes(),
)


def _arrays(shape: st.SearchStrategy) -> st.SearchStrategy:  # type: ignore[type-arg]
    return _dtypes.flatmap(
        lambda dt: hnp.arrays(dt, shape, elements=None if dt.kind != "O" else st.just(0.0))
    )


_q_near = st.lists(
    st.floats(min_value=-0.5, max_value=0.5), min_size=len(_Q0), max_size=len(_Q0)
).map(lambda d: np.asarray(_Q0) + np.asarray(d))

q_strategy = st.one_of(
    st.just(np.asarray(_Q0)),
    _q_near,
    _q_near.map(list),
    _q_near.map(lambda q: q.astype(np.float32)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=8),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=6, max_size=6),
    st.lists(_weird_scalars, max_size=7),
    st.lists(st.lists(st.floats(-1, 1), max_size=6), max_size=3),  # ragged or (N, k)
    _arrays(hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=7)),
    _weird_scalars,
    st.text(max_size=20),
    st.just(np.full(6, 1e308)),
)

stamp_strategy = st.one_of(
    st.just(_STAMP),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.sampled_from([np.float32(_STAMP), np.int64(1), np.float64(np.nan), np.float16(_STAMP)]),
    _weird_scalars,
    _arrays(hnp.array_shapes(min_dims=0, max_dims=2, max_side=3)),
)

q_stamp_strategy = st.one_of(st.just(None), st.just(_STAMP), stamp_strategy)


@st.composite
def _frame_value(draw: st.DrawFn, name: str) -> object:
    """A value for ``frames[name]``: valid, subtly wrong, or not a frame at all."""
    kind = draw(st.sampled_from(["clean", "clean", "stamp", "pixels", "array", "dtype", "other", "lying"]))
    if kind == "clean" and name in _EXACT:
        return DepthFrame(camera=name, depth=_clean_depth(name), stamp=_STAMP)
    if kind == "stamp" and name in _EXACT:  # a finite stamp anywhere: stale, future, huge
        stamp = draw(st.floats(allow_nan=False, allow_infinity=False))
        return DepthFrame(camera=name, depth=_clean_depth(name), stamp=stamp)
    if kind == "pixels" and name in _EXACT:  # the right shape, hostile values (REP 117 and worse)
        depth = _clean_depth(name).copy()
        value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e30, 1e-30, 0.31]))
        rows = draw(st.integers(0, depth.shape[0]))
        depth[:rows] = value
        return DepthFrame(camera=name, depth=depth, stamp=_STAMP)
    if kind == "dtype" and name in _EXACT:  # uint16 millimetres, float64
        depth = _clean_depth(name)
        if draw(st.booleans()):
            return DepthFrame(camera=name, depth=np.nan_to_num(depth * 1000, posinf=0).astype(np.uint16), stamp=_STAMP)
        return DepthFrame(camera=name, depth=depth.astype(np.float64), stamp=_STAMP)
    if kind == "array":  # a DepthFrame of the wrong shape
        h, w = draw(st.integers(1, 9)), draw(st.integers(1, 9))
        return DepthFrame(camera=name, depth=np.full((h, w), 2.0, np.float32), stamp=_STAMP)
    if kind == "lying" and name in _EXACT:  # a DepthFrame whose fields were overwritten
        frame = DepthFrame(camera=name, depth=_clean_depth(name), stamp=_STAMP)
        field = draw(st.sampled_from(["stamp", "depth", "camera"]))
        object.__setattr__(frame, field, draw(_weird_scalars))
        return frame
    return draw(
        st.one_of(
            _weird_scalars,
            _arrays(hnp.array_shapes(min_dims=0, max_dims=3, max_side=5)),
            st.just(_clean_depth(name) if name in _EXACT else np.zeros((2, 2))),  # a bare array
        )
    )


@st.composite
def frames_strategy(draw: st.DrawFn) -> object:
    """A frames mapping (mostly) or something that is not one."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.one_of(_weird_scalars, st.lists(_weird_scalars, max_size=3), st.text(max_size=5)))
    names = draw(st.lists(st.sampled_from([*_CAMERAS, "nobody", ""]), unique=True, max_size=4))
    out: dict[object, object] = {name: draw(_frame_value(name)) for name in names}
    if draw(st.integers(0, 5)) == 0:  # keys that are not camera names at all
        out[draw(st.one_of(st.integers(), st.none(), st.floats()))] = None
    return out


def _forged(frames: object) -> bool:
    """Whether ``frames`` holds a DepthFrame whose fields were overwritten behind its
    validation (those may stop as an internal error: still a named stop)."""
    if not isinstance(frames, dict):
        return False
    return any(
        isinstance(f, DepthFrame)
        and not (type(f.stamp) is float and isinstance(f.depth, np.ndarray) and isinstance(f.camera, str))
        for f in frames.values()
    )


# -- the properties ------------------------------------------------------------------------
@_SETTINGS
@given(frames=frames_strategy(), q=q_strategy, stamp=stamp_strategy, q_stamp=q_stamp_strategy)
def test_step_never_raises(
    small_monitor: Monitor, exact: dict[str, np.ndarray], frames: object, q: object, stamp: object, q_stamp: object
) -> None:
    small_monitor.reset()
    v = small_monitor.step(frames, q, stamp, q_stamp=q_stamp)  # type: ignore[arg-type]
    _assert_valid(v)
    if not _forged(frames):
        # every bad input is named for what it is, not reported as an internal error
        assert not [f for f in v.faults if f.startswith("internal")], v.faults
    # the faults latch: a clean cycle right after still stops (and never raises)
    clean = {n: DepthFrame(camera=n, depth=_clean_depth(n), stamp=_STAMP + 0.05) for n in _CAMERAS}
    after = small_monitor.step(clean, np.asarray(_Q0), _STAMP + 0.05)
    _assert_valid(after)
    assert set(v.faults) <= set(after.faults), (v.faults, after.faults)


@settings(_SETTINGS, max_examples=6)
@given(
    q=st.lists(st.floats(min_value=-0.3, max_value=0.3), min_size=6, max_size=6),
    junk=st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e30, -5.0]),
)
def test_inputs_mutated_after_the_call_change_nothing(
    small_monitor: Monitor, exact: dict[str, np.ndarray], q: list[float], junk: float
) -> None:
    """The verdict and the monitor keep no view of the caller's arrays: overwriting them after
    the call changes neither the verdict nor the next cycle."""
    small_monitor.reset()
    q_in = np.asarray(_Q0) + np.asarray(q)
    depths = {n: _clean_depth(n).copy() for n in _CAMERAS}
    frames = {n: DepthFrame(camera=n, depth=d, stamp=_STAMP) for n, d in depths.items()}
    v = small_monitor.step(frames, q_in, _STAMP)
    _assert_valid(v)
    q_seen, faults = v.q.copy(), v.faults
    q_in[:] = junk
    for d in depths.values():
        d[:] = junk
    np.testing.assert_array_equal(v.q, q_seen)
    assert v.faults == faults
    # the frames the monitor was given still hold what was passed
    for n in _CAMERAS:
        np.testing.assert_array_equal(frames[n].depth, _clean_depth(n))
    nxt = {n: DepthFrame(camera=n, depth=_clean_depth(n), stamp=_STAMP + 0.05) for n in _CAMERAS}
    after = small_monitor.step(nxt, np.asarray(_Q0) + np.asarray(q), _STAMP + 0.05)
    _assert_valid(after)
    assert after.faults == faults
