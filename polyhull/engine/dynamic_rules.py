"""Plausibility of the dynamic part: the rules of :mod:`polyhull.plausibility` on this
cycle's components.

Components are groups of pieces whose bounding boxes, grown by ``TOUCH_EPS``, overlap
(transitively; a superset of "touch or overlap": grouping more only makes a rule fire less,
since every rule spares a set whenever it spares a part of it). A component is judged together with
what it touches:

- a **kept static component** (the static touch grid marks voxels within ``support_eps``
  of R3_static, a superset; where it alone would spare a component from too_small or
  flying, the touch is confirmed against R3_static's triangles): R3_static passed the
  rules, so the union does, and the component is kept;
- the **robot's occlusion M** (a piece that ends at the robot's shadow start, or that comes
  within ``support_eps`` of the padded robot): supported and connected, like the old
  paper-style rule that a person whose legs the robot hides stands on M;
- the **boundary of Z** (walls and ceiling, within ``support_eps``): with
  ``keep_at_boundary``, flying, too_small and too_thin never fire.

The rules (each switchable, in ``RULE_ORDER``, the first that fires is reported):

1. ``too_small``: the sum of the pieces' volumes (at least the union's) is below
   ``min_volume``, unless the component touches M within ``ARM_LENGTH`` of a component
   that passes the rule and touches M too (a hand whose forearm the robot hides);
2. ``flying``: no piece reaches down to within ``support_eps`` of the top of a sheet (the
   floor's or an obstacle top's, whose noise sheet stands in for the surface);
3. ``too_thin``, part-wise: a piece that lies in a shell around a known object (within
   ``shell_thickness`` of an obstacle, by the exact point-to-box distance, or of a padded
   robot piece, by the hull of its vertices plus a polytope inscribed in the ball of that
   radius: a subset of the true shell) or inside one noise sheet (the floor's or an
   obstacle face's, judged at precompute; a vertical face's only ``standing_depth`` deep,
   since a person standing against it sticks out that far) is removed, unless a piece of its component
   outside every shell lies within ``floor_shell_margin`` of it, horizontally (a disc, as
   far in every direction) and along z: a standing person crosses the floor's sheet and
   keeps their feet, a hand reaching into the robot's shell is
   attached to an arm outside it. Pieces touching the boundary of Z are kept with
   ``keep_at_boundary``;
4. ``entry``: touches neither the boundary of Z, an entry area, M, nor comes within
   ``human_speed_max * dt + support_eps`` of the previous cycle's region (bounding-box
   gaps, which never exceed the true distance);
5. ``teleport``: farther than ``human_speed_max * dt`` from every component of the previous
   cycle, and touching neither the boundary, an entry area nor M.

A kept component keeps the **noise sheet under it** (unless it holds no reading: made only
of the far part of small gaps, see :func:`judge_dynamic`): for every kept piece that crosses the
top of a sheet (floor, obstacle face), the sheet within ``floor_shell_margin`` of the
piece's footprint on that face (a disc around it, not a square: a foot reaches as far from
the leg in every direction, and a square's corners reach sqrt(2) times as far; in rows of
``SHEET_PITCH / SHEET_ROWS``, so up to that much farther), as high as C_static reaches in the sheet's slab there (its height
map, measured at precompute): a standing person's legs cross the top of
the floor's sheet, and their feet are in the sheet within that margin of the legs. Pieces
wholly inside a sheet (noise in the band, a limb lying flatter than the sheet) do not
extend it: ``floor_shell_height`` declares that nobody lies flatter. The pipeline applies
this (:func:`sheets_under`) after the kept pieces near the robot are carved finely
(:mod:`polyhull.engine.refine`), so that a coarse piece that only seems to cross the top
does not bring a sheet box with it.

A vertical face's sheet (a table's or the rack's side, a wall) is kept by any kept piece
that reaches into it, and its box hangs down to the face's bottom: a person stands closer
to a wall or a table's side than its sheet is thick, and their legs there are unseen (the
cameras that see the side read it, the others see the table top or nothing). Under the
boxes of a piece that reaches a face from above its upper edge, where that edge is lower
than ``STANDING_HEIGHT`` (a person at a table, seen only above it), the floor's sheet is
kept in turn (the feet). Elsewhere the feet are those of legs that are seen and cross the
floor's sheet, or lie in the hanging box.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import NamedTuple

import numba as nb
import numpy as np

from ..cell import Cell, PlausibilityParams, Zone
from ..distance import hexahedra_triangles
from ..plausibility import RULE_ORDER, RemovedComponent
from ..typed import ArrayF64
from .boxes import OverlapSweep, any_near_upright, any_overlap, group_bounds
from .pieces import PARALLEL_MIN, vertex_bounds
from .static_model import SHEET_PITCH, Sheet, TouchGrid, _to_world
from .threads import share

__all__ = [
    "TOUCH_EPS",
    "DynamicContext",
    "DynamicResult",
    "box_vertices",
    "crosses_sheet_top",
    "hidden_legs",
    "in_shells",
    "judge_dynamic",
    "shell_cuts",
    "sheets_under",
]

TOUCH_EPS = 1e-4
"""Growth [m] of piece bounding boxes when grouping them into components."""

GROUP_PARTS = 4
"""Parts of the components' sweep (:class:`polyhull.engine.boxes.OverlapSweep`) shared by
two threads with the per-piece tests: near the robot (6,000 pieces) the sweep alone took
6 to 8 ms, and one thread waited for it."""


StaticNear = Callable[[ArrayF64, ArrayF64, float, np.ndarray, int], np.ndarray]
"""``(lo, hi, distance, groups, n_groups) -> (n_groups,)``: whether some box of each group,
grown by ``distance``, meets the surface of R3_static."""


def box_vertices(lo: ArrayF64, hi: ArrayF64) -> ArrayF64:
    """(N, 8, 3) corners of boxes [lo, hi] (N, 3), in the piece vertex order."""
    lo = np.atleast_2d(lo)
    hi = np.atleast_2d(hi)
    x = np.stack([lo[:, 0], hi[:, 0], hi[:, 0], lo[:, 0]] * 2, axis=1)
    y = np.stack([lo[:, 1], lo[:, 1], hi[:, 1], hi[:, 1]] * 2, axis=1)
    z = np.concatenate([np.repeat(lo[:, 2:3], 4, axis=1), np.repeat(hi[:, 2:3], 4, axis=1)], axis=1)
    return np.stack([x, y, z], axis=2)


@dataclass(frozen=True, eq=False)
class DynamicContext:
    """What the dynamic rules know besides the pieces.

    Attributes:
        zone: The zone.
        params: The rules' switches and parameters.
        sheets: The judged sheets (floor, obstacle faces) with their thickness.
        sheet_heights: Per sheet, the height map of C_static in its slab (the sheet boxes'
            heights); empty: every box is as thick as its sheet.
        static_touch: Voxels within ``support_eps`` of R3_static.
        obstacle_boxes: (K, 2, 3) bounds of the obstacles (for too_thin).
        robot_shell_planes: Per padded robot piece at q, (F, 4) planes ``n . x <= d`` of its
            shell (the piece grown by an inscribed polytope of ``shell_thickness``).
        robot_spheres: (M, 4) bounding spheres of the padded robot pieces at q.
        entry_lo: (E, 3) entry area minima; ``entry_hi`` the maxima.
        previous_lo: (P, 3) bounding boxes of the previous cycle's dynamic components, or
            None without history; ``previous_hi`` their maxima.
        dt: Time since the previous cycle [s], or None.
        human_speed: v_h [m/s] of the sheet margin and the memory.
        static_near: ``static_near(lo, hi, distance, groups, n_groups)``: for each group
            of boxes [lo, hi] (N, 3), whether some box of it grown by ``distance`` [m] meets
            the surface of R3_static (exact; see
            :meth:`polyhull.engine.static_model.StaticModel.boxes_meet`). None: the
            ``static_touch`` grid alone decides what touches R3_static.
        m_columns: ``m_columns(xy, heights)``: (C,) the lowest of ``heights`` (H,) at
            which each vertical column ``xy`` (C, 2) lies in the robot's occlusion M this
            cycle (by its definition, with the padded robot), +inf at none: for the legs
            the robot hides (:func:`hidden_legs`); None: no robot.
    """

    zone: Zone
    params: PlausibilityParams
    sheets: tuple[Sheet, ...]
    static_touch: TouchGrid
    obstacle_boxes: ArrayF64
    robot_shell_planes: tuple[ArrayF64, ...]
    robot_spheres: ArrayF64
    entry_lo: ArrayF64
    entry_hi: ArrayF64
    previous_lo: ArrayF64 | None
    previous_hi: ArrayF64 | None
    dt: float | None
    sheet_heights: tuple[np.ndarray, ...] = ()
    static_near: StaticNear | None = None
    m_columns: Callable[[ArrayF64, ArrayF64], ArrayF64] | None = None

    @classmethod
    def of(
        cls,
        cell: Cell,
        sheets: Sequence[Sheet],
        static_touch: TouchGrid,
        sheet_heights: Sequence[np.ndarray] = (),
        static_near: StaticNear | None = None,
    ) -> DynamicContext:
        """The parts that do not change between cycles."""
        boxes = np.array([o.mesh.bounds for o in cell.obstacles], dtype=np.float64).reshape(-1, 2, 3)
        areas = cell.plausibility.entry_areas
        return cls(
            zone=cell.zone,
            params=cell.plausibility,
            sheets=tuple(sheets),
            static_touch=static_touch,
            obstacle_boxes=boxes,
            robot_shell_planes=(),
            robot_spheres=np.zeros((0, 4)),
            entry_lo=np.array([a.min for a in areas], dtype=np.float64).reshape(-1, 3),
            entry_hi=np.array([a.max for a in areas], dtype=np.float64).reshape(-1, 3),
            previous_lo=None,
            previous_hi=None,
            dt=None,
            sheet_heights=tuple(sheet_heights),
            static_near=static_near,
        )


@dataclass(frozen=True, eq=False)
class DynamicResult:
    """The dynamic part after its rules.

    Attributes:
        keep: (N,) which pieces are kept.
        labels: (N,) component of every piece.
        own: (N,) the kept pieces that keep the noise sheet under them
            (:func:`sheets_under`): pieces, not of the memory, of components that pass
            too_small and flying on their own.
        spared: (N,) pieces of components that touch the boundary of Z, with
            ``keep_at_boundary`` (no shell cut).
        inside: (N,) pieces inside a shell or a noise sheet (all False without
            ``too_thin``).
        removed: The removed components with their rule (mesh built when read).
        seeds: (N,) the kept pieces the next cycle's shadow memory grows from: pieces (not
            of the memory, not inside a shell or a noise sheet) of components that pass
            too_small on their own volume and stand on a surface or touch the boundary.
        hiding: (N,) the pieces of ``own`` in components that touch M: the legs the
            robot may hide stand under them (:func:`hidden_legs`, all False without
            ``too_thin``), and the floor's sheet is kept under those legs
            (:func:`sheets_under`), where the feet are.
        residue: (N,) the pieces made only of the far part of a small gap (as given).
    """

    keep: np.ndarray
    labels: np.ndarray
    own: np.ndarray
    spared: np.ndarray
    inside: np.ndarray
    removed: tuple[RemovedComponent, ...]
    seeds: np.ndarray
    hiding: np.ndarray
    residue: np.ndarray


def _box_gap(lo: ArrayF64, hi: ArrayF64, blo: ArrayF64, bhi: ArrayF64) -> ArrayF64:
    """(N, M) Euclidean gap between boxes (0 when overlapping)."""
    d = np.maximum(0.0, np.maximum(lo[:, None, :] - bhi[None, :, :], blo[None, :, :] - hi[:, None, :]))
    return np.sqrt((d * d).sum(axis=2))


def _in_shell(vertices: ArrayF64, ctx: DynamicContext) -> np.ndarray:
    """(N,) whether every vertex of each piece (N, K, 3) lies within ``shell_thickness`` of
    a known object."""
    t = ctx.params.shell_thickness
    inside = np.zeros(len(vertices), dtype=bool)
    if len(vertices) == 0:
        return inside
    boxes = np.array([np.concatenate([lo, hi]) for lo, hi in ctx.obstacle_boxes], dtype=np.float64).reshape(-1, 6)
    planes = list(ctx.robot_shell_planes)
    spheres = np.ascontiguousarray(ctx.robot_spheres[: len(planes)], dtype=np.float64).reshape(-1, 4)
    counts = np.array([len(p) for p in planes[: len(spheres)]], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    flat = np.concatenate(planes[: len(spheres)]).reshape(-1, 4) if len(spheres) else np.zeros((0, 4))
    _shell_kernel(np.ascontiguousarray(vertices, dtype=np.float64), boxes, float(t), spheres, np.ascontiguousarray(flat, dtype=np.float64), offsets, inside)
    return inside


@nb.njit(cache=True, nogil=True)
def _shell_kernel(vertices, boxes, t, spheres, planes, offsets, out):  # pragma: no cover - compiled
    """Whether every vertex of each piece is within ``t`` of an obstacle box (exact
    point-to-box distance) or inside a robot piece's shell polytope (its planes, tested
    only within its sphere grown by ``t``); a piece's test stops at its first vertex in no
    shell."""
    for n in range(vertices.shape[0]):
        all_in = True
        for k in range(vertices.shape[1]):
            if not _point_in_shell(vertices[n, k, 0], vertices[n, k, 1], vertices[n, k, 2], boxes, t, spheres, planes, offsets):
                all_in = False
                break
        out[n] = all_in


@nb.njit(cache=True, nogil=True, inline="always")
def _point_in_shell(x, y, z, boxes, t, spheres, planes, offsets):  # pragma: no cover - compiled
    """Whether point (x, y, z) is within ``t`` of an obstacle box or inside a robot piece's
    shell polytope."""
    tt = t * t
    for b in range(boxes.shape[0]):
        dx = max(0.0, max(boxes[b, 0] - x, x - boxes[b, 3]))
        dy = max(0.0, max(boxes[b, 1] - y, y - boxes[b, 4]))
        dz = max(0.0, max(boxes[b, 2] - z, z - boxes[b, 5]))
        if dx * dx + dy * dy + dz * dz <= tt:
            return True
    for s in range(spheres.shape[0]):
        dx = x - spheres[s, 0]
        dy = y - spheres[s, 1]
        dz = z - spheres[s, 2]
        r = spheres[s, 3] + t
        if dx * dx + dy * dy + dz * dz > r * r:
            continue
        ok = True
        for f in range(offsets[s], offsets[s + 1]):
            if x * planes[f, 0] + y * planes[f, 1] + z * planes[f, 2] > planes[f, 3]:
                ok = False
                break
        if ok:
            return True
    return False


class _SheetArrays(NamedTuple):
    """The sheets as arrays, for the compiled pair search."""

    M: ArrayF64  # (S, 3, 4) world -> local
    wlo: ArrayF64  # (S, 3) the slabs' world bounds
    whi: ArrayF64
    face: ArrayF64  # (S, 4) x0, y0, x1, y1 of the face in the local frame
    height: ArrayF64  # (S,)
    W: ArrayF64  # (S, 3, 4) local -> world
    down: np.ndarray  # (S,) the local axis along world z of a vertical face, -1 otherwise
    no_down: np.ndarray  # (S,) -1: no face hangs down


@functools.cache
def _sheet_arrays(sheets: tuple[Sheet, ...]) -> _SheetArrays:
    """The sheets' frames and bounds as arrays (once per set of sheets)."""
    S = len(sheets)
    M = np.zeros((S, 3, 4))
    wlo = np.zeros((S, 3))
    whi = np.zeros((S, 3))
    face = np.zeros((S, 4))
    for k, sh in enumerate(sheets):
        M[k] = sh.to_local()
        wlo[k], whi[k] = sh.world_box(0.0)
        (x0, y0), (x1, y1) = sh.local_box()
        face[k] = (x0, y0, x1, y1)
    height = np.array([sh.height for sh in sheets], dtype=np.float64)
    W = np.array([_to_world(m) for m in M]).reshape(S, 3, 4)
    down = np.array([sh.down for sh in sheets], dtype=np.int64)
    no_down = np.full(S, -1, dtype=np.int64)
    # all read-only: the compiled kernels see one type (a writable array is another)
    for a in (M, wlo, whi, face, height, W, down, no_down):
        a.setflags(write=False)
    return _SheetArrays(M, wlo, whi, face, height, W, down, no_down)


