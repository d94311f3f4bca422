"""Plausibility rules: the artifact filters that turn R2 into R3 (paper section 3.1).

``R3 = R2 \\ union_k A(k)`` where each ``A(k)`` is a connected component of R2 that fails a
plausibility rule (SPEC section 2). This is the only step of polyhull allowed to remove
possibly occupied space, so every rule here is written to err on one side only: when a test
is approximate, the approximation can only make the rule fire *less* often (keep more).

Components:
    The components are the pieces of ``R2.decompose()``, merged when they touch (gap up
    to ``TOUCH_TOLERANCE``): manifold3d splits solids that meet only along an edge or at a
    vertex into separate pieces, and block-shaped camera regions produce such contacts;
    pieces that touch can be parts of one person and are judged together.

The rules, in the order they are evaluated (``RULE_ORDER``; cheapest first). The set of
removed components does not depend on the order, only the rule each removal is reported
with does: the first rule that fires.

1. ``too_small``: the volume is below ``min_volume``.
2. ``flying``: no contact within ``support_eps`` with the floor (z = zone min z) or with a
   static object in the direction of gravity (``support``), nor with the robot occlusion M
   below it when the context carries M (a person whose legs are hidden in M stands on M).
3. ``too_thin``: the component lies entirely inside the shell of thickness
   ``shell_thickness`` around the known objects (obstacles, robot links): inside the
   objects grown by the shell, and not inside the objects themselves.
4. ``entry``: the component touches (within ``support_eps``) neither the boundary of Z, nor
   a declared entry area, nor the robot occlusion M (when given), nor comes within
   ``human_speed_max * dt + support_eps`` of a component of the previous cycle.
5. ``teleport``: the component is farther than ``human_speed_max * dt`` from every
   component of the previous cycle, and touches neither the boundary of Z, nor an entry
   area, nor M (when given): a person may always step in at the boundary or out of the
   robot's shadow. With an empty previous region (nobody was there), every component away
   from the boundary and the entry areas teleported.

Boundary of Z:
    The walls (x and y faces) and the ceiling; not the floor, which everything stands on.
    A component touching it within ``support_eps`` may be part of a person standing outside
    Z and reaching in, whose support and rest lie outside Z: with ``keep_at_boundary``
    (default True) the flying, too_small and too_thin rules never fire for it. entry and
    teleport always spare it.

History:
    entry and teleport need the previous cycle: they never fire when ``previous`` or ``dt``
    is None (the first cycle, or after a reset), so no component is removed for lack of
    history.

Conservative approximations (each can only make a rule fire less often):
    - flying: the contact test clips the supporting solid to the vertical prism over the
      component's footprint (grown by ``FOOTPRINT_MARGIN``), from ``support_eps`` below the
      component up to its top, and accepts any contact within ``support_eps`` with that
      part; every contact in the direction of gravity is such a contact.
    - too_thin: objects are grown by a polytope inscribed in the ball of radius
      ``shell_thickness``, so the grown set lies inside the exact one. Convex objects are
      grown exactly by that polytope (hull of vertex sums); non-convex ones by the union of
      their translates to the polytope's vertices, which lies inside their Minkowski sum.
      Pass convex pieces (collision primitives) as known objects for a tight shell.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import manifold3d as m3
import numpy as np

from .cell import PlausibilityParams, Zone
from .errors import GeometryError, PolyhullError
from .typed import ArrayBool, ArrayF64

__all__ = [
    "RULE_ORDER",
    "TOUCH_TOLERANCE",
    "FOOTPRINT_MARGIN",
    "VOLUME_TOLERANCE",
    "RemovedComponent",
    "PlausibilityContext",
    "PlausibilityResult",
    "apply_plausibility",
    "components",
    "is_too_small",
    "is_flying",
    "is_too_thin",
    "is_unconnected_to_entry",
    "is_teleport",
    "touches_boundary",
    "mesh_volume_centroid",
]

RULE_ORDER: tuple[str, ...] = ("too_small", "flying", "too_thin", "entry", "teleport")
"""The rules in the order they are evaluated; a component is reported with the first that fires."""

TOUCH_TOLERANCE = 1e-5
"""Gap [m] up to which two solids count as touching (float rounding of mesh coordinates)."""

FOOTPRINT_MARGIN = 1e-4
"""Outward growth [m] of a component's footprint in the flying contact test."""

