"""The robot shadow's memory: what the robot hides, near what was just seen.

The paper subtracts the robot's occlusion M on the argument that nobody enters it unseen;
a person who is seen and then steps behind the robot would vanish. The memory keeps the
part of ``C n M`` within a person's reach (``v_h dt``, Euclidean) of what the previous
cycle saw as a target: its **seeds** (see :class:`polyhull.engine.dynamic_rules.DynamicResult`),
and of those only the part within ``SEED_DEPTH`` behind the surface their pixels measured
(:func:`seen_parts`), not the whole previous region. Grown from R3_static, from sensor
noise spared next to the robot, from the unseen shadow behind a person or from the memory
itself, the memory would fill the robot's shadow for good and hold the robot at a
standstill. A person wholly inside M is followed for one cycle; with cameras around the
cell M is the robot's own narrow shadow, and a person's visible remainder seeds the memory
again every cycle. A person who was never seen (hidden in a static or a person's shadow)
and steps from there into M is not followed.

Behind the padded robot (its back depth) in every robot-covered pixel, the segment to the
static free depth holds ``C n M`` (what the robot hides, not freed by this camera); only
the covered pixels of the tiles that the projections of the grown seed boxes meet are
built (each tile with the depth range of the boxes that meet it:
:func:`polyhull.engine.pixels.memory_segments`), then carved like any piece and by M's
own definition (``M = F_static \\ F_static+robot``, :class:`polyhull.engine.pieces.MTest`):
a piece that k cameras would see free in the empty cell with the padded robot (in front
of their segment ends) is not in M, and what of it is in C lies in those cameras'
segments, the other pieces; a piece that fewer than k cameras see free in the empty cell
is in ``C_static``, which M never meets. (Without that test, one camera's robot shadow
that another camera could not see through only because a person stood in the way was
memory too, and with k >= 2 so was blind space: with the eight colour cameras of
``fixtures/cells/color8_cell.toml`` and a person at the robot, 55,000 memory pieces
instead of 28,000.) What remains is kept where it comes within reach of a seed
(:func:`within_reach`: a ball, not a cube, which along a diagonal reaches sqrt(3) times
as far). Refinement carves the memory's pieces at the distance frontier finely against
the same segments (:attr:`ShadowMemory.stacks`) and tests, and keeps the children within
reach again.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor

import numpy as np

from ..camera import Camera
from ..typed import ArrayF32, ArrayF64
from .boxes import any_overlap
from .pieces import CameraStack, ImageStack, PieceSet, piece_vertices, vertex_bounds
from .pixels import box_rects, memory_segments, tile_segments, window_range
from .robot_raster import RobotRaster
from .threads import share

__all__ = ["MEMORY_PIECE", "SEED_DEPTH", "ShadowMemory", "seen_parts", "within_reach"]

MEMORY_PIECE = 0.2
"""Smallest split [m] of the shadow memory's pieces (and of the hull C's, built only when
read). Memory pieces start behind the padded robot, so their distance is about the
padding whatever their size; finer pieces only cost time (refinement splits those at the
distance frontier)."""

SEED_DEPTH = 0.6
"""Depth [m] of a person's body behind the surface their pixels measure (the shadow
memory's seeds are the seen parts of the kept pieces, not the shadow behind them)."""