@nb.njit(cache=True, nogil=True)
def _pairs_kernel(vertices, M, wlo, whi, pad):  # pragma: no cover - compiled
    """(P, 2) pairs (piece, sheet) whose bounding box meets the sheet's slab grown by
    ``pad``, and (P, 6) the piece's bounds in the sheet's local frame (lo, hi)."""
    n = vertices.shape[0]
    S = M.shape[0]
    cap = 256
    idx = np.empty((cap, 2), dtype=np.int64)
    bnd = np.empty((cap, 6))
    k = 0
    for i in range(n):
        lo0 = hi0 = vertices[i, 0, 0]
        lo1 = hi1 = vertices[i, 0, 1]
        lo2 = hi2 = vertices[i, 0, 2]
        for c in range(1, vertices.shape[1]):
            x, y, z = vertices[i, c, 0], vertices[i, c, 1], vertices[i, c, 2]
            lo0 = min(lo0, x)
            hi0 = max(hi0, x)
            lo1 = min(lo1, y)
            hi1 = max(hi1, y)
            lo2 = min(lo2, z)
            hi2 = max(hi2, z)
        for s in range(S):
            if hi0 < wlo[s, 0] - pad or lo0 > whi[s, 0] + pad:
                continue
            if hi1 < wlo[s, 1] - pad or lo1 > whi[s, 1] + pad:
                continue
            if hi2 < wlo[s, 2] - pad or lo2 > whi[s, 2] + pad:
                continue
            if k == cap:
                cap *= 2
                idx2 = np.empty((cap, 2), dtype=np.int64)
                bnd2 = np.empty((cap, 6))
                idx2[:k] = idx[:k]
                bnd2[:k] = bnd[:k]
                idx = idx2
                bnd = bnd2
            for a in range(3):
                m = np.inf
                x = -np.inf
                for c in range(vertices.shape[1]):
                    val = (
                        M[s, a, 0] * vertices[i, c, 0] + M[s, a, 1] * vertices[i, c, 1]
                        + M[s, a, 2] * vertices[i, c, 2] + M[s, a, 3]
                    )
                    m = min(m, val)
                    x = max(x, val)
                bnd[k, a] = m
                bnd[k, 3 + a] = x
            idx[k, 0] = i
            idx[k, 1] = s
            k += 1
    return idx[:k], bnd[:k]