VOLUME_TOLERANCE = 1e-9
"""Volume [m^3] (1 mm^3) below which a boolean remainder counts as empty (too_thin)."""

# Unit polytope vertices, all on the unit sphere, so the polytope lies inside the unit ball.
_GOLDEN = (1.0 + 5.0**0.5) / 2.0
_ICOSAHEDRON = np.array(
    [
        [-1, _GOLDEN, 0], [1, _GOLDEN, 0], [-1, -_GOLDEN, 0], [1, -_GOLDEN, 0],
        [0, -1, _GOLDEN], [0, 1, _GOLDEN], [0, -1, -_GOLDEN], [0, 1, -_GOLDEN],
        [_GOLDEN, 0, -1], [_GOLDEN, 0, 1], [-_GOLDEN, 0, -1], [-_GOLDEN, 0, 1],
    ],
    dtype=np.float64,
)  # (12, 3)
_ICOSAHEDRON /= np.linalg.norm(_ICOSAHEDRON, axis=1, keepdims=True)


def _icosphere_vertices() -> ArrayF64:
    """(42, 3) vertices of the once-subdivided icosahedron, on the unit sphere."""
    v = _ICOSAHEDRON
    d = np.linalg.norm(v[:, None, :] - v[None, :, :], axis=2)
    edge = d[d > 0].min()
    i, j = np.nonzero(np.triu(np.isclose(d, edge), k=1))  # the 30 edges
    mid = (v[i] + v[j]) / 2.0
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    return np.vstack([v, mid])


_ICOSPHERE = _icosphere_vertices()  # (42, 3)
_EMPTY_BOX = np.array([np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf])


# --------------------------------------------------------------------------- values


@dataclass(frozen=True, eq=False)
class RemovedComponent:
    """A component of R2 removed by a plausibility rule (reported in the verdict).

    Attributes:
        rule: The rule that removed it, one of ``RULE_ORDER``.
        volume: Its volume [m^3].
        centroid: (3,) its volume centroid in the world frame [m].
        mesh: The component, world frame.
    """

    rule: str
    volume: float
    centroid: ArrayF64
    mesh: m3.Manifold


@dataclass(frozen=True, eq=False)
class PlausibilityContext:
    """Everything the rules know besides the component itself.

    Attributes:
        zone: The work cell Z; the floor is z = ``zone.min[2]``.
        params: The rules' switches and parameters.
        support: What a person can stand on besides the floor: the union of the static
            obstacles (may be empty).
        known_objects: Obstacles and robot links at the current q; the too_thin shell is
            around these. Convex pieces give an exact shell.
        previous: The components of the previous cycle's region, or None on the first cycle
            or after a reset.
        dt: Time since the previous cycle [s], or None.
        occlusion: The robot occlusion M of this cycle, or None. A component touching it
            may continue inside it: it then counts as supported from below (flying) and as
            connected to an entry (entry, teleport).
    """

    zone: Zone
    params: PlausibilityParams
    support: m3.Manifold = field(default_factory=m3.Manifold)
    known_objects: tuple[m3.Manifold, ...] = ()
    previous: tuple[m3.Manifold, ...] | None = None
    dt: float | None = None
    occlusion: m3.Manifold | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "known_objects", tuple(self.known_objects))
        if self.previous is not None:
            object.__setattr__(self, "previous", tuple(self.previous))
        if self.dt is not None and not (np.isfinite(self.dt) and self.dt >= 0.0):
            raise PolyhullError(
                f"plausibility context: dt must be None or a finite time >= 0 s, got {self.dt!r}"
            )

    @property
    def has_history(self) -> bool:
        """True when the previous cycle is known (entry and teleport can fire)."""
        return self.previous is not None and self.dt is not None


