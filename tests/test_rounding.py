"""The compiled directed float32 rounding against numpy's ``nextafter`` definition."""

from __future__ import annotations

import numba as nb
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.rounding import down32, up32


@nb.njit(cache=True)
def _round_all(xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    d = np.empty(xs.shape[0], dtype=np.float32)
    u = np.empty(xs.shape[0], dtype=np.float32)
    for i in range(xs.shape[0]):
        d[i] = down32(xs[i])
        u[i] = up32(xs[i])
    return d, u


def _expected(xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest float32 <= x and the least >= x: round to nearest, then one step back
    with ``np.nextafter`` where that went the wrong way."""
    f = xs.astype(np.float32)
    down = np.where(f.astype(np.float64) > xs, np.nextafter(f, np.float32(-np.inf)), f)
    up = np.where(f.astype(np.float64) < xs, np.nextafter(f, np.float32(np.inf)), f)
    return down, up


def _check(xs: np.ndarray) -> None:
    with np.errstate(over="ignore"):
        d, u = _round_all(xs)
        want_d, want_u = _expected(xs)
    np.testing.assert_array_equal(d, want_d)
    np.testing.assert_array_equal(u, want_u)
    assert np.all(d.astype(np.float64) <= xs) and np.all(u.astype(np.float64) >= xs)


def test_rounding_near_powers_of_two_and_edges() -> None:
    # the multiplication's margins are tightest at powers of two (the gap halves below one)
    p2 = 2.0 ** np.arange(-125, 127, dtype=np.float64)
    above = np.nextafter(p2.astype(np.float32), np.float32(np.inf)).astype(np.float64)
    parts = [np.array([0.0, 1e-45, 1e-40, float(np.finfo(np.float32).tiny), 3.4e38, 3.5e38, 0.3, 0.1, 5.0, -0.3, -7.0])]
    for k in range(-4, 5):
        for scale in (2.0**-22, 2.0**-24, 2.0**-25, 2.0**-30, 2.0**-52):
            parts += [p2 * (1 + k * scale), above * (1 + k * scale)]
    _check(np.concatenate(parts))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=True, width=64), min_size=1, max_size=50))
def test_rounding_is_nextafter(values: list[float]) -> None:
    _check(np.asarray(values, dtype=np.float64))


def test_rounding_many_depths() -> None:
    rng = np.random.default_rng(0)
    _check(np.concatenate([rng.uniform(0.0, 12.0, 200_000), np.exp(rng.uniform(-85.0, 85.0, 200_000))]))