def seen_parts(
    boxes: ArrayF64,
    free_imgs: Sequence[np.ndarray | None],
    stack: CameraStack,
    binary: Sequence[bool] = (),
    invalid_imgs: Sequence[np.ndarray | None] = (),
) -> ArrayF64:
    """(S, 8, 3) the parts of pieces (boxes (N, 7)) within ``SEED_DEPTH`` behind the
    surface their pixels measured: the depth range ``[max(z0, f_min), min(z1, f_max +
    SEED_DEPTH)]`` with ``f`` the camera's free depth over the piece's pixels. Pieces of a
    camera without a frame, or entirely deeper, give nothing.

    A camera marked in ``binary`` (a colour camera) measures no surface: a changed pixel
    frees nothing, and what it saw may lie anywhere along its piece, which is kept whole
    when some pixel of it has a reading (``invalid_imgs``: the pixels without one); a piece
    of pixels without any reading (a dropout patch) saw nothing, as for a depth camera."""
    out = []
    cams = boxes[:, 0].astype(np.int64)
    for c in np.unique(cams):
        free = free_imgs[int(c)]
        if free is None:
            continue
        b = boxes[cams == c].copy()
        if int(c) < len(binary) and binary[int(c)]:
            invalid = invalid_imgs[int(c)] if int(c) < len(invalid_imgs) else None
            if invalid is not None:
                least, _ = window_range(invalid.view(np.uint8), b[:, 1:5].astype(np.int64))
                b = b[least == 0]
            out.append(b)
            continue
        f_lo, f_hi = window_range(free, b[:, 1:5].astype(np.int64))
        b[:, 5] = np.maximum(b[:, 5], f_lo)
        b[:, 6] = np.minimum(b[:, 6], f_hi + SEED_DEPTH)
        out.append(b[b[:, 5] < b[:, 6]])
    kept = np.concatenate(out) if out else np.zeros((0, 7))
    return piece_vertices(kept, stack)


def within_reach(
    pieces: PieceSet, seed_lo: ArrayF64, seed_hi: ArrayF64, reach: float, pool: Executor | None = None
) -> PieceSet:
    """The pieces whose bounding boxes come within ``reach`` [m] (Euclidean gap) of a seed
    box ``[seed_lo, seed_hi]`` (S, 3): a lower bound of a piece's own gap, so every piece
    with a point within reach of a seed is kept."""
    if not len(pieces):
        return pieces
    return pieces.select(any_overlap(*vertex_bounds(pieces.vertices), seed_lo, seed_hi, pool, reach=reach))