@dataclass(frozen=True, eq=False)
class PlausibilityResult:
    """R3 and what was removed from R2 to get it.

    Attributes:
        region: R3 (R2 itself when nothing was removed).
        kept: The components of R3.
        removed: The removed components, each with its rule.
    """

    region: m3.Manifold
    kept: tuple[m3.Manifold, ...]
    removed: tuple[RemovedComponent, ...]

    @property
    def removed_volume(self) -> float:
        """Total volume removed from R2 [m^3]."""
        return float(sum(r.volume for r in self.removed))


# --------------------------------------------------------------------------- geometry helpers


def _bbox(m: m3.Manifold) -> ArrayF64:
    """(6,) bounding box (xmin, ymin, zmin, xmax, ymax, zmax) [m]; inf/-inf when empty."""
    if m.is_empty():
        return _EMPTY_BOX.copy()
    return np.asarray(m.bounding_box(), dtype=np.float64)


def _bbox_gap(a: ArrayF64, b: ArrayF64) -> float:
    """Euclidean distance [m] between two boxes (0 when they overlap); inf if one is empty."""
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return float("inf")
    d = np.maximum(0.0, np.maximum(a[:3] - b[3:], b[:3] - a[3:]))
    return float(np.linalg.norm(d))


def _vertices(m: m3.Manifold) -> ArrayF64:
    """(N, 3) vertex positions [m]."""
    mesh = m.to_mesh64()
    return np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]


def mesh_volume_centroid(m: m3.Manifold) -> tuple[float, ArrayF64]:
    """Volume [m^3] and (3,) volume centroid [m] of a closed mesh.

    Sums the signed tetrahedra from a reference point (the bounding-box centre, for
    accuracy) to every triangle, as trimesh does. An empty mesh gives 0 and NaNs.
    """
    if m.is_empty():
        return 0.0, np.full(3, np.nan)
    mesh = m.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    ref = verts.min(axis=0) / 2.0 + verts.max(axis=0) / 2.0
    a, b, c = (verts[tris[:, k]] - ref for k in range(3))
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))  # 6 x signed tetra volumes (M,)
    total6 = float(vol6.sum())
    if total6 <= 0.0:
        return 0.0, np.full(3, np.nan)
    centroid = (vol6[:, None] * (a + b + c)).sum(axis=0) / (4.0 * total6) + ref
    return total6 / 6.0, centroid


def _within(a: m3.Manifold, b: m3.Manifold, distance: float) -> bool:
    """True if the solids ``a`` and ``b`` are at most ``distance`` [m] apart (or overlap)."""
    if _bbox_gap(_bbox(a), _bbox(b)) > distance + TOUCH_TOLERANCE:
        return False
    # min_gap returns 0 for overlapping or nested solids and the search length when
    # nothing is closer than it.
    return bool(a.min_gap(b, distance + 2.0 * TOUCH_TOLERANCE) <= distance + TOUCH_TOLERANCE)


def _geometry_key(m: m3.Manifold, extra: float) -> bytes:
    """A digest of the exact geometry of ``m`` (and a parameter), for memoisation."""
    mesh = m.to_mesh64()
    h = hashlib.blake2b(digest_size=20)
    h.update(np.ascontiguousarray(mesh.vert_properties, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.tri_verts, dtype=np.int64).tobytes())
    h.update(np.float64(extra).tobytes())
    return h.digest()


class _Component:
    """A component with its cheap properties computed once (bbox, volume, vertices)."""

    __slots__ = ("manifold", "bbox", "volume", "_vertices")

    def __init__(self, manifold: m3.Manifold, volume: float | None = None) -> None:
        self.manifold = manifold
        self.bbox = _bbox(manifold)
        self.volume = float(manifold.volume()) if volume is None else volume
        self._vertices: ArrayF64 | None = None

    @property
    def vertices(self) -> ArrayF64:
        if self._vertices is None:
            self._vertices = _vertices(self.manifold)
        return self._vertices


