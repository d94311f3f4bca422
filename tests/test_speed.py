"""Speed and separation monitoring: ISO/TS 15066 separation distance and the ramp profile."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.cell import SafetyParams
from polyhull.speed import decide_speed, protective_separation_distance

ISO = SafetyParams()
RAMP = SafetyParams(profile="ramp", ramp_stop_distance=0.3, ramp_full_distance=1.2)


def test_iso_golden_value_by_hand() -> None:
    # d = 1.0 m (>= 0.5 m: v_h = 1.6 m/s), v_r = 1.0 m/s, latency 0.02 s:
    # T_r = 0.1 + 0.02 = 0.12 s, T_s = 0.3 s, S_s = 1.0 * 0.3 / 2 = 0.15 m
    # S_p = 1.6 * 0.42 + 1.0 * 0.12 + 0.15 + 0 + 0.05 + 0.02 = 0.672 + 0.12 + 0.15 + 0.07
    assert protective_separation_distance(1.0, 1.0, ISO, 0.02) == pytest.approx(1.012, abs=1e-12)
    # Solving d = S_p(v) for v at d = 1.5 m, no latency:
    # S_p(v) = 1.6 * 0.4 + v * 0.1 + v * 0.15 + 0.07 = 0.71 + 0.25 v -> v = 0.79 / 0.25 = 3.16
    # which is capped at v_max = 1.5 m/s.
    assert decide_speed(1.5, ISO).speed_scale == 1.0
    # d = 0.9 m: v = (0.9 - 0.71) / 0.25 = 0.76 m/s -> scale 0.76 / 1.5
    dec = decide_speed(0.9, ISO)
    assert dec.allowed_speed == pytest.approx(0.76, abs=1e-12)
    assert dec.speed_scale == pytest.approx(0.76 / 1.5, abs=1e-12)
    assert dec.separation == pytest.approx(0.9, abs=1e-12)


def test_close_range_human_speed_under_half_metre() -> None:
    # Under 0.5 m ISO 13855 uses 2.0 m/s: S_p(0) = 2.0 * 0.4 + 0.07 = 0.87 m.
    assert protective_separation_distance(0.0, 0.49, ISO, 0.0) == pytest.approx(0.87, abs=1e-12)
    assert protective_separation_distance(0.0, 0.5, ISO, 0.0) == pytest.approx(0.71, abs=1e-12)


def test_fixed_stopping_distance_scales_with_speed() -> None:
    p = dataclasses.replace(ISO, stopping_distance=0.4)
    # S_s = 0.4 * 0.75 / 1.5 = 0.2; S_p = 0.64 + 0.075 + 0.2 + 0.07
    assert protective_separation_distance(0.75, 1.0, p, 0.0) == pytest.approx(0.985, abs=1e-12)


def test_latency_increases_separation() -> None:
    for v in (0.0, 0.5, 1.5):
        assert protective_separation_distance(v, 1.0, ISO, 0.05) > protective_separation_distance(v, 1.0, ISO, 0.0)
    assert decide_speed(0.9, ISO, latency=0.05).speed_scale < decide_speed(0.9, ISO).speed_scale


def test_margin_adds_to_separation() -> None:
    base = protective_separation_distance(0.5, 1.0, ISO, 0.0)
    assert protective_separation_distance(0.5, 1.0, ISO, 0.0, margin=0.1) == pytest.approx(base + 0.1)


@pytest.mark.parametrize("params", [ISO, RAMP], ids=["iso", "ramp"])
def test_special_distances(params: SafetyParams) -> None:
    assert decide_speed(math.inf, params).speed_scale == 1.0
    assert decide_speed(math.inf, params).allowed_speed == params.robot_speed_max
    for d in (math.nan, 0.0, -1.0):
        dec = decide_speed(d, params)
        assert dec.speed_scale == 0.0
        assert dec.allowed_speed == 0.0
    assert decide_speed(100.0, params).speed_scale == 1.0


def test_iso_stops_at_or_below_static_separation() -> None:
    for d in (0.2, 0.49, 0.71, 0.7):
        s0 = protective_separation_distance(0.0, d, ISO, 0.0)
        assert d <= s0
        assert decide_speed(d, ISO).speed_scale == 0.0
    # Just above S_p(0) at d >= 0.5 m the robot may move.
    assert decide_speed(0.72, ISO).speed_scale > 0.0


@settings(max_examples=200, deadline=None)
@given(
    a=st.floats(0.0, 5.0),
    b=st.floats(0.0, 5.0),
    latency=st.floats(0.0, 0.1),
    margin=st.floats(0.0, 0.1),
    profile=st.sampled_from(["iso", "ramp"]),
)
def test_speed_monotone_in_distance(a: float, b: float, latency: float, margin: float, profile: str) -> None:
    params = ISO if profile == "iso" else RAMP
    lo, hi = min(a, b), max(a, b)
    s_lo = decide_speed(lo, params, latency, margin).speed_scale
    s_hi = decide_speed(hi, params, latency, margin).speed_scale
    assert 0.0 <= s_lo <= s_hi <= 1.0


@settings(max_examples=100, deadline=None)
@given(d=st.floats(0.01, 5.0), latency=st.floats(0.0, 0.1))
def test_iso_allowed_speed_respects_separation(d: float, latency: float) -> None:
    dec = decide_speed(d, ISO, latency)
    if dec.allowed_speed > 0:
        assert d >= protective_separation_distance(dec.allowed_speed, d, ISO, latency) - 1e-9


def test_ramp_profile() -> None:
    assert decide_speed(0.1, RAMP).speed_scale == 0.0
    assert decide_speed(0.3, RAMP).speed_scale == 0.0
    assert decide_speed(1.2, RAMP).speed_scale == 1.0
    assert decide_speed(2.0, RAMP).speed_scale == 1.0
    for d in np.linspace(0.3, 1.2, 7):
        assert decide_speed(float(d), RAMP).speed_scale == pytest.approx((d - 0.3) / 0.9, abs=1e-12)
    # Margin shifts both ends.
    assert decide_speed(0.35, RAMP, margin=0.1).speed_scale == 0.0
    assert decide_speed(0.75 + 0.1, RAMP, margin=0.1).speed_scale == pytest.approx(0.5, abs=1e-12)
