"""Pixel classes: every pixel of a frame, in image space, in one pass per camera.

Per pixel p of camera i (``f_s`` the static free depth, ``[T, U]`` the static band, ``S``
the depth where the padded robot's shadow starts, +inf where the robot does not cover p):

- **static**: the measurement lies in the band (or the pixel frees nothing even in the
  empty cell): the free depth is ``f_s``;
- otherwise the exact free depth of SPEC section 2 is computed, clamped to ``f_s``:
  ``f(p) = min(f_exact(p), f_s(p))`` (never more than the static model allows);
- the pixel's occluded **segment** runs from ``f(p)`` back to ``end(p) = min(f_s(p), S(p))``;
  beyond ``S`` the robot's shadow (its occlusion M) takes over. A pixel is **explained by
  the robot** when its segment is empty because ``f(p) >= S(p)``, and **unexplained** when
  the segment is not empty: a person, a new object, a dropout, a flying pixel.

Only unexplained pixels cost geometry (:mod:`polyhull.engine.pieces`). The free depth image
``f`` of every camera is what the other cameras carve with, through min/max pyramids.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from ..typed import ArrayF32

__all__ = [
    "PixelClasses",
    "classify_frame",
    "FreePyramid",
    "free_pyramid",
    "tile_segments",
    "memory_segments",
]


class PixelClasses(NamedTuple):
    """One camera's pixels in one cycle.

    Attributes:
        free: (H, W) engine free depth ``f`` [m] (float32, never above the exact one).
        end: (H, W) end of each pixel's occluded segment [m]; a segment exists where
            ``free < end``.
        unexplained: Number of pixels with a segment.
        invalid_share: Share of the pixels that see the empty cell within range and now
            have no usable depth.
        far_side_share: Share of those pixels reading farther than the static band (the
            camera-moved indicator).
    """

    free: ArrayF32
    end: ArrayF32
    unexplained: int
    invalid_share: float
    far_side_share: float


@nb.njit(cache=True, nogil=True)
def _classify(depth, B, T, U, fs, shadow, near, far, a, tmin, is_color, out_free, out_end):  # pragma: no cover - compiled
    H, W = depth.shape
    n_invalid = 0
    n_far = 0
    n_seen = 0
    n_seg = 0
    for v in range(H):
        for u in range(W):
            f_s = np.float64(fs[v, u])
            d = np.float64(depth[v, u])
            if f_s <= near:
                free = near
            elif d >= T[v, u] and d <= U[v, u]:
                n_seen += 1
                free = f_s
            else:
                n_seen += 1
                b = min(np.float64(B[v, u]), far)
                usable = True
                if d == np.inf:
                    de = far
                elif d >= near and d <= far:
                    de = d
                else:  # 0, NaN, -inf, out of range: unknown, nothing free
                    usable = False
                    de = near
                if not usable:
                    n_invalid += 1
                    f = near
                elif is_color:
                    f = near if de < T[v, u] else f_s
                else:
                    t = max(a * de * de, tmin)
                    f = min(de, b) - t
                if usable and d > U[v, u] and d != np.inf:
                    n_far += 1
                free = min(max(f, near), f_s)
            end = min(f_s, np.float64(shadow[v, u]))
            # float32 storage rounds toward the camera (free) and away from it (end):
            # the segment only grows.
            fr = np.float32(free)
            if fr > free:
                fr = np.nextafter(fr, np.float32(-np.inf))
            en = np.float32(end)
            if en < end:
                en = np.nextafter(en, np.float32(np.inf))
            out_free[v, u] = fr
            out_end[v, u] = en
            if fr < en:
                n_seg += 1
    return n_seg, n_invalid, n_far, n_seen


def classify_frame(
    depth: np.ndarray,
    reference: ArrayF32,
    lower: ArrayF32,
    upper: ArrayF32,
    free_static: ArrayF32,
    shadow_start: ArrayF32,
    *,
    near: float,
    far: float,
    tau_a: float,
    tau_min: float,
    is_color: bool,
) -> PixelClasses:
    """Classify the pixels of one frame (see the module docstring).

    Args:
        depth: (H, W) measured z-depth [m], float32 or float64 (REP 117 special values).
        reference: (H, W) reference depth B [m], +inf where nothing is hit.
        lower: (H, W) static band lower bound T [m].
        upper: (H, W) static band upper bound U [m].
        free_static: (H, W) static free depth f_s [m].
        shadow_start: (H, W) depth where the robot's shadow starts [m], +inf elsewhere.
        near: Near range [m].
        far: Far range [m].
        tau_a: ``tolerance_sigmas * noise``: tau(z) = max(tau_a z^2, tau_min) [m].
        tau_min: Floor of tau [m].
        is_color: Binary-depth (colour) camera.
    """
    H, W = free_static.shape
    out_free = np.empty((H, W), dtype=np.float32)
    out_end = np.empty((H, W), dtype=np.float32)
    n_seg, n_invalid, n_far, n_seen = _classify(
        depth, reference, lower, upper, free_static, shadow_start,
        float(near), float(far), float(tau_a), float(tau_min), bool(is_color), out_free, out_end,
    )
    seen = max(int(n_seen), 1)
    return PixelClasses(out_free, out_end, int(n_seg), n_invalid / seen, n_far / seen)


class FreePyramid(NamedTuple):
    """Min and max pyramids of a free depth image, flattened level after level.

    Level l has cells of 2^l x 2^l pixels; ``offsets[l]`` is where it starts in ``mins``
    and ``maxs``, ``shapes[l]`` its (rows, cols).
    """

    mins: ArrayF32
    maxs: ArrayF32
    offsets: np.ndarray  # (L,) int64
    shapes: np.ndarray  # (L, 2) int64


def _pyramid_layout(H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    shapes = [(H, W)]
    while shapes[-1][0] > 1 or shapes[-1][1] > 1:
        h, w = shapes[-1]
        shapes.append((-(-h // 2), -(-w // 2)))
    shp = np.array(shapes, dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(shp[:, 0] * shp[:, 1])[:-1]]).astype(np.int64)
    return offsets, shp


@nb.njit(cache=True, nogil=True)
def _build_pyramid(free, mins, maxs, offsets, shapes):  # pragma: no cover - compiled
    H, W = free.shape
    for v in range(H):
        for u in range(W):
            mins[v * W + u] = free[v, u]
            maxs[v * W + u] = free[v, u]
    for lev in range(1, shapes.shape[0]):
        h0, w0 = shapes[lev - 1, 0], shapes[lev - 1, 1]
        h1, w1 = shapes[lev, 0], shapes[lev, 1]
        o0, o1 = offsets[lev - 1], offsets[lev]
        for r in range(h1):
            for c in range(w1):
                lo = np.float32(np.inf)
                hi = np.float32(-np.inf)
                for dr in range(2):
                    rr = 2 * r + dr
                    if rr >= h0:
                        continue
                    for dc in range(2):
                        cc = 2 * c + dc
                        if cc >= w0:
                            continue
                        lo = min(lo, mins[o0 + rr * w0 + cc])
                        hi = max(hi, maxs[o0 + rr * w0 + cc])
                mins[o1 + r * w1 + c] = lo
                maxs[o1 + r * w1 + c] = hi


def free_pyramid(free: ArrayF32) -> FreePyramid:
    """Min and max pyramids of an (H, W) free depth image (range queries for carving)."""
    H, W = free.shape
    offsets, shapes = _pyramid_layout(H, W)
    total = int((shapes[:, 0] * shapes[:, 1]).sum())
    mins = np.empty(total, dtype=np.float32)
    maxs = np.empty(total, dtype=np.float32)
    _build_pyramid(free, mins, maxs, offsets, shapes)
    return FreePyramid(mins, maxs, offsets, shapes)


@nb.njit(cache=True, nogil=True)
def _tile_segments(free, end, covered, tile):  # pragma: no cover - compiled
    """Pieces (u0, u1, v0, v1 pixel indices inclusive, z0, z1) of one camera.

    A tile without robot pixels gives one piece: the bounding rectangle of its segment
    pixels, from their smallest start to their largest end (a superset of their union).
    A tile with a robot-covered pixel gives one piece per segment pixel, so that no piece
    reaches past the robot's shadow start of another pixel.
    """
    H, W = free.shape
    Hb = (H + tile - 1) // tile
    Wb = (W + tile - 1) // tile
    cap = 1024
    out = np.empty((cap, 6), dtype=np.float64)
    n = 0
    for tb in range(Hb):
        for ub in range(Wb):
            v0 = tb * tile
            u0 = ub * tile
            v1 = min(v0 + tile, H)
            u1 = min(u0 + tile, W)
            robot = False
            any_seg = False
            for v in range(v0, v1):
                for u in range(u0, u1):
                    if free[v, u] < end[v, u]:
                        any_seg = True
                        if covered[v, u]:
                            robot = True
            if not any_seg:
                continue
            if robot:
                for v in range(v0, v1):
                    for u in range(u0, u1):
                        if free[v, u] < end[v, u]:
                            if n == cap:
                                cap *= 2
                                grown = np.empty((cap, 6), dtype=np.float64)
                                grown[:n] = out[:n]
                                out = grown
                            out[n, 0] = u
                            out[n, 1] = u
                            out[n, 2] = v
                            out[n, 3] = v
                            out[n, 4] = free[v, u]
                            out[n, 5] = end[v, u]
                            n += 1
            else:
                zmin = np.inf
                zmax = -np.inf
                pu0, pu1, pv0, pv1 = W, -1, H, -1
                for v in range(v0, v1):
                    for u in range(u0, u1):
                        if free[v, u] < end[v, u]:
                            zmin = min(zmin, np.float64(free[v, u]))
                            zmax = max(zmax, np.float64(end[v, u]))
                            pu0 = min(pu0, u)
                            pu1 = max(pu1, u)
                            pv0 = min(pv0, v)
                            pv1 = max(pv1, v)
                if n == cap:
                    cap *= 2
                    grown = np.empty((cap, 6), dtype=np.float64)
                    grown[:n] = out[:n]
                    out = grown
                out[n, 0] = pu0
                out[n, 1] = pu1
                out[n, 2] = pv0
                out[n, 3] = pv1
                out[n, 4] = zmin
                out[n, 5] = zmax
                n += 1
    return out[:n]


def tile_segments(free: ArrayF32, end: ArrayF32, covered: np.ndarray, tile: int) -> np.ndarray:
    """(N, 6) initial pieces of one camera: pixel rectangle (u0, u1, v0, v1), inclusive
    pixel indices, and depth range (z0, z1) [m] (see :func:`_tile_segments`)."""
    return _tile_segments(free, end, covered, int(tile))


@nb.njit(cache=True, nogil=True)
def _memory(covered, back, free, fs, rects, zr, out_f, out_e):  # pragma: no cover - compiled
    H, W = covered.shape
    for b in range(rects.shape[0]):
        u0 = max(rects[b, 0], 0)
        u1 = min(rects[b, 1], W - 1)
        v0 = max(rects[b, 2], 0)
        v1 = min(rects[b, 3], H - 1)
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if not covered[v, u]:
                    continue
                start = max(max(np.float64(free[v, u]), np.float64(back[v, u])), zr[b, 0])
                stop = min(np.float64(fs[v, u]), zr[b, 1])
                if start < stop:
                    if start < out_f[v, u]:
                        out_f[v, u] = np.float32(start)
                    if stop > out_e[v, u]:
                        out_e[v, u] = np.float32(stop)


def memory_segments(
    covered: np.ndarray,
    robot_back: ArrayF32,
    free: ArrayF32,
    free_static: ArrayF32,
    rects: np.ndarray,
    z_ranges: np.ndarray,
) -> tuple[ArrayF32, ArrayF32]:
    """Segments of the robot's shadow near given boxes, for the shadow memory.

    For every box (its pixel rectangle ``rects`` (B, 4) u0, u1, v0, v1 and z-depth range
    ``z_ranges`` (B, 2) in this camera), the robot-covered pixels of the rectangle get the
    segment from ``max(f, back, z_min)`` to ``min(f_s, z_max)``: what the robot hides from
    this camera behind its body (and the camera does not free), within the box's depth
    range. The robot's own (padded) volume is not part of the region.

    Returns:
        (start, end) images [m]; no segment where ``start >= end``.
    """
    H, W = covered.shape
    out_f = np.full((H, W), np.inf, dtype=np.float32)
    out_e = np.full((H, W), -np.inf, dtype=np.float32)
    if len(rects):
        _memory(covered, robot_back, free, free_static, np.ascontiguousarray(rects, dtype=np.int64),
                np.ascontiguousarray(z_ranges, dtype=np.float64), out_f, out_e)
    return out_f, out_e