def _as_component(c: m3.Manifold | _Component) -> _Component:
    return c if isinstance(c, _Component) else _Component(c)


# --------------------------------------------------------------------------- grown objects


@dataclass(frozen=True, eq=False)
class _Grown:
    """A known object grown by the shell thickness (inside its exact Minkowski sum).

    Attributes:
        solid: The grown object.
        bbox: (6,) its bounding box [m].
        planes: (F, 4) outward face planes ``n . x <= d`` as rows (n, d) when convex, else None.
    """

    solid: m3.Manifold
    bbox: ArrayF64
    planes: ArrayF64 | None

    def contains_points(self, points: ArrayF64) -> ArrayBool:
        """Which of the (N, 3) points may lie inside (exact when convex, by bbox otherwise)."""
        lo, hi = self.bbox[:3], self.bbox[3:]
        inside = np.all((points >= lo - 1e-9) & (points <= hi + 1e-9), axis=1)
        if self.planes is not None and inside.any():
            n, d = self.planes[:, :3], self.planes[:, 3]
            inside &= np.all(points @ n.T <= d + 1e-9, axis=1)
        return inside


class _GrownCache:
    """A small thread-safe LRU cache of grown objects, keyed by their exact geometry."""

    def __init__(self, size: int = 256) -> None:
        self._size = size
        self._items: OrderedDict[bytes, _Grown] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: bytes, build: Callable[[], _Grown]) -> _Grown:
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        grown = build()
        with self._lock:
            self._items[key] = grown
            while len(self._items) > self._size:
                self._items.popitem(last=False)
        return grown


_GROWN_CACHE = _GrownCache()


def _face_planes(m: m3.Manifold) -> ArrayF64:
    """(F, 4) planes (n, d) of the faces of a closed convex mesh, n . x <= d inside."""
    mesh = m.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1)
    keep = length > 1e-15
    n = n[keep] / length[keep, None]
    d = np.einsum("ij,ij->i", n, a[keep])
    return np.column_stack([n, d])


def _grow(obj: m3.Manifold, thickness: float) -> _Grown:
    """``obj`` grown by a polytope inscribed in the ball of radius ``thickness`` [m]."""
    volume = obj.volume()
    hull = obj.hull()
    convex = hull.volume() - volume <= VOLUME_TOLERANCE + 1e-7 * volume
    if convex:
        # Minkowski sum of two convex polytopes: the hull of the pairwise vertex sums.
        verts = _vertices(obj)
        sums = (verts[:, None, :] + thickness * _ICOSPHERE[None, :, :]).reshape(-1, 3)
        solid = m3.Manifold.hull_points(sums)
        planes: ArrayF64 | None = _face_planes(solid)
    else:
        # The union of translates to the polytope's vertices lies inside obj + ball.
        copies = [obj] + [obj.translate(tuple(thickness * v)) for v in _ICOSAHEDRON]
        solid = m3.Manifold.batch_boolean(copies, m3.OpType.Add)
        planes = None
    if solid.status() != m3.Error.NoError or solid.is_empty():
        raise GeometryError(
            f"plausibility too_thin: growing a known object by {thickness} m failed "
            f"(manifold3d status {solid.status().name})"
        )
    return _Grown(solid=solid, bbox=_bbox(solid), planes=planes)


def _grown(obj: m3.Manifold, thickness: float) -> _Grown:
    return _GROWN_CACHE.get(_geometry_key(obj, thickness), lambda: _grow(obj, thickness))


# --------------------------------------------------------------------------- contact tests