def _sheet_pairs(vertices: ArrayF64, sheets: tuple[Sheet, ...], pad: float) -> tuple[np.ndarray, ArrayF64, _SheetArrays]:
    """Pairs (piece, sheet) of pieces (N, 8, 3) near sheets, their local bounds and the
    sheets' arrays."""
    arr = _sheet_arrays(tuple(sheets))
    if vertices.shape[0] == 0 or not sheets:
        return np.zeros((0, 2), dtype=np.int64), np.zeros((0, 6)), arr
    idx, bnd = _pairs_kernel(np.ascontiguousarray(vertices, dtype=np.float64), arr.M, arr.wlo, arr.whi, float(pad))
    return idx, bnd, arr


def _in_sheets(vertices: ArrayF64, ctx: DynamicContext) -> np.ndarray:
    """(N,) whether each piece lies inside one sheet's shell (the static noise sheets; a
    vertical face's only ``standing_depth`` deep)."""
    out = np.zeros(vertices.shape[0], dtype=bool)
    idx, b, arr = _sheet_pairs(vertices, ctx.sheets, 0.0)
    if len(idx) == 0:
        return out
    s = idx[:, 1]
    f = arr.face[s]
    # a vertical face's sheet holds no standing person deeper than standing_depth (one
    # there sticks out that far at the least): what reaches farther out is not noise
    h = np.where(arr.down[s] >= 0, np.minimum(arr.height[s], ctx.params.standing_depth), arr.height[s])
    inside = (
        (b[:, 2] >= -1e-6) & (b[:, 5] <= h)
        & (b[:, 0] >= f[:, 0]) & (b[:, 3] <= f[:, 2]) & (b[:, 1] >= f[:, 1]) & (b[:, 4] <= f[:, 3])
    )
    out[idx[inside, 0]] = True
    return out


STANDING_HEIGHT = 2.0
"""[m] A standing person rises above a vertical face's upper edge (its noise sheet's) only
where that edge is lower than this: at a table, not at a wall or a tall rack."""


def _crossing_pairs(vertices: ArrayF64, ctx: DynamicContext) -> tuple[np.ndarray, ArrayF64]:
    """Pairs (piece, sheet) where the piece crosses the top face of a horizontal sheet, or
    reaches into (or within ``support_eps`` of) a vertical one, over its face, and the
    piece's local bounds in that sheet's frame."""
    eps = ctx.params.support_eps
    idx, b, arr = _sheet_pairs(vertices, ctx.sheets, eps)
    if len(idx) == 0:
        return idx, b
    s = idx[:, 1]
    f = arr.face[s]
    h = arr.height[s]
    # what stands on the surface (legs) crosses the top face; its feet, inside the
    # sheet, lie within the margin of that crossing (nobody lies flatter than the sheet).
    # A vertical face's sheet is kept by whatever reaches into it in front of the face: a
    # person stands closer to a wall or a table's side than its sheet is thick
    near = (b[:, 2] <= h + eps) & ((b[:, 5] >= h) | ((arr.down[s] >= 0) & (b[:, 5] > 0.0)))
    near &= (b[:, 3] >= f[:, 0]) & (b[:, 0] <= f[:, 2]) & (b[:, 4] >= f[:, 1]) & (b[:, 1] <= f[:, 3])
    return idx[near], b[near]


def in_shells(vertices: ArrayF64, ctx: DynamicContext) -> np.ndarray:
    """(N,) whether each piece lies in a shell around a known object or inside a noise
    sheet (the ``too_thin`` rule's shells)."""
    return _in_shell(vertices, ctx) | _in_sheets(vertices, ctx)