class ShadowMemory:
    """The memory's segment images (per camera: each covered pixel's segment behind the
    robot, ``+inf`` / ``-inf`` for none), reused every cycle: only the robot's rectangle of
    each camera is written, and reset at the next cycle's start.

    M reaches in front of the robot too, and a second memory with ``front=True`` holds that
    part: each covered pixel's segment from its shadow start (or the free depth, if
    farther) to the padded robot's front. A colour camera (binary depth) hides the whole
    ray of a pixel the robot changes (its shadow starts at ``near``); a depth camera hides
    the band its tolerance leaves before the robot's surface (its reading frees only up to
    ``tau`` before it: the shadow starts up to ``2 tau - padding`` before the padded
    front). Without the depth cameras' band, a person within a few centimetres of the
    padded robot in every camera, seen a cycle before, was lost there (a search of 60
    walks past the robot: 15 of 35 checked cycles, 1 to 8 body points each).

    Args:
        cameras: The cell's cameras.
        free_static: Each camera's static free depth image [m].
        stack: The cameras as arrays.
        tile: Tile edge [px] (the same tiles as the image's pieces).
        tile_tol: How far [m] a tile's merged piece may reach into the robot's padding.
        front: The part in front of the robot, not the part behind it.
    """

    def __init__(
        self,
        cameras: Sequence[Camera],
        free_static: Sequence[ArrayF32],
        stack: CameraStack,
        tile: int,
        tile_tol: float,
        front: bool = False,
    ) -> None:
        self._cameras = tuple(cameras)
        self._free_static = tuple(free_static)
        self._stack = stack
        self._tile = int(tile)
        self._tile_tol = float(tile_tol)
        self._front = bool(front)
        self._stop: list[np.ndarray | None] = [None] * len(self._cameras)  # the front part's ends
        self._start: list[np.ndarray | None] = [None] * len(self._cameras)  # and starts
        self._stacks: tuple[ImageStack, ImageStack] | None = None
        self._rects: list[tuple[slice, slice] | None] = [None] * len(self._cameras)

    @property
    def stacks(self) -> tuple[ImageStack, ImageStack] | None:
        """The memory segments' (free, end) images of the last :meth:`pieces` call (None
        before the first): refinement carves the memory's pieces along them."""
        return self._stacks

    def pieces(
        self,
        rasters: Mapping[str, RobotRaster],
        free_imgs: Sequence[np.ndarray | None],
        carve: Callable[[np.ndarray, ImageStack, ImageStack], PieceSet],
        seed_lo: ArrayF64,
        seed_hi: ArrayF64,
        reach: float,
        pool: Executor | None = None,
    ) -> PieceSet:
        """Pieces of ``C n M`` within ``reach`` [m] of the seed boxes ``[seed_lo, seed_hi]``
        (S, 3), given this cycle's robot ``rasters`` and free depth images; ``carve(tiles,
        frees, ends)`` carves initial pieces (N, 7) by the cameras' free depth, split along
        the segments ``frees`` / ``ends`` (coarsely: ``MEMORY_PIECE``)."""
        lo, hi = seed_lo - reach, seed_hi + reach  # the segments are built within these
        if self._stacks is None:
            self._stacks = (ImageStack(self._stack, fill=np.inf), ImageStack(self._stack, fill=-np.inf))
        mem_free, mem_end = self._stacks
        tile = self._tile

        def camera(i: int) -> np.ndarray | None:
            # one camera's memory segments as tiles (thread-safe: camera i's images only)
            cam = self._cameras[i]
            raster = rasters.get(cam.name)
            free = free_imgs[i]
            prev = self._rects[i]
            if prev is not None:
                mem_free.image(i)[prev] = np.inf  # no segment
                mem_end.image(i)[prev] = -np.inf
                self._rects[i] = None
            if raster is None or free is None or raster.rect is None:
                return None
            u0, u1, v0, v1 = raster.rect
            # the grown seed boxes behind the robot's nearest back depth (in front of the
            # robot: anywhere), as pixel rectangles within the covered pixels' rectangle
            k = cam.intrinsics
            beyond = cam.near if self._front else max(cam.near, raster.back_min)
            rects, zr = box_rects(lo, hi, cam.T_camera_world, (k.fx, k.fy, k.cx, k.cy), beyond, raster.rect)
            if not len(rects):
                return None  # no seed box here: no segment (the images are reset above)
            # the robot's rectangle, widened to whole tiles (the same tiles as the image's)
            H, W = cam.shape
            tu0, tv0 = (u0 // tile) * tile, (v0 // tile) * tile
            tw = (slice(tv0, min((v1 // tile + 1) * tile, H)), slice(tu0, min((u1 // tile + 1) * tile, W)))
            self._rects[i] = tw
            if self._front:
                # from the shadow start (a colour camera's is ``near``) or the free depth,
                # whichever is farther, to the padded front, written into camera-sized
                # images: a window of them is laid out as the other part's arguments are
                # (one compiled signature)
                if self._stop[i] is None:
                    self._stop[i] = np.empty(cam.shape, dtype=np.float32)
                    self._start[i] = np.empty(cam.shape, dtype=np.float32)
                stop = self._stop[i][tw]  # type: ignore[index]
                np.minimum(self._free_static[i][tw], raster.front[tw], out=stop)
                start = self._start[i][tw]  # type: ignore[index]
                np.maximum(free[tw], raster.shadow_start[tw], out=start)
            else:
                start, stop = raster.back[tw], self._free_static[i][tw]
            f, e = memory_segments(
                raster.covered[tw], start, free[tw], stop,
                rects - np.array([tu0, tu0, tv0, tv0]), zr, mem_free.image(i)[tw], mem_end.image(i)[tw], tile,
            )
            tiles = tile_segments(f, e, raster.covered[tw], tile, raster.front[tw], raster.back[tw], self._tile_tol)
            if not len(tiles):
                return None
            tiles[:, 0:2] += tu0
            tiles[:, 2:4] += tv0
            return np.column_stack([np.full(len(tiles), float(i)), tiles])

        parts = [p for p in share(pool, camera, range(len(self._cameras))) if p is not None]
        if not parts:
            return PieceSet.empty()
        # carved by the cameras' free depth; split along the memory segments
        return within_reach(carve(np.concatenate(parts), mem_free, mem_end), seed_lo, seed_hi, reach, pool)