def touches_boundary(component: m3.Manifold | _Component, zone: Zone, eps: float) -> bool:
    """True if the component comes within ``eps`` [m] of a wall or the ceiling of Z.

    The floor does not count: everything stands on it. Exact, from the bounding box, whose
    extreme coordinates are attained by points of the component.
    """
    c = _as_component(component)
    if not np.all(np.isfinite(c.bbox)):
        return False
    lo, hi = c.bbox[:3], c.bbox[3:]
    zmin, zmax = np.asarray(zone.min), np.asarray(zone.max)
    tol = eps + TOUCH_TOLERANCE
    return bool(np.any(lo[:2] <= zmin[:2] + tol) or np.any(hi >= zmax - tol))


def _touches_entry_area(c: _Component, ctx: PlausibilityContext, eps: float) -> bool:
    for area in ctx.params.entry_areas:
        lo, hi = np.asarray(area.min), np.asarray(area.max)
        if _bbox_gap(c.bbox, np.concatenate([lo, hi])) > eps + TOUCH_TOLERANCE:
            continue
        grown_lo, grown_hi = lo - eps, hi + eps
        if np.any(np.all((c.vertices >= grown_lo) & (c.vertices <= grown_hi), axis=1)):
            return True
        box = m3.Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
        if _within(c.manifold, box, eps):
            return True
    return False


def _touches_occlusion(c: _Component, ctx: PlausibilityContext, eps: float) -> bool:
    return ctx.occlusion is not None and _within(c.manifold, ctx.occlusion, eps)


def _supported_by(c: _Component, solid: m3.Manifold | None, eps: float) -> bool:
    """True if ``solid`` may lie within ``eps`` [m] below the component (conservative).

    Clips ``solid`` to the prism over the component's footprint (grown by
    FOOTPRINT_MARGIN) from ``eps`` below its lowest point up to its top, and accepts any
    contact within ``eps`` with that part. A point of ``solid`` at most ``eps`` straight
    below a point of the component lies in that prism, so no real contact is missed.
    """
    if solid is None or solid.is_empty():
        return False
    margin = FOOTPRINT_MARGIN
    lo, hi = c.bbox[:3].copy(), c.bbox[3:].copy()
    lo[:2] -= margin
    hi[:2] += margin
    lo[2] -= eps + margin
    if _bbox_gap(np.concatenate([lo, hi]), _bbox(solid)) > 0.0:
        return False
    footprint = c.manifold.project().offset(margin, m3.JoinType.Miter)
    prism = m3.Manifold.extrude(footprint, float(hi[2] - lo[2])).translate((0.0, 0.0, float(lo[2])))
    below = solid ^ prism
    if below.is_empty():
        return False
    return _within(c.manifold, below, eps + margin)


def _near_previous(c: _Component, ctx: PlausibilityContext, reach: float) -> bool:
    assert ctx.previous is not None
    for prev in ctx.previous:
        if _within(c.manifold, prev, reach):
            return True
    return False


def _spared_as_entering(c: _Component, ctx: PlausibilityContext) -> bool:
    """True if the component may have just come in: at the boundary, an entry area, or M."""
    eps = ctx.params.support_eps
    return (
        touches_boundary(c, ctx.zone, eps)
        or _touches_entry_area(c, ctx, eps)
        or _touches_occlusion(c, ctx, eps)
    )


def _keep_at_boundary(ctx: PlausibilityContext) -> bool:
    return bool(getattr(ctx.params, "keep_at_boundary", True))


# --------------------------------------------------------------------------- the rules


def is_too_small(component: m3.Manifold | _Component, ctx: PlausibilityContext) -> bool:
    """Rule too_small: volume under ``params.min_volume`` [m^3].

    Spared at the boundary of Z with ``keep_at_boundary`` (a hand reaching in appears alone).
    Evaluates the rule whatever its switch; :func:`apply_plausibility` honours the switch.
    """
    c = _as_component(component)
    if c.volume >= ctx.params.min_volume:
        return False
    return not (_keep_at_boundary(ctx) and touches_boundary(c, ctx.zone, ctx.params.support_eps))