def shell_cuts(
    vertices: ArrayF64, inside: np.ndarray, spared: np.ndarray, ctx: DynamicContext, pool: Executor | None = None
) -> np.ndarray:
    """(N,) the pieces the part-wise ``too_thin`` rule removes: inside a shell
    (``inside``), not ``spared``, and farther than ``floor_shell_margin`` from every piece
    outside the shells (of any component: a superset of "of its own", keeps more),
    horizontally or along z (:func:`polyhull.engine.boxes.any_near_upright`)."""
    cut = inside & ~spared
    if cut.any() and (~inside).any():
        lo, hi = vertex_bounds(vertices)
        m = ctx.params.floor_shell_margin
        cut[cut] = ~any_near_upright(lo[cut], hi[cut], lo[~inside], hi[~inside], m, pool)
    return cut


@nb.njit(cache=True, nogil=True)
def _near_balls(lo, hi, balls, eps):  # pragma: no cover - compiled
    """(N,) whether each box [lo, hi]'s ball (centre, half diagonal) comes within ``eps`` of
    one of the balls (B, 4): centre, radius."""
    out = np.zeros(lo.shape[0], dtype=np.bool_)
    for i in range(lo.shape[0]):
        cx = 0.5 * (lo[i, 0] + hi[i, 0])
        cy = 0.5 * (lo[i, 1] + hi[i, 1])
        cz = 0.5 * (lo[i, 2] + hi[i, 2])
        dx, dy, dz = hi[i, 0] - lo[i, 0], hi[i, 1] - lo[i, 1], hi[i, 2] - lo[i, 2]
        r = 0.5 * np.sqrt(dx * dx + dy * dy + dz * dz)
        for b in range(balls.shape[0]):
            ex, ey, ez = cx - balls[b, 0], cy - balls[b, 1], cz - balls[b, 2]
            if np.sqrt(ex * ex + ey * ey + ez * ez) - balls[b, 3] - r <= eps:
                out[i] = True
                break
    return out


def judge_dynamic(
    vertices: ArrayF64,
    volumes: ArrayF64,
    at_robot: np.ndarray,
    ctx: DynamicContext,
    make_mesh,  # noqa: ANN001 - (indices) -> manifold3d.Manifold, called lazily
    memory: np.ndarray | None = None,
    pool: Executor | None = None,
    residue: np.ndarray | None = None,
) -> DynamicResult:
    """Apply the dynamic rules to pieces with vertices (N, 8, 3) [m], volumes (N,) [m^3]
    and ``at_robot`` (N,) (the piece ends at the robot's shadow start). ``memory`` (N,)
    marks the shadow memory's pieces: they are judged like the others but add no sheet
    boxes (they are the robot's hidden space, not something seen standing there).
    ``residue`` (N,) marks pieces made only of the far part of a small gap (the rays of a
    reading-less pixel cluster beyond the depth where they widen to ``detection_size``,
    :func:`polyhull.engine.pixels.small_gaps`): a component of such pieces alone holds no
    reading, so it is judged like the others but keeps no sheet under it and seeds no
    memory (a hand-sized object the dropout may hide is not a person seen standing there;
    a person beside it shows readings, whose pieces keep the sheets). With a ``pool``, the
    components' sweep and the per-piece tests run on this thread and one of its threads."""
    n = vertices.shape[0]
    if n == 0:
        none = np.zeros(0, bool)
        return DynamicResult(none, np.zeros(0, np.int64), none, none, none, (), none, none, none)
    p = ctx.params
    eps = p.support_eps
    lo, hi = vertex_bounds(vertices)
    c = _components(vertices, lo, hi, volumes, at_robot, ctx, pool)
    labels, K, clo, chi = c.labels, c.n_components, c.lo, c.hi
    grid_touch, near_robot, inside, sheet_pairs = c.grid_touch, c.near_robot, c.inside, c.sheet_pairs

    zmin, zmax = np.asarray(ctx.zone.min, dtype=np.float64), np.asarray(ctx.zone.max, dtype=np.float64)
    boundary = np.any(clo[:, :2] <= zmin[:2] + eps, axis=1) | np.any(chi[:, :2] >= zmax[:2] - eps, axis=1)
    boundary |= chi[:, 2] >= zmax[2] - eps
    touch_static = np.bincount(labels[grid_touch], minlength=K) > 0
    touch_m = np.bincount(labels[near_robot], minlength=K) > 0
    entry: np.ndarray = np.zeros(K, dtype=bool)
    if len(ctx.entry_lo):
        entry = np.asarray((_box_gap(clo, chi, ctx.entry_lo, ctx.entry_hi) <= eps).any(axis=1))

    # The shell rule, part-wise: a piece inside a shell (around the robot or an obstacle, or
    # a noise sheet) goes unless a piece of its component outside every shell lies within
    # ``floor_shell_margin`` of it (a person reaching into the shell, standing on the floor).
    spared = boundary[labels] & p.keep_at_boundary
    shell_cut = np.zeros(n, dtype=bool)
    if p.too_thin:
        shell_cut = shell_cuts(vertices, inside, spared, ctx, pool)
    small = np.zeros(K, dtype=bool)
    if p.too_small:
        rest = np.bincount(labels, weights=np.where(shell_cut, 0.0, volumes), minlength=K)
        small = rest < p.min_volume
        small &= ~_attached_through_m(small, touch_m, labels, lo, hi, clo, chi, pool)
    on_surface = np.zeros(K, dtype=bool)  # reaches a sheet (the floor, an obstacle face)
    if p.flying:
        supported = touch_m.copy()
        assert sheet_pairs is not None
        pairs, b, arr = sheet_pairs
        keep = ~shell_cut[pairs[:, 0]]
        pairs, b = pairs[keep], b[keep]
        sh_i = pairs[:, 1]
        f = arr.face[sh_i]
        ok = (b[:, 2] <= arr.height[sh_i] + eps) & (b[:, 5] >= -eps)
        ok &= (b[:, 3] >= f[:, 0]) & (b[:, 0] <= f[:, 2]) & (b[:, 4] >= f[:, 1]) & (b[:, 1] <= f[:, 3])
        supported[labels[pairs[ok, 0]]] = True
        on_surface[labels[pairs[ok, 0]]] = True
    else:
        supported = np.ones(K, dtype=bool)
    if ctx.static_near is not None:
        # The grid's "touches R3_static" is a superset (5 cm voxels: up to ~0.19 m beyond
        # support_eps). Where it alone spares a component from too_small or flying, it is
        # confirmed exactly; see _confirm_static_touch.
        doubt = touch_static & ~(boundary & p.keep_at_boundary) & (small | ~supported)
        if doubt.any():
            touch_static[doubt] = _confirm_static_touch(
                np.nonzero(doubt)[0], labels, lo, hi, grid_touch, ctx.static_near, eps
            )
    spared_shape = touch_static | (boundary & p.keep_at_boundary)
    fires: dict[str, np.ndarray] = {}
    if p.too_small:
        fires["too_small"] = small & ~spared_shape
    if p.flying:
        fires["flying"] = ~supported & ~spared_shape
    history = ctx.previous_lo is not None and ctx.dt is not None
    if history and (p.entry or p.teleport):
        reach = p.human_speed_max * float(ctx.dt)  # type: ignore[arg-type]
        if len(ctx.previous_lo):  # type: ignore[arg-type]
            gap = _box_gap(clo, chi, ctx.previous_lo, ctx.previous_hi).min(axis=1)  # type: ignore[arg-type]
        else:
            gap = np.full(K, np.inf)
        near_static = ctx.static_touch.any_in(clo - reach, chi + reach)
        open_ = boundary | entry | touch_m | touch_static
        if p.entry:
            fires["entry"] = ~open_ & ~(gap <= reach + eps) & ~near_static
        if p.teleport:
            fires["teleport"] = ~open_ & (gap > reach) & ~near_static

    rule_of = np.full(K, "", dtype=object)
    for name in RULE_ORDER:
        if name in fires:
            hit = fires[name] & (rule_of == "")
            rule_of[hit] = name
    removed_c = rule_of != ""
    keep = ~removed_c[labels] & ~shell_cut

    removed = _removed(labels, K, lo, hi, volumes, shell_cut, removed_c, rule_of, c.volume, make_mesh, vertices)

    # Only components that pass too_small and flying on their own (not only because they
    # touch R3_static or the boundary) keep the sheet under them: a person does; noise
    # spared next to a static blind region does not need a floor under it.
    own = keep & ~(small | ~supported)[labels]
    if memory is not None:
        own &= ~memory
    if residue is None:
        residue = np.zeros(n, dtype=bool)
    elif residue.any():
        seen = np.bincount(labels, weights=(~residue & ~shell_cut).astype(np.float64), minlength=K) > 0
        own &= seen[labels]
    # Seeds of the next cycle's shadow memory: what was seen as a target, standing on a
    # surface or coming in over the boundary, not what M alone or R3_static spared.
    # Pieces inside a shell or a noise sheet are left out: feet in the floor's sheet lie
    # within the sheet margin of the legs that seed.
    seeds = own & ~inside & (on_surface | (boundary & p.keep_at_boundary) | ~np.bool_(p.flying))[labels]
    hiding = own & touch_m[labels] if p.too_thin else np.zeros(n, dtype=bool)
    return DynamicResult(keep, labels, own, spared, inside, removed, seeds, hiding, residue)


