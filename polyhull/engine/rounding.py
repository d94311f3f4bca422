"""float64 depths stored as float32, rounded in a chosen direction, for the compiled kernels.

``np.float32(x)`` rounds to nearest; a depth that bounds something (a free depth, the
robot's front or back) must round the safe way, one float32 step back where to nearest
went the wrong way. That step is arithmetic, not ``np.nextafter``: a libm call in the
loop keeps it from compiling to branch-free code (12 times slower a value; three a pixel
were a third of the robot raster's finishing pass). For a normal float32 ``f`` the gap to
its neighbour away from zero is between ``|f| 2^-24`` and ``|f| 2^-23``, towards zero between
``|f| 2^-24`` and ``|f| 2^-23`` too, and the gap beyond that neighbour at least half of it;
so ``f -/+ c |f|`` with ``c = 1.125 2^-24`` (exact in float64) lies strictly within half a
gap of the neighbour, and rounding it to nearest gives it exactly. Zero and subnormals
step by the subnormal spacing ``2^-149``; an infinity steps to the largest finite float32.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["down32", "up32"]

_STEP = 1.125 * 2.0**-24
_NORMAL = float(np.finfo(np.float32).tiny)  # the least normal float32
_SUB = 2.0**-149  # the subnormal spacing
_MAX = float(np.finfo(np.float32).max)


@nb.njit(cache=True, nogil=True, inline="always")
def down32(x):  # pragma: no cover - compiled
    """The largest float32 at or below ``x`` (float64, not NaN): ``np.nextafter`` of
    ``np.float32(x)`` towards -inf where that is above ``x``."""
    f = np.float32(x)
    a = abs(np.float64(f))
    g = np.float64(f) - _STEP * a
    if a < _NORMAL:
        g = np.float64(f) - _SUB
    elif a == np.inf:
        g = np.float64(_MAX if f > 0.0 else -np.inf)
    return np.float32(g) if f > x else f


@nb.njit(cache=True, nogil=True, inline="always")
def up32(x):  # pragma: no cover - compiled
    """The least float32 at or above ``x`` (float64, not NaN): ``np.nextafter`` of
    ``np.float32(x)`` towards +inf where that is below ``x``."""
    f = np.float32(x)
    a = abs(np.float64(f))
    g = np.float64(f) + _STEP * a
    if a < _NORMAL:
        g = np.float64(f) + _SUB
    elif a == np.inf:
        g = np.float64(-_MAX if f < 0.0 else np.inf)
    return np.float32(g) if f < x else f