def is_flying(component: m3.Manifold | _Component, ctx: PlausibilityContext) -> bool:
    """Rule flying: nothing to stand on within ``params.support_eps`` below the component.

    Not flying when its lowest point is within eps of the floor, when ``ctx.support`` (or
    ``ctx.occlusion``) lies within eps below it, or, with ``keep_at_boundary``, when it
    touches the boundary of Z (its support may be outside Z).
    """
    c = _as_component(component)
    eps = ctx.params.support_eps
    if not np.all(np.isfinite(c.bbox)):
        return False
    if c.bbox[2] <= ctx.zone.floor_z + eps + TOUCH_TOLERANCE:
        return False
    if _keep_at_boundary(ctx) and touches_boundary(c, ctx.zone, eps):
        return False
    if _supported_by(c, ctx.support, eps):
        return False
    return not _supported_by(c, ctx.occlusion, eps)


def is_too_thin(component: m3.Manifold | _Component, ctx: PlausibilityContext) -> bool:
    """Rule too_thin: the component lies inside the shell around the known objects.

    The shell is the known objects grown by ``params.shell_thickness`` (by an inscribed
    polytope, never more), minus the objects themselves. Spared at the boundary of Z with
    ``keep_at_boundary``.
    """
    c = _as_component(component)
    s = ctx.params.shell_thickness
    if s <= 0.0 or not ctx.known_objects or not np.all(np.isfinite(c.bbox)):
        return False
    if _keep_at_boundary(ctx) and touches_boundary(c, ctx.zone, ctx.params.support_eps):
        return False
    relevant = [k for k in ctx.known_objects if _bbox_gap(c.bbox, _bbox(k)) <= s]
    if not relevant:
        return False
    # Cheap exact rejection: a vertex outside every grown bounding box is outside the shell.
    boxes = np.array([_bbox(k) for k in relevant])  # (K, 6)
    lo, hi = boxes[:, None, :3] - s, boxes[:, None, 3:] + s
    v = c.vertices[None, :, :]
    in_any_box = np.any(np.all((v >= lo) & (v <= hi), axis=2), axis=0)  # (N,)
    if not in_any_box.all():
        return False
    grown = [_grown(k, s) for k in relevant]
    in_any = np.zeros(len(c.vertices), dtype=bool)
    for g in grown:
        in_any |= g.contains_points(c.vertices)
    if not in_any.all():
        return False
    shell_out = c.manifold - m3.Manifold.batch_boolean([g.solid for g in grown], m3.OpType.Add)
    if shell_out.volume() > VOLUME_TOLERANCE:
        return False
    # Inside the grown objects; it must not reach into the objects themselves (non-solid
    # obstacles are not subtracted from R2, and a person may be inside them).
    inside_objects = c.manifold ^ m3.Manifold.batch_boolean(relevant, m3.OpType.Add)
    return inside_objects.volume() <= VOLUME_TOLERANCE


def is_unconnected_to_entry(component: m3.Manifold | _Component, ctx: PlausibilityContext) -> bool:
    """Rule entry: not connected to where a person can come from.

    Fires when the previous cycle is known and the component touches (within
    ``support_eps``) neither the boundary of Z, nor an entry area, nor M (when given), and
    is farther than ``human_speed_max * dt + support_eps`` from every previous component.
    Never fires without history (``previous`` or ``dt`` None).
    """
    c = _as_component(component)
    if not ctx.has_history or not np.all(np.isfinite(c.bbox)):
        return False
    if _spared_as_entering(c, ctx):
        return False
    assert ctx.dt is not None
    reach = ctx.params.human_speed_max * ctx.dt + ctx.params.support_eps
    return not _near_previous(c, ctx, reach)


def is_teleport(component: m3.Manifold | _Component, ctx: PlausibilityContext) -> bool:
    """Rule teleport: farther than ``human_speed_max * dt`` from every previous component.

    Never fires without history (``previous`` or ``dt`` None), nor for a component touching
    the boundary of Z, an entry area or M (when given) within ``support_eps``: a person may
    always step in there. With an empty previous region it fires for every other component.
    """
    c = _as_component(component)
    if not ctx.has_history or not np.all(np.isfinite(c.bbox)):
        return False
    if _spared_as_entering(c, ctx):
        return False
    assert ctx.dt is not None
    return not _near_previous(c, ctx, ctx.params.human_speed_max * ctx.dt)