class _Components(NamedTuple):
    """The components of the dynamic pieces, and the per-piece tests the rules read."""

    labels: np.ndarray  # (N,) component of every piece
    n_components: int  # K
    lo: ArrayF64  # (K, 3) their bounding boxes
    hi: ArrayF64
    volume: ArrayF64  # (K,) their volumes [m^3] (overlapping pieces count twice)
    grid_touch: np.ndarray  # (N,) the piece may touch R3_static (the touch grid)
    near_robot: np.ndarray  # (N,) the piece ends at the robot's shadow or meets its balls
    inside: np.ndarray  # (N,) the piece lies inside a shell or a noise sheet
    sheet_pairs: tuple | None  # (piece, sheet) pairs of the flying rule (None without it)


def _components(
    vertices: ArrayF64,
    lo: ArrayF64,
    hi: ArrayF64,
    volumes: ArrayF64,
    at_robot: np.ndarray,
    ctx: DynamicContext,
    pool: Executor | None,
) -> _Components:
    """The components: boxes whose growths by TOUCH_EPS overlap, transitively (pieces that
    touch or overlap have overlapping bounding boxes, so every true component lies in one
    group; grouping more only makes the rules fire less). The sweep's construction, the
    per-piece tests and the sweep's parts run on this thread and one of the pool's (each
    taking the next task when done, in that order: the tests beside the construction)."""
    p = ctx.params
    eps = p.support_eps
    n = len(vertices)

    def per_piece() -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple | None]:
        near_robot = at_robot.copy()
        if len(ctx.robot_spheres):
            near_robot |= _near_balls(lo, hi, np.ascontiguousarray(ctx.robot_spheres, dtype=np.float64), eps)
        inside = in_shells(vertices, ctx) if p.too_thin else np.zeros(n, dtype=bool)
        sheet_pairs = _sheet_pairs(vertices, ctx.sheets, eps) if p.flying else None
        return ctx.static_touch.any_in(lo, hi), near_robot, inside, sheet_pairs

    two = pool if n >= PARALLEL_MIN else None  # fewer: a thread's wake-up costs more than the work
    parts = GROUP_PARTS if two is not None else 1
    sweep: list[OverlapSweep] = []  # built by the first task, while the other thread tests
    built = threading.Event()
    tests = []

    def task(i: int) -> np.ndarray | None:
        if i == -2:
            try:
                sweep.append(OverlapSweep(lo - TOUCH_EPS, hi + TOUCH_EPS, parts))
            finally:
                built.set()  # (a failed build raises here; the scans then return nothing)
            return None
        if i == -1:
            tests.append(per_piece())
            return None
        built.wait()
        return sweep[0].scan(i) if sweep else None

    # the tasks are taken in order: the build first, so a scan waits only for a build
    # another thread runs
    forests = share(two, task, range(-2, parts))
    labels = sweep[0].labels([f for f in forests if f is not None])
    K = int(labels.max()) + 1
    clo, chi = group_bounds(labels, lo, hi, K)
    volume = np.asarray(np.bincount(labels, weights=volumes, minlength=K), dtype=np.float64)
    return _Components(labels, K, clo, chi, volume, *tests[0])


def _removed(
    labels: np.ndarray,
    K: int,
    lo: ArrayF64,
    hi: ArrayF64,
    volumes: ArrayF64,
    shell_cut: np.ndarray,
    removed_c: np.ndarray,
    rule_of: np.ndarray,
    component_volume: ArrayF64,
    make_mesh,  # noqa: ANN001 - (indices) -> manifold3d.Manifold, called lazily
    vertices: ArrayF64,
) -> tuple[RemovedComponent, ...]:
    """The removals to report: per component, its pieces the shell rule cut (``too_thin``),
    then every component a rule removed whole (``rule_of``, of ``component_volume``),
    with volume and centroid (the pieces' ``vertices`` (N, 8, 3) for their drawing)."""
    removed: list[RemovedComponent] = []
    if not (shell_cut.any() or removed_c.any()):
        return ()
    # each component's pieces, in order (one sort, not a pass over all pieces per component)
    by_label = np.argsort(labels, kind="stable")
    starts = np.searchsorted(labels[by_label], np.arange(K + 1))
    # per component, the volume and the volume-weighted centre of its pieces, and of its
    # pieces the shell rule cut (bincounts, not numpy calls per component)
    centre = 0.5 * (lo + hi) * volumes[:, None]
    cut_w = np.where(shell_cut, volumes, 0.0)
    sums = [np.bincount(labels, weights=w, minlength=K) for w in (volumes, cut_w)]
    moments = [
        np.stack([np.bincount(labels, weights=centre[:, a] * m, minlength=K) for a in range(3)], axis=1)
        for m in (1.0, shell_cut)
    ]

    def one(rule: str, k: int, idx: np.ndarray, cut: int, volume: float | None = None) -> RemovedComponent:
        vol = float(sums[cut][k])
        centroid = moments[cut][k] / max(vol, 1e-12)
        return RemovedComponent(rule, vol if volume is None else volume, centroid, LazyMesh(make_mesh, idx, vertices))

    for k in np.unique(labels[shell_cut & ~removed_c[labels]]):
        idx = by_label[starts[k] : starts[k + 1]]
        removed.append(one("too_thin", int(k), idx[shell_cut[idx]], 1))
    for k in np.nonzero(removed_c)[0]:
        removed.append(one(str(rule_of[k]), int(k), by_label[starts[k] : starts[k + 1]], 0, float(component_volume[k])))
    return tuple(removed)


