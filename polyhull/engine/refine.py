"""Refinement at the distance frontier: the dynamic pieces that decide the distance, fine.

The carve splits undecided pieces down to a size that grows with their distance to the
robot (:mod:`polyhull.engine.pieces`); a kept piece near the robot can be centimetres to
decimetres larger than the occupied space it stands for, and the distance that much
short. Worse, a coarse piece whose top only seems to cross the top of the floor's noise
sheet keeps the sheet under it and the pieces inside the sheet within
``floor_shell_margin`` (a person's feet), which brings both toward the robot. So:

- the **first carve** already counts a piece's distance from the last cycle's distance
  less ``FRONT_SLACK`` (the frontier, where the distance is decided) and splits pieces
  that cross the floor sheet's top within ``REACH_EXTRA + floor_shell_margin`` of it down
  to the smallest size;
- after the rules, the **frontier** F is the distance the region has now (python-fcl,
  with the sheets under the pieces); refinement only removes space, so the final
  distance is at least F. The pipeline passes the first carve's frontier as a hint:
  when no piece's lower bound lies more than ``BAND`` below it, F is the hint and that
  measurement is skipped (one python-fcl pass less, ~3 ms a cycle on the bench walk);
  the frontier only steers how finely pieces are carved, never what is kept, and the
  distance reported is the refined region's either way;
- refinement is left out when the nearest part of the region is one it never changes:
  the static region, or ``extra()`` (the sheet under the legs the robot may hide). Both
  are in the refined region too, and refinement only removes space, so the refined
  region's distance is theirs as well; only the pieces the verdict holds are coarser
  (a superset of the refined ones). They are sought below the pieces' lower bounds and,
  when the last cycle's distance was theirs, within ``SURE_SLACK`` of it; when one is found
  there, the pieces and sheets whose bounds are below it are measured against it (none
  nearer: left out; else refined from the same frontier as without the check). On the
  bench walk this leaves out the refinement of 7 of the 20 timed cycles (the static region
  decides while the person is far), with the same distances (and the eight colour
  cameras' walk's), 1 to 3 ms of their distance stage; in the empty cell, of 21 of its
  first 30 cycles, and its kept pieces, unrefined there, add 15.5 l outside ``C_static`` in
  the median of the bench's 100 cycles instead of 15.0 l (29.3 instead of 24.4 l at most);
- pieces whose lower bound of the distance to the robot (the padded pieces' bounding
  spheres) is within ``BAND`` of F are carved again with F as the offset of the size
  budget: pieces at the frontier are split down to ``FINE``, coarser behind it; pieces
  that cross a sheet's top within ``REACH_EXTRA + floor_shell_margin`` of F are split down
  to ``FINE`` everywhere; each round splits a piece to at most a quarter of its size
  (the shadow memory's pieces that cross a sheet's top within ``BAND`` of F, carved at
  ``MEMORY_PIECE`` and left to this step to split, down to ``FINE`` at once, the nearest
  ``MEMORY_FINE``: at a quarter, a memory piece that seemed to cross the floor sheet's top
  kept the sheet within ``floor_shell_margin`` of its whole box, which only a second round
  removed), a
  piece that comes back unchanged is ``SETTLED``, at most ``ROUNDS`` rounds; the pieces
  farther than that reach from the first frontier keep their sheets and distance,
  measured once;
- the part-wise shell rule runs again where its keepers changed (a piece in a sheet kept
  only because a coarse piece seemed to stand out of it goes), then the sheets under the
  pieces that stand on a surface (:func:`polyhull.engine.dynamic_rules.sheets_under`).

Carving drops only space that enough cameras see free, so the refined pieces hold every
possibly occupied point of the pieces they replace. They inherit their parent's verdict
without the rules running again: the rules only remove more from smaller components, so
keeping them is conservative; the shell rule on the finer pieces is the same rule, applied
to a finer description of the same set.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from typing import Any, NamedTuple

import numba as nb
import numpy as np

from ..distance import DistanceResult
from ..typed import ArrayF64
from .boxes import any_near_upright
from .pieces import PieceSet, vertex_bounds
from .static_model import SHEET_PITCH

__all__ = [
    "BAND",
    "FINE",
    "FRONT",
    "MEMORY",
    "MEMORY_FINE",
    "OWN",
    "FRONT_SLACK",
    "REACH_EXTRA",
    "RESIDUE",
    "ROUNDS",
    "SETTLED",
    "SPARED",
    "Refined",
    "RegionRules",
    "distance_lower_bounds",
    "refine_kept",
]

FINE = 0.02
"""Smallest piece size [m] at the frontier."""

BAND = 0.3
"""Depth [m] behind the frontier within which kept pieces are carved again."""

ROUNDS = 1
"""Refinement rounds per cycle. On the bench walk (loaded 2-core machine): 0 rounds,
true minus reported distance 0.81 m in the median; 1 round 0.63 m; 4 rounds 0.59 m at twice
the cost of one."""

MEMORY_FINE = 64
"""The most shadow-memory pieces crossing a sheet's top at the frontier that a round splits
straight down to ``FINE`` (the nearest first; the rest, like every other piece, to a
quarter of the largest)."""

FRONT_SLACK = 0.3
"""How far [m] the frontier may come nearer between two cycles (a person's and the
robot's motion within a cycle): the first carve refines from the last distance less this."""

REACH_EXTRA = BAND + 2.0 * SHEET_PITCH
"""With ``floor_shell_margin``: how far behind the frontier [m] a piece that crosses a
sheet's top is split finely (its sheet box reaches the margin, rounded outward by the
sheet cells, nearer)."""


def distance_lower_bounds(vertices: ArrayF64, spheres: ArrayF64) -> ArrayF64:
    """(N,) a lower bound of each hexahedron's (N, 8, 3) distance to the robot, whose
    padded pieces lie in the balls ``spheres`` (S, 4): centre distance minus both radii."""
    if vertices.shape[0] == 0 or len(spheres) == 0:
        return np.full(vertices.shape[0], np.inf)
    return _lower_bounds(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(spheres, dtype=np.float64))


@nb.njit(cache=True, nogil=True)
def _lower_bounds(vertices, spheres):  # pragma: no cover - compiled
    n, m = vertices.shape[0], vertices.shape[1]
    out = np.empty(n)
    for i in range(n):
        c0 = c1 = c2 = 0.0
        for k in range(m):
            c0 += vertices[i, k, 0]
            c1 += vertices[i, k, 1]
            c2 += vertices[i, k, 2]
        c0 /= m
        c1 /= m
        c2 /= m
        rad = 0.0
        for k in range(m):
            dx = vertices[i, k, 0] - c0
            dy = vertices[i, k, 1] - c1
            dz = vertices[i, k, 2] - c2
            rad = max(rad, np.sqrt(dx * dx + dy * dy + dz * dz))
        d = np.inf
        for s in range(spheres.shape[0]):
            dx = c0 - spheres[s, 0]
            dy = c1 - spheres[s, 1]
            dz = c2 - spheres[s, 2]
            d = min(d, np.sqrt(dx * dx + dy * dy + dz * dz) - spheres[s, 3])
        out[i] = max(d - rad, 0.0)
    return out


OWN = 1
"""Flag: the piece keeps the noise sheet under it."""
MEMORY = 2
"""Flag: the piece is of the shadow memory (carved with the memory's segments)."""
SPARED = 4
"""Flag: the piece's component touches the boundary of Z (kept by ``keep_at_boundary``)."""
SETTLED = 8
"""Flag: carving returned the piece unchanged (no camera frees any of it, or it is at its
size budget): not carved again this cycle."""
FRONT = 16
"""Flag (with ``MEMORY``): the piece is of the memory's part in front of the robot (a colour
camera's, carved with those segments)."""
RESIDUE = 32
"""Flag: the piece is made only of the far part of a small gap (no reading behind it; see
:func:`polyhull.engine.pixels.small_gaps`)."""


def _same_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) whether each row of ``a`` (N, K) is a row of ``b`` (M, K) (equal values;
    ``b`` sorted once, each row of ``a`` found by binary search)."""
    out = np.zeros(len(a), dtype=bool)
    if len(a) == 0 or len(b) == 0:
        return out
    b = np.ascontiguousarray(b, dtype=np.float64)
    b = b[_lex_order(b)]
    _rows_in(np.ascontiguousarray(a, dtype=np.float64), b, out)
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _row_below(b, i, j):  # pragma: no cover - compiled
    """Row ``i`` of ``b`` before row ``j`` (lexicographic order, the first column first)."""
    for k in range(b.shape[1]):
        if b[i, k] != b[j, k]:
            return b[i, k] < b[j, k]
    return False


@nb.njit(cache=True, nogil=True)
def _lex_order(b):  # pragma: no cover - compiled
    """The rows of ``b`` (M, K) in lexicographic order (indices; a bottom-up merge sort,
    stable: ``np.lexsort`` of the columns, last key first, sorts 2,000 rows of 7 columns
    in seven passes, several times slower)."""
    n = b.shape[0]
    order = np.arange(n)
    tmp = np.empty(n, dtype=np.int64)
    width = 1
    while width < n:
        for lo in range(0, n, 2 * width):
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i, j, k = lo, mid, lo
            while i < mid and j < hi:
                if _row_below(b, order[j], order[i]):
                    tmp[k] = order[j]
                    j += 1
                else:
                    tmp[k] = order[i]
                    i += 1
                k += 1
            while i < mid:
                tmp[k] = order[i]
                i += 1
                k += 1
            while j < hi:
                tmp[k] = order[j]
                j += 1
                k += 1
        order, tmp = tmp, order
        width *= 2
    return order


@nb.njit(cache=True, nogil=True)
def _rows_in(a, b, out):  # pragma: no cover - compiled
    K = a.shape[1]
    for i in range(a.shape[0]):
        lo, hi = 0, b.shape[0]
        while lo < hi:  # the first row of b not below a[i] (lexicographic order)
            mid = (lo + hi) // 2
            below = False
            for k in range(K):
                if b[mid, k] != a[i, k]:
                    below = b[mid, k] < a[i, k]
                    break
            if below:
                lo = mid + 1
            else:
                hi = mid
        if lo < b.shape[0]:
            same = True
            for k in range(K):
                if b[lo, k] != a[i, k]:
                    same = False
                    break
            out[i] = same


class Refined(NamedTuple):
    """The region's dynamic part after refinement.

    Attributes:
        pieces: The kept pieces (after the shell rule on the finer pieces).
        cut: The pieces the shell rule removed on the finer pieces.
        sheets: (S, 8, 3) the sheet boxes under the kept pieces that stand on a surface.
        distance: The distance result of ``measure`` for the pieces and sheets.
        rounds: Carving rounds run.
        flags: (K,) the flags of :attr:`pieces` (a carved piece has its parent's).
        certain: The distance is the static region's or ``extra()``'s: refinement was left
            out (see the module docstring).
    """

    pieces: PieceSet
    cut: PieceSet
    sheets: ArrayF64
    distance: Any
    rounds: int
    flags: np.ndarray
    certain: bool = False


Recarve = Callable[[np.ndarray, int, float, float, float], PieceSet]
"""``recarve(boxes (M, 7), flags, offset, alpha, size_min)``: carve the boxes again (with
the memory's segments when ``flags`` hold ``MEMORY``, its front part's with ``FRONT``)
with that size budget, ``offset`` [m] subtracted
from each piece's distance to the robot."""


class RegionRules(NamedTuple):
    """What refinement needs of the dynamic rules (:mod:`polyhull.engine.dynamic_rules`)."""

    in_shells: Callable[[ArrayF64], np.ndarray]  # (N, 8, 3) -> (N,) inside a shell/sheet
    crossing: Callable[[ArrayF64], np.ndarray]  # (N, 8, 3) -> (N,) crosses a sheet's top
    sheets: Callable[[ArrayF64], ArrayF64]  # the sheet boxes under these pieces
    margin: float  # floor_shell_margin [m]
    too_thin: bool  # the shell rule is on


SURE_SLACK = 0.05
"""How far [m] beyond the last cycle's distance the static region and ``extra()`` are
sought before refining (they decide the distance again when the robot's motion has not
brought a piece nearer: a few centimetres a cycle on the bench walk); farther, the cycle
measures and refines as before. Only how often refinement is left out depends on it."""

TIE = 1e-12
"""Relative (and absolute, [m]) slack within which the static region or ``extra()`` counts
as attaining the region's distance (one FCL query measured twice gives the same value)."""


def _certain(measure: Callable[[ArrayF64, Any], Any], extra: Callable[[], ArrayF64], below: float) -> Any | None:
    """The distance result of the parts of the region that refinement never changes, the
    static region (which ``measure`` adds to every result) and the sheet boxes
    ``extra()``, when they come nearer than ``below`` [m]; None otherwise (then nothing of
    them is measured beyond what that bound asks: links farther than it are left out)."""
    if not below > 0.0:
        return None
    cap = DistanceResult(below, None, None)
    res = measure(extra(), cap)
    return None if res is cap or not res.distance < below else res


def refine_kept(
    kept: PieceSet,
    flags: np.ndarray,
    inside: np.ndarray,
    rules: RegionRules,
    spheres: ArrayF64,
    alpha: float,
    recarve: Recarve,
    measure: Callable[[ArrayF64, Any], Any],
    pool: Executor | None = None,
    front_hint: float | None = None,
    hint_spheres: ArrayF64 | None = None,
    extra: Callable[[], ArrayF64] | None = None,
    leave_out: bool = True,
    last_certain: bool = False,
) -> Refined:
    """Carve again the kept pieces (``kept`` with their ``flags`` and whether each is
    ``inside`` a shell) that can decide the distance to the robot (see the module
    docstring); ``alpha`` is the carve's size budget per metre of distance (a piece larger
    than that budget, counted from the frontier, is carved again); ``measure(vertices,
    best)`` gives the distance result (``.distance``) of the region with these dynamic
    hexahedra, or ``best`` (a result of another part) if that is nearer. ``pool``: the
    shell rule's box tests are shared with one of its threads. ``front_hint`` [m]: the
    frontier to refine from instead of measuring the unrefined region first, used when no
    piece's lower bound lies more than ``BAND`` below it (see the module docstring), the
    bound counted to ``hint_spheres`` (S', 4) when given: the balls of the links the
    distance is measured to (``spheres`` may hold more, e.g. a base fixed to the world,
    whose balls steer the carving but cannot decide the distance). ``extra()`` (E, 8, 3):
    sheet boxes of the region besides the pieces' (the sheet under the legs the robot
    hides), measured with every part and returned with the sheets; asked for only when
    the region is first measured (it may still be computed on another thread until then).
    ``leave_out``: refinement is left out where it cannot change the distance (see the
    module docstring); False refines as if the static region and ``extra()`` were farther
    (the monitor's warm-up, whose cycles must call every kernel a cycle may call).
    ``last_certain``: the last cycle's distance was the static region's or ``extra()``'s
    (:attr:`Refined.certain`); only then are they sought as far as ``SURE_SLACK`` beyond it
    (else only below the pieces' bounds: when the pieces decide, seeking farther costs
    static queries and a measurement for nothing)."""
    margin = rules.margin
    reach = REACH_EXTRA + margin  # farthest behind the frontier that is refined
    cross = rules.crossing(kept.vertices)
    cut = np.zeros(len(kept), dtype=bool)  # the rules ran on these pieces already

    def more() -> ArrayF64:
        return np.zeros((0, 8, 3)) if extra is None else extra()

    def own_sheets(part: np.ndarray) -> ArrayF64:
        # the sheets under the pieces of ``part`` that stand on a surface
        return rules.sheets(kept.vertices[part & ~cut & cross & ((flags & OWN) > 0)])

    def region(part: np.ndarray, best: Any) -> tuple[ArrayF64, Any]:
        sheets = np.concatenate([own_sheets(part), more()])
        return sheets, measure(np.concatenate([kept.vertices[part & ~cut], sheets]), best)

    all_ = np.ones(len(kept), dtype=bool)
    rounds = 0
    lower = distance_lower_bounds(kept.vertices, spheres)
    # the bounds to the links the distance is measured to
    measured_lower = lower if hint_spheres is None else distance_lower_bounds(kept.vertices, hint_spheres)
    result = None
    sure = None
    # the hinted frontier (the last cycle's, less its slack) when no piece can be much nearer
    hint = front_hint if front_hint is not None and len(kept) and len(spheres) and float(measured_lower.min()) >= front_hint - BAND else None
    if leave_out and len(kept) and len(spheres):
        # the static region within ``SURE_SLACK`` of the last cycle's distance (when it decided
        # the distance then), or nearer than any piece can be (``extra()`` is asked for only
        # when refinement is left out: it may still be computed on another thread, and asking
        # starts the next cycle's history there, beside the carving)
        last = -np.inf if front_hint is None or not last_certain else float(front_hint) + FRONT_SLACK + SURE_SLACK
        sure = _certain(measure, lambda: np.zeros((0, 8, 3)), max(float(measured_lower.min()), last))
    if sure is not None:
        # when nothing of the pieces and their sheets is nearer, the distance is theirs, and
        # refinement (which only removes space) cannot change it: it is left out; else the
        # pieces are refined from the same frontier as without the check (the hinted one,
        # or the distance just measured), so the same pieces are carved
        under = own_sheets(all_)
        bounds = distance_lower_bounds(under, spheres if hint_spheres is None else hint_spheres)
        d_sure = float(sure.distance)
        if d_sure > min(float(measured_lower.min()), float(bounds.min(initial=np.inf))):
            # only the pieces and sheets whose bounds are below it can be nearer
            result = measure(np.concatenate([kept.vertices[measured_lower < d_sure], under[bounds < d_sure]]), sure)
        if result is None or result is sure or not result.distance < d_sure:
            # nothing of the pieces nearer: the static region's distance, or ``extra()``'s
            sheets = np.concatenate([under, more()])
            return Refined(kept, kept.select(cut), sheets, measure(more(), sure), rounds, flags, True)
        if not result.distance > 0.0:  # contact
            return Refined(kept, kept.select(cut), np.concatenate([under, more()]), result, rounds, flags)
    if hint is not None:
        # the first measurement is skipped (or, made for the check, not used)
        front0, result = float(hint), None
    elif result is not None:
        # measured against the static region: the frontier (the region is measured again
        # at the end, with the sheets)
        front0, result = float(result.distance), None
    else:
        sheets, result = region(all_, None)
        # nothing to refine, or contact already (the cycle stops whatever the finer pieces
        # say), or the static region or ``extra()`` is the nearest part
        if len(kept) == 0 or len(spheres) == 0 or not (0.0 < float(result.distance) < np.inf):
            return Refined(kept, kept.select(cut), sheets, result, rounds, flags)
        if leave_out and _certain(measure, more, float(result.distance) * (1.0 + TIE) + TIE) is not None:
            return Refined(kept, kept.select(cut), sheets, result, rounds, flags, True)
        front0 = float(result.distance)
    # Only the pieces within ``reach`` (and a margin) of the first frontier take part in
    # the rounds; the rest keep their sheets and their distance (measured once).
    movable = lower < front0 + reach + BAND
    # the far part's distance is measured at the end, only if it can be the nearest
    far_sheets = own_sheets(~movable)
    far_lower = min(
        float(lower[~movable].min(initial=np.inf)),
        float(distance_lower_bounds(far_sheets, spheres).min(initial=np.inf)),
    )

    def final() -> tuple[ArrayF64, Any]:
        # the movable part measured, and the far part when it can be the nearest
        near_sheets, res = region(movable, None)
        if far_lower < float(res.distance):
            res = measure(np.concatenate([kept.vertices[~movable & ~cut], far_sheets]), res)
        return np.concatenate([far_sheets, near_sheets]), res

    front = front0
    d: ArrayF64 | None = lower  # the pieces' bounds (None once a round has changed the pieces)
    while rounds < ROUNDS:
        v = kept.vertices
        if d is None:
            d = distance_lower_bounds(v, spheres)
        vlo, vhi = vertex_bounds(v)
        size = (vhi - vlo).max(axis=1)
        live = movable & ~cut & ((flags & SETTLED) == 0)
        near = live & (size > 1.5 * np.maximum(FINE, alpha * (d - front))) & (d < front + BAND)
        sheet = live & cross & (size > 1.5 * FINE) & (d < front + reach)
        near &= ~sheet
        # the shadow memory's pieces that cross a sheet's top at the frontier: to FINE now
        fine = sheet & ((flags & MEMORY) > 0) & (d < front + BAND)
        many = np.nonzero(fine)[0]
        if len(many) > MEMORY_FINE:
            # the nearest only (a colour camera's memory holds thousands at the robot)
            fine[many[np.argsort(d[many], kind="stable")[MEMORY_FINE:]]] = False
        sheet &= ~fine
        if not (near.any() or sheet.any() or fine.any()):
            break
        rounds += 1
        sel = near | sheet | fine
        changed = sel & ~inside
        changed_lo, changed_hi = vlo[changed], vhi[changed]
        parts, out_flags = [kept.select(~sel)], [flags[~sel]]
        for group, a, to_fine in ((near, alpha, False), (sheet, 0.0, False), (fine, 0.0, True)):
            for f in np.unique(flags[group]):
                idx = group & (flags == f)  # one call per flag value: its children inherit it
                # a quarter of the largest size per round: the next round splits again
                # only what still decides the distance or crosses a sheet's top
                smin = FINE if to_fine else max(FINE, 0.25 * float(size[idx].max()))
                new = recarve(kept.boxes[idx], int(f), front, a, smin)
                parts.append(new)
                out_flags.append(np.where(_same_rows(new.boxes, kept.boxes[idx]), f | SETTLED, f).astype(flags.dtype))
        n_rest = int((~sel).sum())
        kept = PieceSet.concat(parts)
        d = None
        flags = np.concatenate(out_flags)
        children = kept.vertices[n_rest:]
        inside = np.concatenate([inside[~sel], rules.in_shells(children) if rules.too_thin else np.zeros(len(children), bool)])
        cross = np.concatenate([cross[~sel], rules.crossing(children)])
        cut = np.concatenate([cut[~sel], np.zeros(len(children), dtype=bool)])
        movable = np.concatenate([movable[~sel], np.ones(len(children), dtype=bool)])
        if rules.too_thin and inside.any():
            # the shell rule again where its keepers changed: a piece in a shell is kept
            # only within ``margin`` of a piece outside every shell (refinement only
            # removes such pieces, so a piece once cut stays cut)
            lo, hi = vertex_bounds(kept.vertices)
            test = inside & ~cut & ((flags & SPARED) == 0)
            old = np.nonzero(test[:n_rest])[0]  # only those that can be cut ask
            test[old] = any_near_upright(lo[old], hi[old], changed_lo, changed_hi, margin, pool)
            if test.any():
                keepers = ~inside
                cut[test] = ~any_near_upright(lo[test], hi[test], lo[keepers], hi[keepers], margin, pool)
        sheets, result = final()
        front = float(result.distance)
    if result is None:  # nothing to refine from the hinted frontier
        sheets, result = final()
    return Refined(kept.select(~cut), kept.select(cut), sheets, result, rounds, flags[~cut])
