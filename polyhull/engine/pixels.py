"""Pixel classes: every pixel of a frame, in image space, in one pass per camera.

Per pixel p of camera i (``f_s`` the static free depth, ``[T, U]`` the static band, ``S``
the depth where the padded robot's shadow starts, +inf where the robot does not cover p):

- **static**: the measurement lies in the band (or the pixel frees nothing even in the
  empty cell): the free depth is ``f_s``. At a depth camera's static edge the band is the
  3 x 3 neighbourhood's (flying pixels), so ``f_s`` is the nearer surface's, up to a metre
  short of the farther one the pixel usually reads: there a reading in the band frees its
  own exact free depth (at least ``f_s``, the band's least; about 1,000 pixels a camera,
  in the row chunks classified every cycle), so the other cameras' pieces are carved with
  what the pixel saw, not with the static model's wedge behind the edge;
- otherwise the exact free depth (``regions.free_depth``) is computed, clamped to ``f_s``:
  ``f(p) = min(f_exact(p), f_s(p))`` (never more than the static model allows);
- the pixel's occluded **segment** runs from ``f(p)`` back to ``end(p) = min(f_s(p), S(p))``,
  or, for a surface seen in front of the band (a valid reading there in the pixel and its
  8 neighbours), to ``min(f_e(p), S(p))`` with ``f_e = B - tau(B)`` the empty cell's free
  depth (``M = F_static \\ F_static+robot`` is defined from the empty cell: the space the
  empty cell shows the pixel, behind what it sees now, is not M); beyond ``S`` the robot's
  shadow (its occlusion M) takes over. A pixel is **explained by
  the robot** when its segment is empty because ``f(p) >= S(p)``, and **unexplained** when
  the segment is not empty: a person, a new object, a dropout, a flying pixel;
- at a static edge pixel whose wedge may meet another camera's robot shadow
  (:mod:`polyhull.engine.edge_wedges`), with a valid non-edge reading that has a segment
  within ``WEDGE_REACH`` px, ``end`` is the pixel's own band's least free depth instead of
  ``f_s``: a reading in front of its own band (in the widened one) then has a segment.

Only unexplained pixels cost geometry (:mod:`polyhull.engine.pieces`). The free depth image
``f`` of every camera is what the other cameras carve with, through min/max pyramids.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from ..typed import ArrayF32
from .rounding import down32, up32

__all__ = [
    "PixelBuffers",
    "PixelClasses",
    "StaticClasses",
    "classify_frame",
    "prepare_static",
    "pyramid_layout",
    "build_pyramid",
    "update_pyramid",
    "tile_segments",
    "memory_segments",
    "box_rects",
    "small_gaps",
    "only_marked_segments",
    "window_range",
]


class PixelClasses(NamedTuple):
    """One camera's pixels in one cycle.

    Attributes:
        free: (H, W) engine free depth ``f`` [m] (float32, never above the exact one).
        end: (H, W) end of each pixel's occluded segment [m]; a segment exists where
            ``free < end``.
        unexplained: Number of pixels with a segment.
        invalid: (H, W) pixels with no usable reading (0, NaN, -inf, out of range).
        invalid_share: Share of the pixels that see the empty cell within range and now
            have no usable depth.
        far_side_share: Share of those pixels reading farther than the static band (the
            camera-moved indicator).
        tiles: (ceil(H / tile), ceil(W / tile)) the tiles holding a segment pixel (what
            :func:`tile_segments` visits).
    """

    free: ArrayF32
    end: ArrayF32
    unexplained: int
    invalid: np.ndarray
    invalid_share: float
    far_side_share: float
    tiles: np.ndarray


class StaticClasses(NamedTuple):
    """What one camera's pixel classification can know before any frame
    (:func:`prepare_static`).

    Attributes:
        free0: (H, W) the free depth of a pixel whose reading is static: ``f_s``, or the
            near range (rounded down) where ``f_s <= near``.
        lower: (H, W) the band's lower bound T, -inf where ``f_s <= near`` (such a pixel
            frees the near range whatever it reads).
        upper: (H, W) the band's upper bound U, +inf where ``f_s <= near``.
        seen: Number of pixels with ``f_s > near`` (that see the empty cell within range).
        band: (H, W) uint32, the band shrunk to whole millimetres (and one more), packed:
            ``Tq`` in the low 16 bits, ``Uq`` in the high ones (65535: no upper bound). A
            reading with ``Tq <= 1000 d <= Uq`` is in the band for sure; the others are
            tested against T and U. One image of half the size instead of two: the test
            of every pixel is bound by memory traffic.
        edge: (H, W) static edge pixels (:attr:`polyhull.engine.static_model.StaticCamera.edge`):
            a reading in their band frees its own exact free depth, not ``free0``.
        edge_chunks: (H, ceil(W / CHUNK)) the row chunks holding one (classified pixel
            by pixel every cycle).
    """

    free0: ArrayF32
    lower: ArrayF32
    upper: ArrayF32
    seen: int
    band: np.ndarray
    edge: np.ndarray
    edge_chunks: np.ndarray


def prepare_static(
    lower: ArrayF32, upper: ArrayF32, free_static: ArrayF32, near: float, edge: np.ndarray | None = None
) -> StaticClasses:
    """The frame-independent part of :func:`classify_frame` for one camera (``edge``: its
    static edge pixels, none when None)."""
    fs = np.asarray(free_static, dtype=np.float32)
    inside = fs.astype(np.float64) <= float(near)
    near32 = np.float32(near)
    if float(near32) > float(near):
        near32 = np.nextafter(near32, np.float32(-np.inf))
    free0 = np.where(inside, near32, fs).astype(np.float32)
    lo = np.where(inside, -np.inf, lower).astype(np.float32)
    hi = np.where(inside, np.inf, upper).astype(np.float32)
    H, W = fs.shape
    e = np.zeros((H, W), dtype=np.bool_) if edge is None else np.asarray(edge, dtype=np.bool_) & ~inside
    chunks = np.zeros((H, -(-W // CHUNK) * CHUNK), dtype=np.bool_)
    chunks[:, :W] = e
    return StaticClasses(
        free0, lo, hi, int((~inside).sum()), _packed_band(lo, hi), np.ascontiguousarray(e),
        np.ascontiguousarray(chunks.reshape(H, -1, CHUNK).any(axis=2)),
    )


def _packed_band(lower: ArrayF32, upper: ArrayF32) -> np.ndarray:
    """:attr:`StaticClasses.band`: ``Tq = ceil(1000 T) + 1`` (0 for -inf) and ``Uq =
    floor(1000 U) - 1`` (65535 for +inf), a millimetre inside the band and more than its
    rounding; a pixel whose band does not fit (beyond 65 m, NaN) gets (65535, 0): always
    tested exactly."""
    T = np.asarray(lower, dtype=np.float64)
    U = np.asarray(upper, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        tq = np.where(T == -np.inf, 0.0, np.ceil(T * 1000.0) + 1.0)
        uq = np.where(U == np.inf, 65535.0, np.floor(U * 1000.0) - 1.0)
        fits = (tq >= 0.0) & (tq <= 65534.0) & ((U == np.inf) | ((uq >= 0.0) & (uq <= 65534.0)))
    tq = np.where(fits, tq, 65535.0).astype(np.uint32)
    uq = np.where(fits, uq, 0.0).astype(np.uint32)
    return np.ascontiguousarray(tq | (uq << np.uint32(16)))


_NO_WEDGES = np.zeros((0, 2), dtype=np.int64)  # writable, as every later list (one kernel signature)

WEDGE_REACH = 2
"""[px] An edge pixel's wedge (:mod:`polyhull.engine.edge_wedges`) runs to its own free
depth when a valid reading with a segment, not at a static edge, lies within this many
pixels (across the 2-3 px wide strip of an edge's widened bands)."""

CHUNK = 16
"""Pixels of a row tested together for a non-static reading (a branch-free, vectorised
test); a chunk holding one is classified pixel by pixel."""

BLOCK = 8
"""Edge [px] of the blocks in which :class:`PixelBuffers` mark what a classification wrote
(:attr:`PixelBuffers.changed`): level 3 of the free depth pyramids, updated only there."""


class PixelBuffers:
    """One camera's free depth, segment ends and invalid flags, kept from cycle to cycle.

    Between cycles they hold the last classification; what differs from the static
    images (``free0``, ``f_s``, no invalid pixel) lies in the chunks of :attr:`dirty` and,
    for the segment ends, in the robot's rectangle :attr:`rect`. The next classification
    writes only the chunks it classifies or the last one wrote, so a cycle reads and
    writes the whole images only where the scene is not static (a copy of three images a
    camera costs more than the rest of the classification: the cycle is bound by memory
    traffic).

    Attributes:
        free: (H, W) float32 free depth.
        end: (H, W) float32 segment ends.
        invalid: (H, W) pixels with no usable reading.
        dirty: (H, ceil(W / CHUNK)) row chunks where ``free`` or ``invalid`` differ from
            the static images.
        changed: (ceil(H / BLOCK), ceil(W / BLOCK)) blocks the last classification wrote
            (where the free depth pyramids must be updated).
        end_changed: The blocks where the last classification wrote ``end`` (the last and
            this robot rectangle and edge wedges: where the segment ends' pyramids must be
            updated).
        rect: (u0, u1, v0, v1) where ``end`` may differ from ``f_s`` (empty: u1 < u0).
        wedges: (m, 2) the edge pixels (v, u) whose ``end`` is their own free depth
            (:mod:`polyhull.engine.edge_wedges`); ``end`` differs from ``f_s`` there too.
        sheets: (n_v, n_u) the tiles whose ``end`` is the empty cell's free depth (sheet
            tiles), or None before the first classification.
    """

    def __init__(self, static: StaticClasses, free_static: ArrayF32, free: ArrayF32 | None = None, end: ArrayF32 | None = None) -> None:
        """Buffers holding the static images (``free`` and ``end`` are written here: views
        of a cycle's image stacks, or new arrays when None)."""
        H, W = free_static.shape
        self.free = np.empty((H, W), dtype=np.float32) if free is None else free
        self.end = np.empty((H, W), dtype=np.float32) if end is None else end
        self.free[:] = static.free0
        self.end[:] = free_static
        self.invalid = np.zeros((H, W), dtype=np.bool_)
        self.dirty = np.zeros((H, -(-W // CHUNK)), dtype=np.bool_)
        self.changed = np.zeros((-(-H // BLOCK), -(-W // BLOCK)), dtype=np.bool_)
        self.end_changed = np.zeros_like(self.changed)
        self.rect = np.array([0, -1, 0, -1], dtype=np.int64)
        self.wedges = _NO_WEDGES
        self.sheets: np.ndarray | None = None


@nb.njit(cache=True, nogil=True, inline="always")
def _exact_free(d, b, a, tmin):  # pragma: no cover - compiled
    """The exact free depth ``min(D, B) - tau(D)`` of a usable reading ``d`` [m]
    (``b``: the reference depth, capped at the range)."""
    return min(d, b) - max(a * d * d, tmin)


@nb.njit(cache=True, nogil=True, inline="always")
def _mark_tile(changed, tv, tu, tile, H, W):  # pragma: no cover - compiled
    """Mark the blocks of ``changed`` that tile (tv, tu) of edge ``tile`` covers."""
    for bv in range(tv * tile // BLOCK, (min((tv + 1) * tile, H) - 1) // BLOCK + 1):
        for bu in range(tu * tile // BLOCK, (min((tu + 1) * tile, W) - 1) // BLOCK + 1):
            changed[bv, bu] = True


@nb.njit(cache=True, nogil=True, inline="always")
def _in_front(d, t, near, far):  # pragma: no cover - compiled
    """A valid reading ``d`` in front of its static band (lower bound ``t``)."""
    return d >= near and d <= far and d < t


@nb.njit(cache=True, nogil=True, inline="always")
def _surface_end(out_end, fe, shadow, v, u, sv0, sv1, su0, su1):  # pragma: no cover - compiled
    """Run pixel (v, u)'s segment to the empty cell's free depth ``fe`` (or the robot's
    shadow start when nearer), never shortening it."""
    e32 = fe[v, u]
    if v >= sv0 and v <= sv1 and u >= su0 and u <= su1:
        e32 = min(e32, shadow[v, u])
    out_end[v, u] = max(out_end[v, u], e32)


@nb.njit(cache=True, nogil=True, inline="always")
def _static_end(fs, shadow, v, u, sv0, sv1, su0, su1):  # pragma: no cover - compiled
    """A static pixel's segment end: ``f_s``, or the robot's shadow start when nearer (read
    only inside the shadow rectangle ``[su0, su1] x [sv0, sv1]``)."""
    if v >= sv0 and v <= sv1 and u >= su0 and u <= su1:
        return min(fs[v, u], shadow[v, u])
    return fs[v, u]


@nb.njit(cache=True, nogil=True)
def _classify(depth, band, B, T, U, fs, fe, free0, edge, edge_chunks, shadow, rect, prev_rect, wedge_vu, wedge_end, prev_wedge_vu, applied, sheet_cand, sheet_reach, sheet_z, sheet_end, margin, lift, prev_sheet, out_sheet, near, far, a, tmin, is_color, out_free, out_end, out_invalid, tile, out_tiles, dirty, changed):  # pragma: no cover - compiled
    """Classify a frame into buffers holding the last classification (:class:`PixelBuffers`):
    only the row chunks holding a reading not surely in the band (the packed ``band`` of
    :class:`StaticClasses`, then ``T``/``U``: every reading is "in the band" where ``f_s <=
    near``, except NaN) are classified pixel by pixel, and written whole; a chunk the last
    classification wrote and this one does not is put back to the static images. A static
    pixel frees ``free0`` and its segment (to ``f_s``, or to the robot's shadow start) is
    empty; a static edge pixel (``edge``, in the chunks of ``edge_chunks``, classified
    every cycle) frees its reading's exact free depth, at least ``free0``. A pixel seeing a
    surface in front of the band (a valid reading there in it and its 8 neighbours) ends
    its segment at ``fe``, the empty cell's free depth ``B - tau(B)`` (or the robot's
    shadow start), not at ``f_s``: the empty cell shows it the space behind what it sees,
    which is not M; a pixel without a reading, beyond its band, or an isolated flying pixel
    keeps ``f_s`` (the band's declared tolerance of M). These pixels already have a
    segment, in a chunk already written. The candidate edge pixels ``wedge_vu`` (v, u)
    within ``WEDGE_REACH`` px of a valid non-edge reading with a segment end their
    segments at ``wedge_end`` (or the robot's shadow start), so a reading in front of
    their own band has a segment there (``applied``, (m,) bool, says which); the last
    cycle's applied ones, ``prev_wedge_vu``, are put back first. The candidate sheet tiles
    ``sheet_cand`` (:class:`polyhull.engine.edge_wedges.SheetTiles`) within their
    ``sheet_reach`` [tiles] of a tile holding such a surface not on the robot's image and
    within ``lift`` [m] in front of the reference (a lower leg), at a depth within
    ``margin`` of the sheet's depths ``sheet_z`` (2, n_v, n_u), end every non-edge pixel's
    segment at ``sheet_end``, its sheet's part outside ``C_static`` (``out_sheet`` says
    which; the last cycle's, ``prev_sheet``, are put back first). ``dirty`` and ``changed`` are updated (see
    :class:`PixelBuffers`); ``changed`` also marks where ``end`` was written."""
    H, W = depth.shape
    out_tiles[:, :] = False
    out_sheet[:, :] = False
    changed[:, :] = False
    su0, su1, sv0, sv1 = rect[0], rect[1], rect[2], rect[3]
    n_invalid = 0
    n_far = 0
    n_seg = 0
    for v in range(prev_rect[2], prev_rect[3] + 1):  # the last robot rectangle's ends
        for u in range(prev_rect[0], prev_rect[1] + 1):
            out_end[v, u] = fs[v, u]
    for v in range(sv0, sv1 + 1):  # the shadow image is +inf outside the rectangle
        for u in range(su0, su1 + 1):
            out_end[v, u] = min(fs[v, u], shadow[v, u])
    for w in range(prev_wedge_vu.shape[0]):  # the last cycle's edge wedges
        v, u = prev_wedge_vu[w, 0], prev_wedge_vu[w, 1]
        out_end[v, u] = _static_end(fs, shadow, v, u, sv0, sv1, su0, su1)
    for tv in range(prev_sheet.shape[0]):  # the last cycle's sheet tiles
        for tu in range(prev_sheet.shape[1]):
            if prev_sheet[tv, tu]:
                for v in range(tv * tile, min((tv + 1) * tile, H)):
                    for u in range(tu * tile, min((tu + 1) * tile, W)):
                        if not edge[v, u]:
                            out_end[v, u] = _static_end(fs, shadow, v, u, sv0, sv1, su0, su1)
                _mark_tile(changed, tv, tu, tile, H, W)
    for v in range(H):
        for ci in range(dirty.shape[1]):
            c0 = ci * CHUNK
            c1 = min(c0 + CHUNK, W)
            hit = edge_chunks[v, ci]
            ok = True  # bitwise, not short-circuit: the loop compiles branch-free
            for u in range(c0, c1):
                dm = np.float32(1000.0) * depth[v, u]
                p = band[v, u]
                tq = np.float32(p & 0xFFFF)
                uq = np.float32(p >> 16)
                ok &= (dm >= tq) & ((dm <= uq) | (uq == np.float32(65535.0)))
            hit |= not ok
            was = dirty[v, ci]
            if not hit:
                if was:  # back to the static images
                    for u in range(c0, c1):
                        out_free[v, u] = free0[v, u]
                        out_invalid[v, u] = False
                        out_end[v, u] = _static_end(fs, shadow, v, u, sv0, sv1, su0, su1)
                    dirty[v, ci] = False
                    changed[v // BLOCK, c0 // BLOCK] = True
                    changed[v // BLOCK, (c1 - 1) // BLOCK] = True
                continue
            now = False
            for u in range(c0, c1):
                d = np.float64(depth[v, u])
                if d >= T[v, u] and d <= U[v, u]:
                    if edge[v, u] and d >= near and d <= far:
                        # a static edge: the band is the neighbourhood's (flying pixels), so
                        # f_s is the nearer surface's; this reading's exact free depth is at
                        # least that (f_s is its least over the band), rounded toward the camera
                        fr = max(down32(_exact_free(d, min(np.float64(B[v, u]), far), a, tmin)), free0[v, u])
                        out_free[v, u] = fr
                        out_invalid[v, u] = False
                        now |= fr != free0[v, u]
                    elif was:
                        out_free[v, u] = free0[v, u]
                        out_invalid[v, u] = False
                    if was:
                        out_end[v, u] = _static_end(fs, shadow, v, u, sv0, sv1, su0, su1)
                    continue
                f_s = np.float64(fs[v, u])
                bad = False
                if f_s <= near:
                    free = near
                else:
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
                        bad = True
                        f = near
                    elif is_color:
                        f = near if de < T[v, u] else f_s
                    else:
                        f = _exact_free(de, b, a, tmin)
                    if usable and d > U[v, u] and d != np.inf:
                        n_far += 1
                    free = min(max(f, near), f_s)
                # f_s, or the shadow start when nearer (a surface seen in front of the band
                # runs farther: the pass after this one)
                e32 = _static_end(fs, shadow, v, u, sv0, sv1, su0, su1)
                out_end[v, u] = e32
                end = np.float64(e32)
                # float32 storage rounds toward the camera (free): the segment only grows
                fr = down32(free)
                out_free[v, u] = fr
                out_invalid[v, u] = bad
                now |= fr != free0[v, u] or bad
                if fr < end:
                    n_seg += 1
                    out_tiles[v // tile, u // tile] = True
            dirty[v, ci] = now
            if now or was:
                changed[v // BLOCK, c0 // BLOCK] = True
                changed[v // BLOCK, (c1 - 1) // BLOCK] = True
    # a surface seen in front of the band runs to the empty cell's free depth, and near a
    # lower leg seen, so do the candidate sheet tiles (:func:`_surfaces`, :func:`_sheets`)
    if not is_color and n_seg > 0:
        rect4 = (sv0, sv1, su0, su1)
        seen_lo, seen_hi, any_seen = _surfaces(depth, B, T, fs, fe, shadow, rect4, near, far, lift, out_free, out_end, tile, out_tiles)
        if any_seen:
            _sheets(
                fs, edge, shadow, rect4, sheet_cand, sheet_reach, sheet_z, sheet_end, margin, seen_lo, seen_hi,
                out_free, out_end, tile, out_tiles, out_sheet, changed,
            )
    # a candidate edge wedge runs to its own free depth where something is seen next to it:
    # a valid reading with a segment, not at a static edge, within WEDGE_REACH px
    for w in range(wedge_vu.shape[0]):
        v, u = wedge_vu[w, 0], wedge_vu[w, 1]
        seen = False
        for qv in range(max(v - WEDGE_REACH, 0), min(v + WEDGE_REACH + 1, H)):
            for qu in range(max(u - WEDGE_REACH, 0), min(u + WEDGE_REACH + 1, W)):
                seen |= not edge[qv, qu] and not out_invalid[qv, qu] and out_free[qv, qu] < out_end[qv, qu]
        applied[w] = seen
        if not seen:
            continue
        inside = v >= sv0 and v <= sv1 and u >= su0 and u <= su1
        before = out_end[v, u]
        out_end[v, u] = min(wedge_end[w], shadow[v, u]) if inside else wedge_end[w]
        if out_free[v, u] < out_end[v, u] and not out_free[v, u] < before:
            n_seg += 1
            out_tiles[v // tile, u // tile] = True
    return n_seg, n_invalid, n_far


@nb.njit(cache=True, nogil=True)
def _surfaces(depth, B, T, fs, fe, shadow, rect, near, far, lift, out_free, out_end, tile, out_tiles):  # pragma: no cover - compiled
    """A surface seen in front of the band (a valid reading there, and in all 8 neighbours,
    not an isolated flying pixel) hides what the empty cell shows the pixel up to its free
    depth ``fe``: the segment runs there (or to the robot's shadow start, inside ``rect``
    (v0, v1, u0, u1), when nearer); so does the surface's border, a valid reading in front
    of the band next to its interior (a foot's silhouette, with the floor beside it in the
    band). Visits the marked tiles. Returns, per tile, the least and greatest depth of the
    surface pixels off the robot's image within ``lift`` [m] in front of their reference (a
    lower leg; lo > hi: none), and whether there is any."""
    H, W = depth.shape
    sv0, sv1, su0, su1 = rect
    surface = np.zeros((H, W), dtype=np.bool_)
    seen_lo = np.full(out_tiles.shape, np.inf)
    seen_hi = np.full(out_tiles.shape, -np.inf)
    any_seen = False
    # the marked tiles' pixels off the image's border (the 3 x 3 tests): (tv, tu, v0, v1, u0, u1)
    cells = _tile_cells(out_tiles, tile, 1, H - 1, 1, W - 1)
    for k in range(cells.shape[0]):
        tv, tu = cells[k, 0], cells[k, 1]
        for v in range(cells[k, 2], cells[k, 3]):
            for u in range(cells[k, 4], cells[k, 5]):
                if fe[v, u] <= fs[v, u] or not out_free[v, u] < out_end[v, u]:
                    continue
                whole = True
                for qv in range(v - 1, v + 2):
                    for qu in range(u - 1, u + 2):
                        whole &= _in_front(depth[qv, qu], T[qv, qu], near, far)
                if not whole:
                    continue
                surface[v, u] = True
                _surface_end(out_end, fe, shadow, v, u, sv0, sv1, su0, su1)
                d = np.float64(depth[v, u])
                on_robot = v >= sv0 and v <= sv1 and u >= su0 and u <= su1 and shadow[v, u] < np.inf
                if not on_robot and np.float64(B[v, u]) - d <= lift:
                    seen_lo[tv, tu] = min(seen_lo[tv, tu], d)
                    seen_hi[tv, tu] = max(seen_hi[tv, tu], d)
                    any_seen = True
    for k in range(cells.shape[0]):  # then their borders (the interior is complete)
        for v in range(cells[k, 2], cells[k, 3]):
            for u in range(cells[k, 4], cells[k, 5]):
                if surface[v, u] or fe[v, u] <= fs[v, u] or not out_free[v, u] < out_end[v, u]:
                    continue
                if not _in_front(depth[v, u], T[v, u], near, far):
                    continue
                border = False
                for qv in range(v - 1, v + 2):
                    for qu in range(u - 1, u + 2):
                        border |= surface[qv, qu]
                if border:
                    _surface_end(out_end, fe, shadow, v, u, sv0, sv1, su0, su1)
    return seen_lo, seen_hi, any_seen


@nb.njit(cache=True, nogil=True)
def _tile_cells(tiles, tile, v_lo, v_hi, u_lo, u_hi):  # pragma: no cover - compiled
    """(m, 6) the marked ``tiles`` (edge ``tile`` px) as rows (tv, tu, v0, v1, u0, u1): their
    pixel ranges [v0, v1) x [u0, u1), clipped to [v_lo, v_hi) x [u_lo, u_hi)."""
    out = np.empty((int(tiles.sum()), 6), dtype=np.int64)
    m = 0
    for tv in range(tiles.shape[0]):
        for tu in range(tiles.shape[1]):
            if tiles[tv, tu]:
                out[m, 0], out[m, 1] = tv, tu
                out[m, 2], out[m, 3] = max(tv * tile, v_lo), min((tv + 1) * tile, v_hi)
                out[m, 4], out[m, 5] = max(tu * tile, u_lo), min((tu + 1) * tile, u_hi)
                m += 1
    return out


@nb.njit(cache=True, nogil=True)
def _sheets(fs, edge, shadow, rect, cand, reach, sheet_z, sheet_end, margin, seen_lo, seen_hi, out_free, out_end, tile, out_tiles, out_sheet, changed):  # pragma: no cover - compiled
    """The band sheets another camera's robot shadow may cross (``cand``), within a person's
    feet's reach of a lower leg seen (``reach`` tiles in the image, ``margin`` [m] from the
    sheet's depths ``sheet_z`` in depth; the legs' depths per tile ``seen_lo``/``seen_hi``):
    a foot in the sheet reads as the surface. Their non-edge pixels' segments run to
    ``sheet_end`` (or the robot's shadow start inside ``rect``); ``out_sheet`` and
    ``changed`` mark the tiles."""
    H, W = fs.shape
    sv0, sv1, su0, su1 = rect
    n_tv, n_tu = out_tiles.shape
    for tv in range(n_tv):
        for tu in range(n_tu):
            r = reach[tv, tu]
            if not cand[tv, tu] or r <= 0:
                continue
            near_seen = False
            z0 = sheet_z[0, tv, tu] - margin
            z1 = sheet_z[1, tv, tu] + margin
            for qv in range(max(tv - r, 0), min(tv + r + 1, n_tv)):
                for qu in range(max(tu - r, 0), min(tu + r + 1, n_tu)):
                    near_seen |= seen_lo[qv, qu] <= z1 and seen_hi[qv, qu] >= z0
            if not near_seen:
                continue
            out_sheet[tv, tu] = True
            _mark_tile(changed, tv, tu, tile, H, W)
            for v in range(tv * tile, min((tv + 1) * tile, H)):
                for u in range(tu * tile, min((tu + 1) * tile, W)):
                    if edge[v, u] or sheet_end[v, u] <= fs[v, u]:
                        continue
                    _surface_end(out_end, sheet_end, shadow, v, u, sv0, sv1, su0, su1)
                    if out_free[v, u] < out_end[v, u]:
                        out_tiles[tv, tu] = True


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
    tile: int = 8,
    shadow_rect: tuple[int, int, int, int] | None = None,
    static: StaticClasses | None = None,
    buffers: PixelBuffers | None = None,
    edge: np.ndarray | None = None,
    wedges: tuple[np.ndarray, np.ndarray] | None = None,
    free_empty: ArrayF32 | None = None,
    sheets: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float] | None = None,
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
        tile: Edge [px] of the tiles of :attr:`PixelClasses.tiles`.
        shadow_rect: (u0, u1, v0, v1) inclusive rectangle outside which ``shadow_start`` is
            +inf (not read there); None: the whole image.
        static: :func:`prepare_static` of ``lower``, ``upper``, ``free_static`` and
            ``near`` (made here when None; a monitor makes it once).
        buffers: The camera's :class:`PixelBuffers` (with this ``static`` and
            ``free_static``), written and returned in the classes; new ones when None.
        edge: (H, W) the static edge pixels (used when ``static`` is None): a reading in
            their band frees its exact free depth.
        wedges: ((m, 2) edge pixels (v, u), (m,) their segment ends [m]): the edge pixels
            whose segment may run to their own band's free depth this cycle
            (:meth:`polyhull.engine.edge_wedges.EdgeWedges.ends`); it does where a valid
            reading with a segment, not at an edge, lies within ``WEDGE_REACH`` px. None:
            none.
        free_empty: (H, W) the empty cell's free depth ``B - tau(B)`` [m]
            (:attr:`polyhull.engine.static_model.StaticCamera.free_empty`), where the
            segment of a surface seen in front of the band ends; None: ``free_static``.
        sheets: ((n_v, n_u) bool, (n_v, n_u) int, (2, n_v, n_u) float, (H, W) float32,
            margin [m], lift [m]) the tiles whose band sheet may meet another camera's
            robot shadow this cycle, their reach [tiles] and sheet depths [m], the pixels'
            sheet ends [m], the floor shell's lateral margin and the depth before the
            reference within which a surface seen is a lower leg
            (:class:`polyhull.engine.edge_wedges.SheetTiles`): within its reach of such a
            surface, seen in front of the band, not on the robot's image, at a depth within
            the margin of its sheet, such a tile's segments run to their sheet ends. None:
            none.
    """
    H, W = free_static.shape
    if static is None:
        static = prepare_static(lower, upper, free_static, near, edge)
    if buffers is None:
        buffers = PixelBuffers(static, free_static)
    tile = int(tile)
    rect = np.array((0, W - 1, 0, H - 1) if shadow_rect is None else shadow_rect, dtype=np.int64)
    out_tiles = np.empty(((H + tile - 1) // tile, (W + tile - 1) // tile), dtype=np.bool_)
    b = buffers
    if wedges is None:
        wedge_vu, wedge_end = _NO_WEDGES, np.zeros(0, dtype=np.float32)
    else:
        wedge_vu = np.ascontiguousarray(wedges[0], dtype=np.int64).reshape(-1, 2)
        wedge_end = np.ascontiguousarray(wedges[1], dtype=np.float32)
    applied = np.zeros(len(wedge_vu), dtype=np.bool_)
    if sheets is None:
        sheet_cand, sheet_reach = np.zeros(out_tiles.shape, dtype=np.bool_), np.zeros(out_tiles.shape, dtype=np.int64)
        sheet_z, sheet_end, margin, lift = np.zeros((2, *out_tiles.shape)), free_static, 0.0, 0.0
    else:
        sheet_cand, sheet_reach = sheets[0], np.asarray(sheets[1], dtype=np.int64)
        sheet_z, sheet_end = np.asarray(sheets[2], dtype=np.float64), sheets[3]
        margin, lift = float(sheets[4]), float(sheets[5])
    prev_sheet = b.sheets if b.sheets is not None and b.sheets.shape == out_tiles.shape else np.zeros(out_tiles.shape, dtype=np.bool_)
    out_sheet = np.zeros(out_tiles.shape, dtype=np.bool_)
    n_seg, n_invalid, n_far = _classify(
        depth, static.band, reference, static.lower, static.upper, free_static,
        free_static if free_empty is None else free_empty, static.free0, static.edge,
        static.edge_chunks, shadow_start, rect, b.rect, wedge_vu, wedge_end, b.wedges, applied,
        sheet_cand, sheet_reach, sheet_z, sheet_end, margin, lift, prev_sheet, out_sheet,
        float(near), float(far), float(tau_a), float(tau_min), bool(is_color), b.free, b.end, b.invalid,
        tile, out_tiles, b.dirty, b.changed,
    )
    b.sheets = out_sheet
    b.end_changed[:] = b.changed  # the chunks classified (an unexplained pixel's end)
    for u0, u1, v0, v1 in (b.rect, rect):
        if u1 >= u0 and v1 >= v0:
            b.end_changed[v0 // BLOCK : v1 // BLOCK + 1, u0 // BLOCK : u1 // BLOCK + 1] = True
    wedge_vu = wedge_vu[applied]
    for vu in (b.wedges, wedge_vu):
        b.end_changed[vu[:, 0] // BLOCK, vu[:, 1] // BLOCK] = True
    b.rect = rect
    b.wedges = wedge_vu
    seen = max(static.seen, 1)
    return PixelClasses(b.free, b.end, int(n_seg), b.invalid, n_invalid / seen, n_far / seen, out_tiles)


@nb.njit(cache=True, nogil=True)
def _small_gaps(free, end, invalid, fs, near, fx, fy, size, tile, tiles):  # pragma: no cover - compiled
    """(G, 3) rows (v, u, new free depth) of the pixels of the 8-connected clusters of
    segment pixels without a reading (``free < end`` and ``invalid``) whose segments
    :func:`small_gaps` frees, wholly or in part: one pass over the marked ``tiles`` (edge
    ``tile`` px; segment pixels lie only in them), each cluster followed from its first pixel
    (:func:`_gap_cluster`)."""
    H, W = free.shape
    # the candidates first (a tight scan into an array that never grows: an array
    # reassigned in the loop costs reference counting per pixel), then their clusters
    room = 0
    for tb in range(tiles.shape[0]):
        for ub in range(tiles.shape[1]):
            if tiles[tb, ub]:
                room += (min((tb + 1) * tile, H) - tb * tile) * (min((ub + 1) * tile, W) - ub * tile)
    cand = np.empty((room, 2), dtype=np.int64)
    nc = 0
    for tb in range(tiles.shape[0]):
        for ub in range(tiles.shape[1]):
            if not tiles[tb, ub]:
                continue
            for v in range(tb * tile, min((tb + 1) * tile, H)):
                for u in range(ub * tile, min((ub + 1) * tile, W)):
                    if invalid[v, u] and free[v, u] < end[v, u]:
                        cand[nc, 0] = v
                        cand[nc, 1] = u
                        nc += 1
    seen = np.zeros((H, W), dtype=np.bool_)
    stack = np.empty((64, 2), dtype=np.int64)
    comp = np.empty((64, 2), dtype=np.int64)
    out = np.empty((64, 3), dtype=np.float64)
    n_out = 0
    for c in range(nc):
        v, u = cand[c, 0], cand[c, 1]
        if not seen[v, u]:
            stack, comp, out, n_out = _gap_cluster(
                v, u, free, end, invalid, fs, near, fx, fy, size, seen, stack, comp, out, n_out
            )
    return out[:n_out]


@nb.njit(cache=True, nogil=True)
def _gap_cluster(v, u, free, end, invalid, fs, near, fx, fy, size, seen, stack, comp, out, n_out):  # pragma: no cover - compiled
    """Follow the cluster of pixel (v, u) (a stack); append its pixels to ``out`` when it
    is a small gap. Returns the (possibly grown) work arrays and the count in ``out``."""
    H, W = free.shape
    seen[v, u] = True
    stack[0, 0] = v
    stack[0, 1] = u
    ns = 1
    nc = 0
    u0, u1, v0, v1 = u, u, v, v
    zmax = 0.0
    closed = True
    while ns > 0:
        ns -= 1
        pv, pu = stack[ns, 0], stack[ns, 1]
        comp = push_row(comp, nc, (pv, pu))
        nc += 1
        u0 = min(u0, pu)
        u1 = max(u1, pu)
        v0 = min(v0, pv)
        v1 = max(v1, pv)
        zmax = max(zmax, np.float64(end[pv, pu]))
        for dv in range(-1, 2):
            for du in range(-1, 2):
                qv, qu = pv + dv, pu + du
                if qv < 0 or qv >= H or qu < 0 or qu >= W:
                    closed = False
                    continue
                if invalid[qv, qu] and free[qv, qu] < end[qv, qu]:
                    if not seen[qv, qu]:
                        seen[qv, qu] = True
                        stack = push_row(stack, ns, (qv, qu))
                        ns += 1
                elif not _explained(free[qv, qu], end[qv, qu], fs[qv, qu], invalid[qv, qu], near):
                    closed = False
    if not closed:
        return stack, comp, out, n_out
    # nearer than zcut the cluster's rays are narrower than ``size`` on one image axis at
    # least; an object of that cross-section lies beyond zcut - size / 2 (its widest
    # section is where it fits, its points within half its size of it): free to zcut - size
    zcut = size * min(fx / (u1 - u0 + 3), fy / (v1 - v0 + 3))
    whole = (u1 - u0 + 3) * zmax / fx < size and (v1 - v0 + 3) * zmax / fy < size
    lim = down32(zcut - size)
    for c in range(nc):
        pv, pu = comp[c, 0], comp[c, 1]
        to = end[pv, pu] if whole else min(end[pv, pu], lim)
        if to > free[pv, pu]:
            out = push_row(out, n_out, (np.float64(pv), np.float64(pu), np.float64(to)))
            n_out += 1
    return stack, comp, out, n_out


@nb.njit(cache=True, nogil=True, inline="always")
def _explained(free, end, fs, invalid, near):  # pragma: no cover - compiled
    """A pixel around a small gap: it reads the static scene (free to its static free depth),
    or a reading explained by the robot (valid, freeing something, no segment behind it)."""
    if fs > near and free >= fs:
        return True
    return not invalid and free > near and free >= end


def small_gaps(
    free: ArrayF32, end: ArrayF32, invalid: np.ndarray, free_static: ArrayF32, near: float, fx: float, fy: float, size: float
) -> ArrayF32:
    """(H, W) the free depth once the segments of pixels without a reading are freed where
    they are too narrow to hide an object of ``size`` [m] (float32; ``free`` elsewhere).

    Only pixels with no usable reading (dropouts, out of range) are candidates: a valid
    reading in front of the background is an observation (a hand seen through a gap) and
    is never filled. Their segments (``free < end``) are grouped into 8-connected
    clusters. When every pixel around a cluster reads the static scene (free to its static
    free depth) or the robot (a valid reading explained by the padded robot: free to its
    shadow start, no segment), an object in the cluster's segments is walled in by free
    pixel footprints, or reaches beyond them only into the static region or the robot's
    shadow behind them: its cross-section in the cluster's rays at z-depth z is under
    ``(extent + 2) px * z / f``. Where that is under ``size`` on both image axes, the
    cluster cannot hide an object the system is declared to detect (its detection
    capability) that shows no reading at all: a dropout patch, out-of-range pixels.

    - When it is under ``size`` at the cluster's farthest segment end (on the robot's
      image, its shadow start: the segments never run behind it), the cluster's segments
      are freed whole.
    - Otherwise the rays widen to ``size`` at ``zcut``: an object of that cross-section
      has its widest section beyond ``zcut`` and every point within half its size of that
      section, so the segments are freed up to ``zcut - size`` (half a size to spare), and
      their far part stays. A patch at 6.6 m (a camera across the cell) then keeps only its
      last decimetres instead of a column through the cell's middle.

    Clusters at the image border, next to pixels that see nothing, or next to a person or
    a flying pixel (a reading with a segment), are never freed.
    """
    out = free.copy()
    vu, to = small_gap_pixels(free, end, invalid, free_static, near, fx, fy, size)
    out[vu[:, 0], vu[:, 1]] = to
    return out


def small_gap_pixels(
    free: ArrayF32,
    end: ArrayF32,
    invalid: np.ndarray,
    free_static: ArrayF32,
    near: float,
    fx: float,
    fy: float,
    size: float,
    tiles: tuple[int, np.ndarray] | None = None,
) -> tuple[np.ndarray, ArrayF32]:
    """The pixels :func:`small_gaps` frees (without an image-sized mask): (G, 2) their
    (v, u) and (G,) their new free depth (float32, above ``free``, at most ``end``).
    ``tiles``: (edge [px], grid) the tiles that may hold a segment pixel
    (:attr:`PixelClasses.tiles`), the only ones visited; None: all."""
    if tiles is None:
        tile, grid = 1 << 30, np.ones((1, 1), dtype=np.bool_)
    else:
        tile, grid = int(tiles[0]), tiles[1]
    rows = _small_gaps(free, end, invalid, free_static, float(near), float(fx), float(fy), float(size), tile, grid)
    return rows[:, :2].astype(np.int64), rows[:, 2].astype(np.float32)


@nb.njit(cache=True, nogil=True)
def _only_marked(rects, free, end, mark, out):  # pragma: no cover - compiled
    for k in range(rects.shape[0]):
        seg = False
        ok = True
        for v in range(rects[k, 2], rects[k, 3] + 1):
            for u in range(rects[k, 0], rects[k, 1] + 1):
                if free[v, u] < end[v, u]:
                    seg = True
                    if not mark[v, u]:
                        ok = False
                        break
            if not ok:
                break
        out[k] = ok and seg


def only_marked_segments(rects: np.ndarray, free: ArrayF32, end: ArrayF32, mark: np.ndarray) -> np.ndarray:
    """(N,) whether every segment pixel (``free < end``) in each pixel rectangle ``rects``
    (N, 4): u0, u1, v0, v1 (inclusive, inside the image) is ``mark``-ed, and there is one:
    e.g. pieces made only of the far part of :func:`small_gaps`' clusters."""
    out = np.zeros(len(rects), dtype=np.bool_)
    if len(rects):
        _only_marked(np.ascontiguousarray(rects, dtype=np.int64), free, end, mark, out)
    return out


@nb.njit(cache=True, nogil=True)
def _window_range(img, rects, lo, hi):  # pragma: no cover - compiled
    for i in range(rects.shape[0]):
        a = np.inf
        b = -np.inf
        for v in range(rects[i, 2], rects[i, 3] + 1):
            for u in range(rects[i, 0], rects[i, 1] + 1):
                x = np.float64(img[v, u])
                a = min(a, x)
                b = max(b, x)
        lo[i] = a
        hi[i] = b


def window_range(img: np.ndarray, rects: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of ``img`` over each pixel rectangle ``rects`` (N, 4): u0, u1, v0, v1
    (inclusive, inside the image)."""
    lo = np.empty(len(rects))
    hi = np.empty(len(rects))
    _window_range(img, np.ascontiguousarray(rects, dtype=np.int64), lo, hi)
    return lo, hi


def pyramid_layout(H: int, W: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (L,) and (rows, cols) shapes (L, 2) of the levels of an (H, W) image's
    min/max pyramid (level l has 2^l x 2^l pixel cells). Level 0 is the image itself
    (offset 0, not stored); levels 1.. are flattened one after the other from offset 0."""
    shapes = [(H, W)]
    while shapes[-1][0] > 1 or shapes[-1][1] > 1:
        h, w = shapes[-1]
        shapes.append((-(-h // 2), -(-w // 2)))
    shp = np.array(shapes, dtype=np.int64)
    offsets = np.zeros(len(shp), dtype=np.int64)
    offsets[2:] = np.cumsum(shp[1:-1, 0] * shp[1:-1, 1])
    return offsets, shp


@nb.njit(cache=True, nogil=True)
def _build_pyramid(free, mins, maxs, offsets, shapes):  # pragma: no cover - compiled
    H, W = free.shape
    if shapes.shape[0] > 1:
        h1, w1 = shapes[1, 0], shapes[1, 1]
        for r in range(h1):
            # a cell past the last row or column repeats it (no change to min or max)
            ra = 2 * r
            rb = min(2 * r + 1, H - 1)
            for c in range(w1):
                c0 = 2 * c
                c1 = min(c0 + 1, W - 1)
                x0, x1, x2, x3 = free[ra, c0], free[ra, c1], free[rb, c0], free[rb, c1]
                mins[r * w1 + c] = min(min(x0, x1), min(x2, x3))
                maxs[r * w1 + c] = max(max(x0, x1), max(x2, x3))
    for lev in range(2, shapes.shape[0]):
        h0, w0 = shapes[lev - 1, 0], shapes[lev - 1, 1]
        h1, w1 = shapes[lev, 0], shapes[lev, 1]
        o0, o1 = offsets[lev - 1], offsets[lev]
        for r in range(h1):
            a = o0 + 2 * r * w0
            b = o0 + min(2 * r + 1, h0 - 1) * w0
            for c in range(w1):
                c0 = 2 * c
                c1 = min(c0 + 1, w0 - 1)
                mins[o1 + r * w1 + c] = min(min(mins[a + c0], mins[a + c1]), min(mins[b + c0], mins[b + c1]))
                maxs[o1 + r * w1 + c] = max(max(maxs[a + c0], maxs[a + c1]), max(maxs[b + c0], maxs[b + c1]))


@nb.njit(cache=True, nogil=True)
def _update_pyramid(free, mins, maxs, offsets, shapes, changed):  # pragma: no cover - compiled
    """Levels 1..3 only in the ``changed`` blocks (BLOCK = 8 px: a level-3 cell each),
    the coarser levels (1/64 of the pixels) whole; the layout as in :func:`_build_pyramid`."""
    H, W = free.shape
    for lev in range(1, shapes.shape[0]):
        h0, w0 = shapes[lev - 1, 0], shapes[lev - 1, 1]
        h1, w1 = shapes[lev, 0], shapes[lev, 1]
        o0, o1 = offsets[lev - 1], offsets[lev]
        for bv in range(changed.shape[0] if lev <= 3 else 1):
            for bu in range(changed.shape[1] if lev <= 3 else 1):
                if lev <= 3:
                    if not changed[bv, bu]:
                        continue
                    k = 1 << (3 - lev)
                    r0, r1, c0_, c1_ = bv * k, min((bv + 1) * k, h1), bu * k, min((bu + 1) * k, w1)
                else:
                    r0, r1, c0_, c1_ = 0, h1, 0, w1
                for r in range(r0, r1):
                    ra = 2 * r
                    rb = min(2 * r + 1, h0 - 1)
                    for c in range(c0_, c1_):
                        ca = 2 * c
                        cb = min(ca + 1, w0 - 1)
                        if lev == 1:
                            x0, x1, x2, x3 = free[ra, ca], free[ra, cb], free[rb, ca], free[rb, cb]
                            mins[o1 + r * w1 + c] = min(min(x0, x1), min(x2, x3))
                            maxs[o1 + r * w1 + c] = max(max(x0, x1), max(x2, x3))
                        else:
                            a = o0 + ra * w0
                            b = o0 + rb * w0
                            mins[o1 + r * w1 + c] = min(min(mins[a + ca], mins[a + cb]), min(mins[b + ca], mins[b + cb]))
                            maxs[o1 + r * w1 + c] = max(max(maxs[a + ca], maxs[a + cb]), max(maxs[b + ca], maxs[b + cb]))


def update_pyramid(
    free: ArrayF32, mins: ArrayF32, maxs: ArrayF32, offsets: np.ndarray, shapes: np.ndarray, changed: np.ndarray
) -> None:
    """Bring the pyramids of :func:`build_pyramid` up to date after ``free`` changed only in
    the ``changed`` blocks (BLOCK x BLOCK pixels, :attr:`PixelBuffers.changed`)."""
    _update_pyramid(free, mins, maxs, offsets, shapes, changed)


def build_pyramid(free: ArrayF32, mins: ArrayF32, maxs: ArrayF32, offsets: np.ndarray, shapes: np.ndarray) -> None:
    """Write the levels 1.. of the min and max pyramids of an (H, W) free depth image into
    ``mins`` and ``maxs`` (flat, laid out by :func:`pyramid_layout`; level 0 is the image
    itself; range queries for carving)."""
    _build_pyramid(free, mins, maxs, offsets, shapes)


@nb.njit(cache=True, nogil=True)
def push_row(out, n, row):  # pragma: no cover - compiled
    """Write ``row`` (a tuple of floats) as row ``n`` of ``out``, doubling ``out`` when it
    is full; returns the (possibly new) array."""
    if n == out.shape[0]:
        grown = np.empty((2 * out.shape[0], out.shape[1]), dtype=out.dtype)
        grown[:n] = out[:n]
        out = grown
    for j in range(len(row)):
        out[n, j] = row[j]
    return out


@nb.njit(cache=True, nogil=True)
def _tile_segments(free, end, covered, front, back, tol, tile, mask):  # pragma: no cover - compiled
    """Pieces (u0, u1, v0, v1 pixel indices inclusive, z0, z1) of one camera.

    A tile gives one piece, the bounding rectangle of its segment pixels from their
    smallest start to their largest end (a superset of their union), when that piece
    stays out of the padded robot in every robot-covered pixel of the tile (its depth
    range ends before ``front + tol`` or starts after ``back - tol`` there: it reaches at
    most ``tol`` into the padding). Otherwise it gives one piece per run of segment pixels
    along a row, each run as long as its piece stays out of the padded robot likewise in
    its own pixels (a single pixel's piece always does: it ends at the robot's shadow start
    or starts behind it).
    """
    H, W = free.shape
    Hb = (H + tile - 1) // tile
    Wb = (W + tile - 1) // tile
    cap = 1024
    out = np.empty((cap, 6), dtype=np.float64)
    n = 0
    for tb in range(Hb):
        for ub in range(Wb):
            if not mask[tb, ub]:
                continue
            v0 = tb * tile
            u0 = ub * tile
            v1 = min(v0 + tile, H)
            u1 = min(u0 + tile, W)
            any_seg = False
            zlo = np.inf
            zhi = -np.inf
            for v in range(v0, v1):
                for u in range(u0, u1):
                    if free[v, u] < end[v, u]:
                        any_seg = True
                        zlo = min(zlo, np.float64(free[v, u]))
                        zhi = max(zhi, np.float64(end[v, u]))
            if not any_seg:
                continue
            robot = False
            for v in range(v0, v1):
                for u in range(u0, u1):
                    if covered[v, u]:
                        if not (zhi <= np.float64(front[v, u]) + tol or zlo >= np.float64(back[v, u]) - tol):
                            robot = True
            if robot:
                # runs of segment pixels along each row, as long as the run's piece stays
                # out of the padded robot in every pixel of the run
                for v in range(v0, v1):
                    u = u0
                    while u < u1:
                        if not free[v, u] < end[v, u]:
                            u += 1
                            continue
                        ra = u
                        rlo = np.float64(free[v, u])
                        rhi = np.float64(end[v, u])
                        u += 1
                        while u < u1 and free[v, u] < end[v, u]:
                            nlo = min(rlo, np.float64(free[v, u]))
                            nhi = max(rhi, np.float64(end[v, u]))
                            clear = True
                            for w in range(ra, u + 1):
                                if covered[v, w] and not (
                                    nhi <= np.float64(front[v, w]) + tol or nlo >= np.float64(back[v, w]) - tol
                                ):
                                    clear = False
                                    break
                            if not clear:
                                break
                            rlo = nlo
                            rhi = nhi
                            u += 1
                        out = push_row(out, n, (float(ra), float(u - 1), float(v), float(v), rlo, rhi))
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
                out = push_row(out, n, (float(pu0), float(pu1), float(pv0), float(pv1), zmin, zmax))
                n += 1
    return out[:n]


def tile_segments(
    free: ArrayF32,
    end: ArrayF32,
    covered: np.ndarray,
    tile: int,
    front: ArrayF32 | None = None,
    back: ArrayF32 | None = None,
    tol: float = 0.0,
    tiles: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 6) initial pieces of one camera: pixel rectangle (u0, u1, v0, v1), inclusive
    pixel indices, and depth range (z0, z1) [m] (see :func:`_tile_segments`). ``front``
    and ``back`` bound the padded robot's depth in its ``covered`` pixels; without them,
    every tile with a covered pixel is split into pixels. ``tiles`` (the tile grid's
    shape) marks the tiles that may hold a segment pixel (:attr:`PixelClasses.tiles`);
    the others are not visited. None: every tile is."""
    if front is None or back is None:
        front = np.full(free.shape, -np.inf, dtype=np.float32)
        back = np.full(free.shape, np.inf, dtype=np.float32)
    H, W = free.shape
    shape = ((H + tile - 1) // tile, (W + tile - 1) // tile)
    if tiles is None:
        tiles = np.ones(shape, dtype=np.bool_)
    elif tiles.shape != shape:
        raise ValueError(f"tiles: expected shape {shape}, got {tiles.shape}")
    return _tile_segments(free, end, covered, front, back, float(tol), int(tile), tiles)


@nb.njit(cache=True, nogil=True)
def _memory(covered, back, free, fs, rects, zr, cell, out_f, out_e):  # pragma: no cover - compiled
    H, W = covered.shape
    Hb = (H + cell - 1) // cell
    Wb = (W + cell - 1) // cell
    zlo = np.full((Hb, Wb), np.inf)
    zhi = np.full((Hb, Wb), -np.inf)
    for b in range(rects.shape[0]):
        u0 = max(rects[b, 0], 0)
        u1 = min(rects[b, 1], W - 1)
        v0 = max(rects[b, 2], 0)
        v1 = min(rects[b, 3], H - 1)
        if u0 > u1 or v0 > v1:
            continue
        for tb in range(v0 // cell, v1 // cell + 1):
            for ub in range(u0 // cell, u1 // cell + 1):
                zlo[tb, ub] = min(zlo[tb, ub], zr[b, 0])
                zhi[tb, ub] = max(zhi[tb, ub], zr[b, 1])
    for v in range(H):
        for u in range(W):
            if not covered[v, u]:
                continue
            lo = zlo[v // cell, u // cell]
            if lo == np.inf:
                continue
            start = max(max(np.float64(free[v, u]), np.float64(back[v, u])), lo)
            stop = min(np.float64(fs[v, u]), zhi[v // cell, u // cell])
            if start < stop:
                out_f[v, u] = down32(start)
                out_e[v, u] = up32(stop)


def memory_segments(
    covered: np.ndarray,
    robot_back: ArrayF32,
    free: ArrayF32,
    free_static: ArrayF32,
    rects: np.ndarray,
    z_ranges: np.ndarray,
    out_start: ArrayF32 | None = None,
    out_end: ArrayF32 | None = None,
    cell: int = 1,
) -> tuple[ArrayF32, ArrayF32]:
    """Segments of the robot's shadow near given boxes, for the shadow memory.

    Every box has a pixel rectangle ``rects`` (B, 4) u0, u1, v0, v1 and a z-depth range
    ``z_ranges`` (B, 2) in this camera. The image is cut into ``cell`` x ``cell`` px cells;
    a cell takes the least start and greatest end of the boxes whose rectangles meet it,
    and every robot-covered pixel of the cell gets the segment from ``max(f, back,
    z_min)`` to ``min(f_s, z_max)``: what the robot hides from this camera behind its
    body (and the camera does not free), within the boxes' depth range. This holds every
    box's own segment in each of its pixels (a superset: it also bridges the depth gaps
    between boxes, and reaches the cell's other covered pixels). The robot's own (padded)
    volume is not part of the region.

    Returns:
        (start, end) images [m], rounded outward; no segment where ``start >= end``. They
        are written into ``out_start`` and ``out_end`` when given (filled here with +inf
        and -inf).
    """
    H, W = covered.shape
    out_f = np.empty((H, W), dtype=np.float32) if out_start is None else out_start
    out_e = np.empty((H, W), dtype=np.float32) if out_end is None else out_end
    out_f.fill(np.inf)
    out_e.fill(-np.inf)
    if len(rects):
        _memory(covered, robot_back, free, free_static, np.ascontiguousarray(rects, dtype=np.int64),
                np.ascontiguousarray(z_ranges, dtype=np.float64), int(cell), out_f, out_e)
    return out_f, out_e


def box_rects(
    lo: np.ndarray, hi: np.ndarray, T_camera_world: np.ndarray, intrinsics: tuple[float, float, float, float],
    z_beyond: float, window: tuple[int, int, int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """The pixel rectangles and depth ranges of world boxes [lo, hi] (B, 3) in a camera.

    A box counts when all its corners are in front of the camera (z > 1e-6), some corner
    is deeper than ``z_beyond`` [m], and the pixel rectangle of its corners' projections
    meets ``window`` (u0, u1, v0, v1, inclusive). Returns (S, 4) int64 rectangles (u0, u1,
    v0, v1) clipped to the window and (S, 2) the corners' z range, for the boxes that
    count, in order (one compiled pass; no corner array)."""
    fx, fy, cx, cy = intrinsics
    T = np.ascontiguousarray(T_camera_world, dtype=np.float64)
    n = lo.shape[0]
    rects = np.empty((n, 4), dtype=np.int64)
    zr = np.empty((n, 2))
    k = _box_rects(
        np.ascontiguousarray(lo, dtype=np.float64), np.ascontiguousarray(hi, dtype=np.float64), T,
        float(fx), float(fy), float(cx), float(cy), float(z_beyond),
        int(window[0]), int(window[1]), int(window[2]), int(window[3]), rects, zr,
    )
    return rects[:k], zr[:k]


@nb.njit(cache=True, nogil=True)
def project_bounds(points, R, t, fx, fy, cx, cy, z_eps):  # pragma: no cover - compiled
    """(umin, umax, vmin, vmax, zmin, zmax) of world points (K, 3) in a camera (world ->
    camera rotation ``R``, translation ``t``): the z range of all, the pixel range of those
    with z > ``z_eps``."""
    umin = np.inf
    umax = -np.inf
    vmin = np.inf
    vmax = -np.inf
    zmin = np.inf
    zmax = -np.inf
    for j in range(points.shape[0]):
        x, y, z = points[j, 0], points[j, 1], points[j, 2]
        px = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
        py = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
        pz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        zmin = min(zmin, pz)
        zmax = max(zmax, pz)
        if pz > z_eps:
            u = fx * px / pz + cx
            v = fy * py / pz + cy
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
    return umin, umax, vmin, vmax, zmin, zmax


@nb.njit(cache=True, nogil=True)
def _box_rects(lo, hi, T, fx, fy, cx, cy, z_beyond, c0, c1, r0, r1, rects, zr):  # pragma: no cover - compiled
    k = 0
    corners = np.empty((8, 3))
    R = T[:3, :3]
    t = T[:3, 3]
    for b in range(lo.shape[0]):
        for m in range(8):
            corners[m, 0] = hi[b, 0] if m & 1 else lo[b, 0]
            corners[m, 1] = hi[b, 1] if m & 2 else lo[b, 1]
            corners[m, 2] = hi[b, 2] if m & 4 else lo[b, 2]
        umin, umax, vmin, vmax, zmin, zmax = project_bounds(corners, R, t, fx, fy, cx, cy, 1e-6)
        if not (zmax > z_beyond and zmin > 1e-6):
            continue
        pu0 = np.floor(umin + 0.5)
        pu1 = np.floor(umax + 0.5)
        pv0 = np.floor(vmin + 0.5)
        pv1 = np.floor(vmax + 0.5)
        if not (pu1 >= c0 and pu0 <= c1 and pv1 >= r0 and pv0 <= r1):
            continue
        rects[k, 0] = int(max(pu0, c0))
        rects[k, 1] = int(min(pu1, c1))
        rects[k, 2] = int(max(pv0, r0))
        rects[k, 3] = int(min(pv1, r1))
        zr[k, 0] = zmin
        zr[k, 1] = zmax
        k += 1
    return k