LEG_HEIGHTS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
"""[m] Heights above the floor at which the columns under those pieces are tested for M:
a hidden leg crosses the top of the floor's sheet (0.24 m at most in the paper cell) in M."""

LEG_GRID = 0.05
"""[m] Step of the columns' grid: a shin or the shadow hiding it (7 cm across or more, the
detection capability) holds one of its points (a disc of diameter sqrt(2) x 5 cm does)."""


def hidden_legs(lo: ArrayF64, hi: ArrayF64, touching: np.ndarray, ctx: DynamicContext) -> ArrayF64:
    """(L, 8, 3) boxes standing for the legs the robot may hide: under the kept pieces
    ``touching`` (N,) M (of components that touch it; bounds ``lo``, ``hi`` (N, 3)),
    however high they start, every column of a ``LEG_GRID`` grid over their footprints that
    holds a point of M at a height of ``LEG_HEIGHTS`` (``ctx.m_columns``), from the floor up
    to the highest of them (through the top of the floor's sheet, however thick it is there).

    A person whose legs the robot hides from every camera stands on M (the rules keep
    them: :func:`judge_dynamic`), but nothing of them crosses the floor's sheet where the
    legs are: their feet, inside the sheet and outside M, went with the sheet rule. Any
    possibly occupied space over M may hold such a body, and its hidden legs cross the
    sheet's top in M under it, so the floor's sheet kept under these boxes (grown by the
    margin, :func:`sheets_under` with ``horizontal``) holds the feet. M holds the padded
    robot too: a leg may stand in its padding, and under an arm swept that low beside a
    person the sheet then reaches the arm (a contact). Away from the robot M has no point
    so low, and nothing is added. The body seen may start high: a person lunging at the
    robot's base and reaching over it, whom the base and the arm hide from the floor to
    1.1 m (a search of random walks found one whose forward foot, 0.33 m from the base's
    axis, went with the sheet rule while only pieces starting below 1 m were looked under)."""
    if ctx.m_columns is None or not touching.any():
        return np.zeros((0, 8, 3))
    zlo = np.asarray(ctx.zone.min, dtype=np.float64)
    zhi = np.asarray(ctx.zone.max, dtype=np.float64)
    g = LEG_GRID
    xy = _footprint_columns(lo, hi, touching, zlo, zhi, g)
    if len(xy) == 0:
        return np.zeros((0, 8, 3))
    col = np.isfinite(ctx.m_columns(xy, zlo[2] + np.asarray(LEG_HEIGHTS)))
    if not col.any():
        return np.zeros((0, 8, 3))
    # a leg from the floor up through every sheet's top (whatever the local thickness)
    c0 = xy[col] - 0.5 * g
    z0 = np.full(len(c0), zlo[2] - ctx.params.support_eps)
    return box_vertices(np.column_stack([c0, z0]), np.column_stack([c0 + g, z0 + ctx.params.support_eps + LEG_HEIGHTS[-1]]))


@nb.njit(cache=True, nogil=True)
def _footprint_columns(lo, hi, touching, zlo, zhi, g):  # pragma: no cover - compiled
    """(C, 2) the centres of the cells of a ``g`` grid (from ``zlo``) that the footprints
    of the boxes ``touching`` cover (clipped to the zone ``[zlo, zhi]``; a box covers the
    cells ``floor(lo / g) <= cell < ceil(hi / g)`` on x and y)."""
    a0 = a1 = np.iinfo(np.int64).max
    b0 = b1 = np.iinfo(np.int64).min
    n = 0
    for i in range(lo.shape[0]):
        if touching[i]:
            n += 1
            a0 = min(a0, int(np.floor((min(max(lo[i, 0], zlo[0]), zhi[0]) - zlo[0]) / g)))
            a1 = min(a1, int(np.floor((min(max(lo[i, 1], zlo[1]), zhi[1]) - zlo[1]) / g)))
            b0 = max(b0, int(np.ceil((min(max(hi[i, 0], zlo[0]), zhi[0]) - zlo[0]) / g)))
            b1 = max(b1, int(np.ceil((min(max(hi[i, 1], zlo[1]), zhi[1]) - zlo[1]) / g)))
    if n == 0 or b0 <= a0 or b1 <= a1:
        return np.zeros((0, 2))
    occ = np.zeros((b0 - a0, b1 - a1), dtype=np.bool_)
    count = 0
    for i in range(lo.shape[0]):
        if touching[i]:
            x0 = int(np.floor((min(max(lo[i, 0], zlo[0]), zhi[0]) - zlo[0]) / g)) - a0
            y0 = int(np.floor((min(max(lo[i, 1], zlo[1]), zhi[1]) - zlo[1]) / g)) - a1
            x1 = int(np.ceil((min(max(hi[i, 0], zlo[0]), zhi[0]) - zlo[0]) / g)) - a0
            y1 = int(np.ceil((min(max(hi[i, 1], zlo[1]), zhi[1]) - zlo[1]) / g)) - a1
            for x in range(x0, x1):
                for y in range(y0, y1):
                    if not occ[x, y]:
                        occ[x, y] = True
                        count += 1
    out = np.empty((count, 2))
    c = 0
    for x in range(occ.shape[0]):
        for y in range(occ.shape[1]):
            if occ[x, y]:
                out[c, 0] = zlo[0] + (x + a0 + 0.5) * g
                out[c, 1] = zlo[1] + (y + a1 + 0.5) * g
                c += 1
    return out


ARM_LENGTH = 0.75
"""[m] Shoulder to fingertip: how far from a person's seen body a part of them (a hand)
may be seen alone, the arm between hidden by the robot."""


def _attached_through_m(
    small: np.ndarray, touch_m: np.ndarray, labels: np.ndarray, lo: ArrayF64, hi: ArrayF64,
    clo: ArrayF64, chi: ArrayF64, pool: Executor | None,
) -> np.ndarray:
    """(K,) the components too small on their own that may be a part of a person whose rest
    the robot hides: they touch M, and a piece of them (``lo``, ``hi`` (N, 3)) comes within
    ``ARM_LENGTH`` of a piece of a component that passes the size rule and touches M too
    (a hand reaching past the robot's arm, the forearm hidden, the body seen). Judged with
    that body through M, they are not too small. The components' boxes (``clo``, ``chi``
    (K, 3)) select the few that need the pieces' test."""
    big = ~small & touch_m
    cand = np.nonzero(small & touch_m)[0]
    out = np.zeros(len(small), dtype=bool)
    if not (big.any() and len(cand)):
        return out
    b = big[labels]
    blo, bhi = lo[b], hi[b]
    # the components' boxes first (a superset), then the pieces of those that pass
    cand = cand[any_overlap(clo[cand], chi[cand], blo, bhi, pool, reach=ARM_LENGTH)]
    if len(cand):
        q = np.zeros(len(small), dtype=bool)
        q[cand] = True
        q = q[labels]
        near = any_overlap(lo[q], hi[q], blo, bhi, pool, reach=ARM_LENGTH)
        out[np.unique(labels[q][near])] = True
    return out