_RULES: dict[str, Callable[[_Component, PlausibilityContext], bool]] = {
    "too_small": is_too_small,
    "flying": is_flying,
    "too_thin": is_too_thin,
    "entry": is_unconnected_to_entry,
    "teleport": is_teleport,
}


# --------------------------------------------------------------------------- components


def _components(region: m3.Manifold) -> list[_Component]:
    """The pieces of ``region`` merged when they touch (see the module docstring)."""
    pieces = [_Component(p) for p in region.decompose()]
    pieces = [p for p in pieces if not p.manifold.is_empty()]
    n = len(pieces)
    if n <= 1:
        return pieces
    boxes = np.array([p.bbox for p in pieces])  # (n, 6)
    tol = TOUCH_TOLERANCE
    overlap = np.all(
        (boxes[:, None, :3] <= boxes[None, :, 3:] + tol)
        & (boxes[None, :, :3] <= boxes[:, None, 3:] + tol),
        axis=2,
    )
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(overlap, k=1)), strict=True):
        ri, rj = find(int(i)), find(int(j))
        if ri != rj and pieces[i].manifold.min_gap(pieces[j].manifold, tol) < tol:
            parent[rj] = ri
    groups: dict[int, list[_Component]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(pieces[i])
    merged = []
    for group in groups.values():
        if len(group) == 1:
            merged.append(group[0])
        else:
            solid = m3.Manifold.batch_boolean([g.manifold for g in group], m3.OpType.Add)
            merged.append(_Component(solid, volume=sum(g.volume for g in group)))
    return merged


def components(region: m3.Manifold) -> tuple[m3.Manifold, ...]:
    """The connected components of a region as the rules see them.

    The pieces of ``region.decompose()``, merged when they touch (gap up to
    TOUCH_TOLERANCE), since manifold3d separates solids meeting only at an edge or vertex.
    """
    return tuple(c.manifold for c in _components(region))


def apply_plausibility(r2: m3.Manifold, ctx: PlausibilityContext) -> PlausibilityResult:
    """Remove the implausible components of R2: R3 = R2 minus every component failing a rule.

    Each enabled rule (``ctx.params.<rule>``) is evaluated in ``RULE_ORDER``; a component is
    removed by the first rule that fires and reported with it.

    Args:
        r2: The region R2 (world frame).
        ctx: Zone, parameters, support, known objects and the previous cycle.

    Returns:
        R3, its components, and the removed components with rule, volume and centroid.

    Raises:
        GeometryError: If R2 or a boolean result is not a valid manifold.
    """
    if r2.status() != m3.Error.NoError:
        raise GeometryError(f"plausibility: R2 is not a valid manifold (status {r2.status().name})")
    if r2.is_empty():
        return PlausibilityResult(region=r2, kept=(), removed=())
    enabled = [(name, _RULES[name]) for name in RULE_ORDER if getattr(ctx.params, name)]
    kept: list[m3.Manifold] = []
    removed: list[RemovedComponent] = []
    for comp in _components(r2):
        rule = next((name for name, fires in enabled if fires(comp, ctx)), None)
        if rule is None:
            kept.append(comp.manifold)
            continue
        _, centroid = mesh_volume_centroid(comp.manifold)
        removed.append(
            RemovedComponent(rule=rule, volume=comp.volume, centroid=centroid, mesh=comp.manifold)
        )
    if not removed:
        region = r2
    elif kept:
        region = m3.Manifold.batch_boolean(kept, m3.OpType.Add)
    else:
        region = m3.Manifold()
    if region.status() != m3.Error.NoError:
        raise GeometryError(f"plausibility: R3 union failed (status {region.status().name})")
    return PlausibilityResult(region=region, kept=tuple(kept), removed=tuple(removed))