def _confirm_static_touch(
    components: np.ndarray,
    labels: np.ndarray,
    lo: ArrayF64,
    hi: ArrayF64,
    grid_touch: np.ndarray,
    static_near: StaticNear,
    eps: float,
) -> np.ndarray:
    """(C,) whether each of ``components`` really comes within ``eps`` of R3_static: some
    piece whose bounding box [lo, hi] meets the touch grid (the others are farther than
    ``eps`` for sure) has its box, grown by ``eps``, meet the surface of R3_static.

    A component judged not touching is removed only of what R3_static does not hold:
    every piece's grown box is then wholly outside R3_static (the piece farther than
    ``eps`` from it) or wholly inside it (the piece is part of R3_static, which stays in
    the region). So the rules see the pieces outside R3_static as the separate component
    they are, which the too_small and flying rules judge; the grid's slack kept
    dropout residue 0.16 to 0.2 m from a static blind region as if it touched it.
    """
    idx = np.nonzero(np.isin(labels, components) & grid_touch)[0]
    group = np.searchsorted(components, labels[idx])  # components are sorted
    return np.asarray(static_near(lo[idx], hi[idx], eps, group, len(components)), dtype=bool)


SHEET_STEP = 0.03
"""Height change [m] of the sheet's height map that starts a new sheet box along a run."""


def crosses_sheet_top(vertices: ArrayF64, ctx: DynamicContext) -> np.ndarray:
    """(N,) whether each piece crosses the top face of some sheet over that sheet's face:
    the pieces that keep the sheet under them (:func:`sheets_under`)."""
    out = np.zeros(vertices.shape[0], dtype=bool)
    idx, _ = _crossing_pairs(vertices, ctx)
    out[idx[:, 0]] = True
    return out


def sheets_under(vertices: ArrayF64, ctx: DynamicContext, horizontal: bool = False) -> ArrayF64:
    """Boxes (S, 8, 3) of the sheets under kept pieces (see the module docstring): for
    every piece that crosses a sheet's top face (or reaches into a vertical sheet), the
    sheet within ``floor_shell_margin`` of the piece's footprint on the face (a disc
    around it, in rows of ``SHEET_PITCH / SHEET_ROWS``), clipped to the face;
    on a vertical face, the footprint reaches down to the face's bottom, and for a piece
    that reaches it from above its (low) upper edge, the floor's sheet (or a top's) is
    kept under those boxes in turn (the feet of a person at a table).

    Per sheet and row, the union of the footprints' discs along x (a superset: the half
    width at the row's least distance), as one box per run of height-map cells of
    ``SHEET_PITCH``, the run broken where the map changes by more than ``SHEET_STEP``: each
    box is as high as C_static reaches in the slab over its run (the sheet's height where no
    height map is known); boxes equal in the rows after extend. One compiled
    pass over the sheets (:func:`_sheet_boxes`). ``horizontal``: the horizontal sheets only
    (no vertical face's, nor what hangs from it)."""
    if vertices.shape[0] == 0 or not ctx.sheets:
        return np.zeros((0, 8, 3))
    pairs, bounds = _crossing_pairs(vertices, ctx)
    arr = _sheet_arrays(tuple(ctx.sheets))
    if horizontal:  # the floor's sheet and the tops' only
        flat = arr.down[pairs[:, 1]] < 0
        pairs, bounds = pairs[flat], bounds[flat]
    if len(pairs) == 0:
        return np.zeros((0, 8, 3))
    # on a vertical face, the body over the pieces' footprint can reach down to the floor
    # inside the sheet (legs closer to a wall or a table's side than its sheet is thick):
    # the boxes hang down to the face's bottom. Where the piece reaches in from above the
    # face's edge (a person at a table, seen only above it), the floor's sheet is kept
    # under those boxes in turn (the feet)
    vertical = arr.down[pairs[:, 1]] >= 0
    if not vertical.any():
        return _boxes_of_pairs(pairs, bounds, arr, ctx)
    hanging = _boxes_of_pairs(pairs[vertical], bounds[vertical], arr, ctx, down=True)
    parts = [_boxes_of_pairs(pairs[~vertical], bounds[~vertical], arr, ctx), hanging]
    above = _from_above(pairs, bounds, arr)
    if above.any():
        p2, b2 = _crossing_pairs(_boxes_of_pairs(pairs[above], bounds[above], arr, ctx, down=True), ctx)
        flat = arr.down[p2[:, 1]] < 0
        parts.append(_boxes_of_pairs(p2[flat], b2[flat], arr, ctx))
    return np.concatenate(parts)


def _from_above(pairs: np.ndarray, bounds: ArrayF64, arr: _SheetArrays) -> np.ndarray:
    """(P,) the crossing pairs on a vertical face whose piece reaches into the sheet from
    above the face's upper edge, where that edge is lower than ``STANDING_HEIGHT`` (a
    person at a table, seen above it), without crossing the sheet's top face."""
    s = pairs[:, 1]
    down = arr.down[s]
    f = arr.face[s]
    top = np.where(down == 0, f[:, 2], f[:, 3])  # the face's upper edge (world z)
    reach = np.where(down == 0, bounds[:, 3], bounds[:, 4])
    return (down >= 0) & (reach >= top) & (top <= STANDING_HEIGHT) & (bounds[:, 5] < arr.height[s])


def _boxes_of_pairs(
    pairs: np.ndarray, bounds: ArrayF64, arr: _SheetArrays, ctx: DynamicContext, down: bool = False
) -> ArrayF64:
    """:func:`_sheet_boxes` of crossing pairs (P, 2) and the pieces' local bounds (P, 6);
    ``down``: the footprints on vertical faces reach down to the face's bottom."""
    if len(pairs) == 0:
        return np.zeros((0, 8, 3))
    maps = _height_maps(ctx.sheet_heights, len(ctx.sheets))
    order = np.argsort(pairs[:, 1], kind="stable")
    hang = arr.down if down else arr.no_down
    return _sheet_boxes(
        np.ascontiguousarray(pairs[order, 1]), np.ascontiguousarray(bounds[order]), arr.face, arr.W, arr.height,
        hang, maps[0], maps[1], maps[2], float(ctx.params.floor_shell_margin), SHEET_PITCH, SHEET_STEP,
    )


_HEIGHT_MAPS: list[tuple[tuple[np.ndarray, ...], tuple[ArrayF64, np.ndarray, np.ndarray]]] = []


def _height_maps(heights: tuple[np.ndarray, ...], n: int) -> tuple[ArrayF64, np.ndarray, np.ndarray]:
    """The sheets' height maps flat: values, (S,) offsets, (S, 2) shapes ((0, 0): none);
    kept for the last few tuples of maps (the monitor passes the same one every cycle)."""
    for key, val in _HEIGHT_MAPS:
        if key is heights:
            return val
    maps = list(heights) if heights else [None] * n
    shapes = np.zeros((n, 2), dtype=np.int64)
    offsets = np.zeros(n, dtype=np.int64)
    parts = []
    at = 0
    for k, h in enumerate(maps):
        offsets[k] = at
        if h is not None:
            h = np.ascontiguousarray(h, dtype=np.float64)
            shapes[k] = h.shape
            parts.append(h.ravel())
            at += h.size
    val = (np.concatenate(parts) if parts else np.zeros(0), offsets, shapes)
    _HEIGHT_MAPS.insert(0, (heights, val))
    del _HEIGHT_MAPS[4:]
    return val


SHEET_ROWS = 1
"""Rows of the sheet boxes per ``SHEET_PITCH`` cell (see :func:`_sheet_boxes`): each row's
boxes end where the disc around a footprint ends, to ``SHEET_PITCH / SHEET_ROWS`` across.
On the bench walk, 2 rows a cell took 0.01 m more off the person's median gap than 1 row
(0.338 against 0.349 m) for about twice the sheet boxes (700 to 850 against 175 to 480 in
the near cycles), 4 rows nothing more for 1,100 to 1,600."""


@nb.njit(cache=True, nogil=True)
def _sheet_boxes(sheet, bounds, face, W, height, down, hflat, hoff, hshape, margin, pitch, step):  # pragma: no cover - compiled
    """World boxes (B, 8, 3) of :func:`sheets_under` from the crossing pairs' sheets (P,)
    (sorted) and the pieces' local bounds (P, 6); ``down`` (S,): the local axis along world
    z of a vertical sheet (its footprints reach down to the face's bottom), -1 otherwise.

    Per sheet, in rows ``pitch / SHEET_ROWS`` wide along the face's local y: in each row, the
    union of the x intervals within ``margin`` of a footprint (the disc around it, its
    half-width at the row's least distance to the footprint, so a superset), clipped to the
    face; each interval is cut where the height map (cells of ``pitch``) changes by more
    than ``step`` from the run's first cell, and each part is a box as high as the highest
    cell it covers; a box equal along x and in height to one in the row before extends it."""
    out = np.empty((64, 8, 3))
    nb_out = 0
    P = sheet.shape[0]
    hs = pitch / SHEET_ROWS
    m2 = margin * margin
    p0 = 0
    while p0 < P:
        k = sheet[p0]
        p1 = p0
        while p1 < P and sheet[p1] == k:
            p1 += 1
        x0, y0, x1, y1 = face[k, 0], face[k, 1], face[k, 2], face[k, 3]
        # the footprints (on a vertical face from the face's bottom) whose grown box meets the face
        fp = np.empty((p1 - p0, 4))
        m = 0
        ymin = np.inf
        ymax = -np.inf
        xmax = -np.inf
        for p in range(p0, p1):
            fx0 = x0 if down[k] == 0 else bounds[p, 0]
            fy0 = y0 if down[k] == 1 else bounds[p, 1]
            fx1 = bounds[p, 3]
            fy1 = bounds[p, 4]
            if not (min(fx1 + margin, x1) > max(fx0 - margin, x0) and min(fy1 + margin, y1) > max(fy0 - margin, y0)):
                continue
            fp[m, 0], fp[m, 1], fp[m, 2], fp[m, 3] = fx0, fy0, fx1, fy1
            ymin = min(ymin, max(fy0 - margin, y0))
            ymax = max(ymax, min(fy1 + margin, y1))
            xmax = max(xmax, min(fx1 + margin, x1))
            m += 1
        p0 = p1
        if m == 0:
            continue
        # the height map's cells over the footprints' reach
        s0 = int(np.ceil((xmax - x0) / pitch))
        s1 = int(np.ceil((ymax - y0) / pitch))
        col_h = np.full((max(s0, 1), max(s1, 1)), height[k])
        h0, h1 = hshape[k, 0], hshape[k, 1]
        for i in range(min(s0, h0)):
            for j in range(min(s1, h1)):
                col_h[i, j] = hflat[hoff[k] + i * h1 + j]
        local = np.empty((64, 5))  # lx, ly, hx, hy, top
        nl = 0
        last = np.empty(16, dtype=np.int64)  # the row before's boxes (indices into local)
        n_last = 0
        ia = np.empty(m)
        ib = np.empty(m)
        r0 = int(np.floor((ymin - y0) / hs))
        for r in range(r0, int(np.ceil((ymax - y0) / hs))):
            ya = y0 + r * hs
            yb = min(ya + hs, y1)
            if not yb > ya:
                break
            j = min(int(np.floor((ya - y0) / pitch + 1e-9)), s1 - 1)
            # this row's intervals, sorted by their start (insertion: few footprints a sheet)
            n = 0
            for q in range(m):
                dy = max(max(fp[q, 1] - yb, ya - fp[q, 3]), 0.0)
                if dy > margin:
                    continue
                w = np.sqrt(max(m2 - dy * dy, 0.0))
                a = max(fp[q, 0] - w, x0)
                b = min(fp[q, 2] + w, x1)
                if not b > a:
                    continue
                t = n
                while t > 0 and ia[t - 1] > a:
                    ia[t] = ia[t - 1]
                    ib[t] = ib[t - 1]
                    t -= 1
                ia[t] = a
                ib[t] = b
                n += 1
            now = np.empty(max(16, 2 * n_last), dtype=np.int64)  # this row's boxes
            n_now = 0
            t = 0
            while t < n:
                a = ia[t]
                b = ib[t]
                t += 1
                while t < n and ia[t] <= b:
                    b = max(b, ib[t])
                    t += 1
                # the merged interval [a, b], cut where the height changes
                i = min(int(np.floor((a - x0) / pitch)), s0 - 1)
                i_end = min(int(np.ceil((b - x0) / pitch)), s0)
                while i < i_end:
                    start = i
                    base = col_h[i, j]
                    top = base
                    i += 1
                    while i < i_end and abs(col_h[i, j] - base) <= step:
                        top = max(top, col_h[i, j])
                        i += 1
                    lx = max(a, x0 + start * pitch)
                    hx = min(b, x0 + i * pitch)
                    if not hx > lx:
                        continue
                    e = -1  # a box of the row before, equal along x and in height, grows
                    for t2 in range(n_last):
                        g = last[t2]
                        if local[g, 0] == lx and local[g, 2] == hx and local[g, 4] == top and local[g, 3] == ya:
                            local[g, 3] = yb
                            e = g
                            break
                    if e < 0:
                        if nl == local.shape[0]:
                            more = np.empty((2 * nl, 5))
                            more[:nl] = local[:nl]
                            local = more
                        local[nl, 0], local[nl, 1], local[nl, 2], local[nl, 3], local[nl, 4] = lx, ya, hx, yb, top
                        e = nl
                        nl += 1
                    if n_now == now.shape[0]:
                        more_i = np.empty(2 * n_now, dtype=np.int64)
                        more_i[:n_now] = now[:n_now]
                        now = more_i
                    now[n_now] = e
                    n_now += 1
            last, n_last = now, n_now
        for e in range(nl):
            if nb_out == out.shape[0]:
                grown_out = np.empty((2 * out.shape[0], 8, 3))
                grown_out[:nb_out] = out[:nb_out]
                out = grown_out
            lx, ly, hx, hy, top = local[e, 0], local[e, 1], local[e, 2], local[e, 3], local[e, 4]
            for c in range(8):
                x = lx if (c % 4 == 0 or c % 4 == 3) else hx
                y = ly if (c % 4 < 2) else hy
                z = 0.0 if c < 4 else top
                for a3 in range(3):
                    out[nb_out, c, a3] = W[k, a3, 0] * x + W[k, a3, 1] * y + W[k, a3, 2] * z + W[k, a3, 3]
            nb_out += 1
    return out[:nb_out]


class LazyMesh:
    """A removed component's mesh, ``make(idx)``, built when first read; the component is
    the union of the hexahedra ``pieces[idx]`` (``pieces`` (N, 8, 3))."""

    def __init__(self, make, idx: np.ndarray, pieces: ArrayF64) -> None:  # noqa: ANN001
        self._make = make
        self._idx = idx
        self._pieces = pieces
        self._mesh = None

    def get(self):  # noqa: ANN201
        if self._mesh is None:
            self._mesh = self._make(self._idx)
        return self._mesh

    def drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """Its hexahedra as triangles, not united (:func:`polyhull.distance.hexahedra_triangles`)."""
        return hexahedra_triangles(self._pieces[self._idx])
