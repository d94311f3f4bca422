"""Plausibility rules: the artifact filters that turn R2 into R3 (paper section 3.1).

``R3 = R2 \\ union_k A(k)`` where each ``A(k)`` is a connected component of R2 that fails a
plausibility rule (listed below). This is the only step of polyhull allowed to remove
possibly occupied space, so every rule here is written to err on one side only: when a test
is approximate, the approximation can only make the rule fire *less* often (keep more).

Components:
    ``R2.decompose()`` returns every boundary shell on its own. A shell of negative volume
    is a cavity (the robot or an obstacle enclosed by R2) and belongs to the smallest outer
    shell around it; a component is an outer shell with its cavities, and its volume is the
    net volume. The rules see a component as the solid inside its outer shell, which can
    only make them fire less often. Components that touch (gap up to
    ``TOUCH_TOLERANCE``; manifold3d splits solids meeting only along an edge or at a vertex)
    can be parts of one person and are judged together: every rule is monotone (what it
    spares, it spares in any superset), so a component kept on its own keeps everything
    touching it, and a group of touching components that would all be removed is judged
    again as one. Shells whose volume is within ``VOLUME_TOLERANCE`` of zero are flat
    slivers left by boolean operations; they hold no space and never connect components.

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

import atexit
import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
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


class RemovedComponent:
    """A component removed by a plausibility rule (reported in the verdict).

    Attributes:
        rule: The rule that removed it, one of ``RULE_ORDER``, ``"sheet"`` (the noise
            sheet in front of a known surface, judged at precompute) or ``"small_gaps"``
            (pixel clusters too narrow to hide a detectable object, judged in image space).
        volume: Its volume [m^3].
        centroid: (3,) its volume centroid in the world frame [m].
        mesh: The component, world frame (built when first read for dynamic components).
    """

    __slots__ = ("rule", "volume", "centroid", "_mesh")

    def __init__(self, rule: str, volume: float, centroid: ArrayF64, mesh: object) -> None:
        self.rule = rule
        self.volume = float(volume)
        self.centroid = np.asarray(centroid, dtype=np.float64)
        self._mesh = mesh

    @property
    def mesh(self) -> m3.Manifold:
        """The removed component as a manifold (world frame)."""
        if isinstance(self._mesh, m3.Manifold):
            return self._mesh
        self._mesh = self._mesh.get()  # type: ignore[attr-defined]
        return self._mesh

    def drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """The component as triangles to draw fast: (V, 3) vertices [m] and (F, 3) vertex
        indices. A dynamic component made of pieces gives its pieces' hexahedra as they
        are (interiors may overlap; the union as :attr:`mesh` takes seconds for thousands
        of pieces, these triangles milliseconds); otherwise :attr:`mesh`'s triangles."""
        drawing = getattr(self._mesh, "drawing", None)
        if callable(drawing):
            return drawing()  # type: ignore[no-any-return]
        mesh = self.mesh.to_mesh64()
        props = np.asarray(mesh.vert_properties, dtype=np.float64)
        vertices = props.reshape(len(props), -1)[:, :3] if props.size else np.zeros((0, 3))
        return vertices, np.asarray(mesh.tri_verts, dtype=np.int64).reshape(-1, 3)

    def __repr__(self) -> str:
        return f"RemovedComponent(rule={self.rule!r}, volume={self.volume:.6g})"


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
    # Solids of the context wrapped once with their cached mesh arrays (see _solid).
    _solids: dict[tuple[str, int], _Component] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

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
        kept: The kept components of R2, each as the solid inside its outer shell
            (cavities filled; components touching at an edge or a vertex listed apart).
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


def _volume_moment(m: m3.Manifold) -> tuple[float, ArrayF64]:
    """Signed volume [m^3] and (3,) first moment of volume [m^4] of a closed shell.

    Sums the signed tetrahedra from a reference point (the bounding-box centre, for
    accuracy) to every triangle, as trimesh does; a cavity shell has a negative volume.
    """
    if m.is_empty():
        return 0.0, np.zeros(3)
    mesh = m.to_mesh64()
    verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    tris = np.asarray(mesh.tri_verts, dtype=np.int64)
    ref = verts.min(axis=0) / 2.0 + verts.max(axis=0) / 2.0
    a, b, c = (verts[tris[:, k]] - ref for k in range(3))
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))  # 6 x signed tetra volumes (M,)
    volume = float(vol6.sum()) / 6.0
    moment = (vol6[:, None] * (a + b + c)).sum(axis=0) / 24.0 + volume * ref
    return volume, moment


def mesh_volume_centroid(m: m3.Manifold) -> tuple[float, ArrayF64]:
    """Volume [m^3] and (3,) volume centroid [m] of a closed mesh (NaNs without volume)."""
    volume, moment = _volume_moment(m)
    if not volume > 0.0:
        return max(volume, 0.0), np.full(3, np.nan)
    return volume, moment / volume


def _geometry_key(m: m3.Manifold, extra: float) -> bytes:
    """A digest of the exact geometry of ``m`` (and a parameter), for memoisation."""
    mesh = m.to_mesh64()
    h = hashlib.blake2b(digest_size=20)
    h.update(np.ascontiguousarray(mesh.vert_properties, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.tri_verts, dtype=np.int64).tobytes())
    h.update(np.float64(extra).tobytes())
    return h.digest()


class _Component:
    """A component with its cheap properties computed once (bbox, volume, mesh arrays).

    A component with cavities is its outer shell (as a filled solid, which every rule
    treats leniently: contact and continuity can only be found more often, the shell test
    fires less often) plus the cavity shells, which count in its net volume.
    """

    __slots__ = (
        "manifold",
        "shells",
        "bbox",
        "volume",
        "_vertices",
        "_triangles",
        "_triangle_boxes",
        "_hull_planes",
    )

    def __init__(
        self,
        manifold: m3.Manifold,
        volume: float | None = None,
        shells: tuple[m3.Manifold, ...] | None = None,
    ) -> None:
        # ``manifold`` is the solid bounded by the outer shell(s); ``shells`` are every
        # boundary shell, cavities included, and ``volume`` is the net volume.
        self.manifold = manifold
        self.shells = (manifold,) if shells is None else shells
        self.bbox = _bbox(manifold)
        self.volume = float(manifold.volume()) if volume is None else volume
        self._vertices: ArrayF64 | None = None
        self._triangles: ArrayF64 | None = None
        self._triangle_boxes: ArrayF64 | None = None
        self._hull_planes: ArrayF64 | None = None

    def _load_mesh(self) -> None:
        mesh = self.manifold.to_mesh64()
        verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        tris = np.asarray(mesh.tri_verts, dtype=np.int64)
        corners = verts[tris]  # (M, 3, 3)
        self._vertices = verts
        self._triangles = corners
        self._triangle_boxes = np.asfortranarray(np.hstack([corners.min(axis=1), corners.max(axis=1)]))

    @property
    def vertices(self) -> ArrayF64:
        """(N, 3) vertex positions [m]."""
        if self._vertices is None:
            self._load_mesh()
        assert self._vertices is not None
        return self._vertices

    @property
    def triangles(self) -> ArrayF64:
        """(M, 3, 3) corners of every triangle [m]."""
        if self._triangles is None:
            self._load_mesh()
        assert self._triangles is not None
        return self._triangles

    def winding(self, points: ArrayF64) -> ArrayF64:
        """(N,) generalised winding numbers of the outer solid at the (N, 3) points."""
        tri = self.triangles
        out = np.zeros(len(points))
        for i, p in enumerate(points):
            a, b, c = tri[:, 0] - p, tri[:, 1] - p, tri[:, 2] - p
            la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
            det = _dot(a, np.cross(b, c))
            den = la * lb * lc + _dot(a, b) * lc + _dot(a, c) * lb + _dot(b, c) * la
            out[i] = np.arctan2(det, den).sum() / (2.0 * np.pi)
        return out

    @property
    def hull_planes(self) -> ArrayF64:
        """(F, 4) face planes (n, d) of the convex hull, n . x <= d inside."""
        if self._hull_planes is None:
            self._hull_planes = _face_planes(self.manifold.hull())
        return self._hull_planes

    @property
    def triangle_boxes(self) -> ArrayF64:
        """(M, 6) bounding box of every triangle [m]."""
        if self._triangle_boxes is None:
            self._load_mesh()
        assert self._triangle_boxes is not None
        return self._triangle_boxes


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

    def clear(self) -> None:
        """Drop every cached object."""
        with self._lock:
            self._items.clear()


_GROWN_CACHE = _GrownCache()
# Free the cached manifolds before interpreter shutdown, not after it (nanobind reports
# objects still alive at shutdown as leaks on stderr).
atexit.register(_GROWN_CACHE.clear)


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


def _solid(ctx: PlausibilityContext, kind: str, index: int, manifold: m3.Manifold) -> _Component:
    """``manifold`` (a solid of the context) wrapped once per context."""
    key = (kind, index)
    solid = ctx._solids.get(key)
    if solid is None:
        solid = ctx._solids[key] = _Component(manifold)
    return solid


def _touches_entry_area(c: _Component, ctx: PlausibilityContext, eps: float) -> bool:
    for k, area in enumerate(ctx.params.entry_areas):
        lo, hi = np.asarray(area.min), np.asarray(area.max)
        if _bbox_gap(c.bbox, np.concatenate([lo, hi])) > eps + TOUCH_TOLERANCE:
            continue
        grown_lo, grown_hi = lo - eps, hi + eps
        if np.any(np.all((c.vertices >= grown_lo) & (c.vertices <= grown_hi), axis=1)):
            return True
        box = m3.Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
        if _within(c, _solid(ctx, "entry", k, box), eps):
            return True
    return False


def _touches_occlusion(c: _Component, ctx: PlausibilityContext, eps: float) -> bool:
    if ctx.occlusion is None or ctx.occlusion.is_empty():
        return False
    return _within(c, _solid(ctx, "occlusion", 0, ctx.occlusion), eps)


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
    return _within(c, _Component(below), eps + margin)


def _near_previous(c: _Component, ctx: PlausibilityContext, reach: float) -> bool:
    assert ctx.previous is not None
    return any(
        _within(c, _solid(ctx, "previous", k, prev), reach)
        for k, prev in enumerate(ctx.previous)
        if not prev.is_empty()
    )


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

def _within(a: _Component, b: _Component, distance: float, *, nested: bool = True) -> bool:
    """True if the solids ``a`` and ``b`` come within ``distance`` [m] of each other.

    Exact up to rounding: the least distance between a triangle of ``a`` and one of ``b``,
    over the pairs that the triangles' boxes and the two convex hulls do not separate. With
    ``nested``, a solid lying inside the other (surfaces apart) counts as within any
    distance; pieces of one region are disjoint and need not check that.
    """
    if _bbox_gap(a.bbox, b.bbox) > distance + TOUCH_TOLERANCE:
        return False
    reach = distance + TOUCH_TOLERANCE
    # Keep the triangles of each solid that come near the other's box and hull.
    near_a = _boxes_meet(a.triangle_boxes, b.bbox[:3] - reach, b.bbox[3:] + reach)
    near_b = _boxes_meet(b.triangle_boxes, a.bbox[:3] - reach, a.bbox[3:] + reach)
    if near_a.any():
        near_a[near_a] = ~_separated_by_planes(a.triangles[near_a], b.hull_planes, reach)
    if near_b.any():
        near_b[near_b] = ~_separated_by_planes(b.triangles[near_b], a.hull_planes, reach)
    if near_a.any() and near_b.any():
        ta, tb = a.triangles[near_a], b.triangles[near_b]
        ba, bb = a.triangle_boxes[near_a], b.triangle_boxes[near_b]
        if len(ta) * len(tb) > _MAX_TRIANGLE_PAIRS:
            gap = a.manifold.min_gap(b.manifold, reach + TOUCH_TOLERANCE)
            return bool(gap <= reach)
        chunk = max(1, _PAIR_CHUNK // len(tb))
        for start in range(0, len(ta), chunk):
            ca, cb = ta[start : start + chunk], ba[start : start + chunk]
            ia, ib = np.nonzero(
                np.all(cb[:, None, :3] <= bb[None, :, 3:] + reach, axis=2)
                & np.all(bb[None, :, :3] <= cb[:, None, 3:] + reach, axis=2)
            )
            if len(ia) == 0:
                continue
            t1, t2 = ca[ia], tb[ib]
            # Pairs separated by the plane of either triangle are farther apart than reach.
            keep = ~(_beyond_plane(t1, t2, reach) | _beyond_plane(t2, t1, reach))
            if keep.any() and _triangle_distances(t1[keep], t2[keep]).min() <= reach:
                return True
    if not nested:
        return False
    return _inside(a, b) or _inside(b, a)


def _inside(inner: _Component, outer: _Component) -> bool:
    """True if a vertex of ``inner`` lies inside the solid ``outer`` (winding number)."""
    lo, hi = inner.bbox[:3], inner.bbox[3:]
    if np.any(outer.bbox[:3] > lo) or np.any(outer.bbox[3:] < hi):
        return False
    return bool(outer.winding(inner.vertices[:1])[0] > 0.5)


def _touch(a: _Component, b: _Component) -> bool:
    """True if two disjoint pieces of one region touch (gap up to TOUCH_TOLERANCE)."""
    return _within(a, b, 0.0, nested=False)


def _separated_by_planes(triangles: ArrayF64, planes: ArrayF64, gap: float) -> ArrayBool:
    """Which (M, 3, 3) triangles lie wholly more than ``gap`` [m] outside one of the planes.

    Args:
        triangles: (M, 3, 3) corners [m].
        planes: (F, 4) planes (n, d) with unit n, n . x <= d inside.
        gap: Margin [m].
    """
    if len(planes) == 0 or len(triangles) == 0:
        return np.zeros(len(triangles), dtype=bool)
    side = triangles @ planes[:, :3].T - planes[:, 3]  # (M, 3, F)
    return np.any(side.min(axis=1) > gap, axis=1)


def _beyond_plane(t1: ArrayF64, t2: ArrayF64, gap: float) -> ArrayBool:
    """Which (P, 3, 3) triangles t2 lie wholly more than ``gap`` [m] to one side of t1's plane."""
    n = np.cross(t1[:, 1] - t1[:, 0], t1[:, 2] - t1[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-300
    n = n / np.where(ok, length, 1.0)[:, None]
    side = np.einsum("pkj,pj->pk", t2 - t1[:, :1], n)  # (P, 3) signed distances
    return ok & ((side.min(axis=1) > gap) | (side.max(axis=1) < -gap))


# Above this many candidate triangle pairs, _within asks manifold3d's min_gap instead.
_MAX_TRIANGLE_PAIRS = 50_000_000
# Triangle pairs whose boxes are compared at once.
_PAIR_CHUNK = 200_000


def _boxes_meet(boxes: ArrayF64, lo: ArrayF64, hi: ArrayF64) -> ArrayBool:
    """Which (M, 6) boxes meet the box [lo, hi]."""
    meet = boxes[:, 0] <= hi[0]
    for k in range(1, 3):
        meet &= boxes[:, k] <= hi[k]
    for k in range(3):
        meet &= boxes[:, 3 + k] >= lo[k]
    return meet


def _dot(u: ArrayF64, v: ArrayF64) -> ArrayF64:
    return np.einsum("ij,ij->i", u, v)


def _point_triangle_distances(p: ArrayF64, a: ArrayF64, b: ArrayF64, c: ArrayF64) -> ArrayF64:
    """(P,) distances from the points p to the triangles (a, b, c), all (P, 3) [m].

    Closest point by Voronoi regions (Ericson, Real-Time Collision Detection, 5.1.5).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_face, w_face = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        # Degenerate triangles give inf or NaN here; they are caught below.
        closest = a + v_face[:, None] * ab + w_face[:, None] * ac  # interior of the face
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + t_bc[:, None] * (c - b)),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[:, None] * ac),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[:, None] * ab),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d1 <= 0) & (d2 <= 0), a),
        ]
    for mask, point in regions:  # the first matching region wins: apply in reverse
        closest = np.where(mask[:, None], point, closest)
    with np.errstate(invalid="ignore"):
        dist = np.linalg.norm(p - closest, axis=1)
    # A degenerate triangle can leave NaN: fall back to the distance to its corners.
    corners = np.minimum.reduce([np.linalg.norm(p - q, axis=1) for q in (a, b, c)])
    return np.where(np.isfinite(dist), np.minimum(dist, corners), corners)


def _segment_distances(p1: ArrayF64, q1: ArrayF64, p2: ArrayF64, q2: ArrayF64) -> ArrayF64:
    """(P,) distances between the segments p1q1 and p2q2, all (P, 3) [m] (Ericson 5.1.9).

    Degenerate segments give inf: their points are covered by the point-triangle distances.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-300, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        low, high = t < 0.0, t > 1.0
        s = np.where(low, np.clip(-c / a, 0.0, 1.0), np.where(high, np.clip((b - c) / a, 0.0, 1.0), s))
        t = np.clip(t, 0.0, 1.0)
    dist = np.linalg.norm(p1 + s[:, None] * d1 - p2 - t[:, None] * d2, axis=1)
    return np.where((a > 1e-300) & (e > 1e-300) & np.isfinite(dist), dist, np.inf)


def _triangle_distances(t1: ArrayF64, t2: ArrayF64) -> ArrayF64:
    """(P,) distances between the (P, 3, 3) triangles t1 and t2 that do not cross [m].

    The least of the six corner-to-triangle and nine edge-to-edge distances: exact for
    triangles that touch or are apart (the surfaces of disjoint solids do not cross).
    """
    out = np.full(len(t1), np.inf)
    for k in range(3):
        out = np.minimum(out, _point_triangle_distances(t1[:, k], t2[:, 0], t2[:, 1], t2[:, 2]))
        out = np.minimum(out, _point_triangle_distances(t2[:, k], t1[:, 0], t1[:, 1], t1[:, 2]))
    for i in range(3):
        for j in range(3):
            out = np.minimum(
                out,
                _segment_distances(t1[:, i], t1[:, (i + 1) % 3], t2[:, j], t2[:, (j + 1) % 3]),
            )
    return out


def _touch_groups(pieces: Sequence[_Component], sources: Sequence[int]) -> list[list[int]]:
    """Groups of pieces connected by touching, for the groups that contain a source index.

    Only pairs with a source are tested, so a group is complete when every piece that could
    join it from outside is a source or touches one.
    """
    n = len(pieces)
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if n > 1 and sources:
        boxes = np.array([p.bbox for p in pieces])  # (n, 6)
        tol = TOUCH_TOLERANCE
        for i in sources:
            near = np.all(boxes[:, :3] <= boxes[i, 3:] + tol, axis=1) & np.all(
                boxes[:, 3:] >= boxes[i, :3] - tol, axis=1
            )
            near[i] = False
            for j in np.flatnonzero(near):
                ri, rj = find(i), find(int(j))
                if ri != rj and _touch(pieces[i], pieces[int(j)]):
                    parent[rj] = ri
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    wanted = {find(i) for i in sources}
    return [g for root, g in groups.items() if root in wanted]


def _merge(pieces: Sequence[_Component]) -> _Component:
    if len(pieces) == 1:
        return pieces[0]
    solid = m3.Manifold.batch_boolean([p.manifold for p in pieces], m3.OpType.Add)
    shells = tuple(shell for p in pieces for shell in p.shells)
    return _Component(solid, volume=float(sum(p.volume for p in pieces)), shells=shells)


def _pieces(region: m3.Manifold) -> tuple[list[_Component], list[_Component]]:
    """The components of ``region`` (outer shells with their cavities) and its flat pieces.

    ``decompose`` returns every boundary shell on its own; a shell of negative volume is a
    cavity and joins the smallest outer shell that encloses it. Shells whose volume is
    within VOLUME_TOLERANCE of zero are flat slivers and returned apart.
    """
    shells = [c for c in (_Component(p) for p in region.decompose()) if not c.manifold.is_empty()]
    flat = [c for c in shells if abs(c.volume) <= VOLUME_TOLERANCE]
    outer = [c for c in shells if c.volume > VOLUME_TOLERANCE]
    cavities: dict[int, list[_Component]] = {}
    for hole in (c for c in shells if c.volume < -VOLUME_TOLERANCE):
        lo, hi = hole.bbox[:3], hole.bbox[3:]
        around = [
            i
            for i, c in enumerate(outer)
            if np.all(c.bbox[:3] <= lo + TOUCH_TOLERANCE) and np.all(c.bbox[3:] >= hi - TOUCH_TOLERANCE)
        ]
        if len(around) > 1:
            point = hole.vertices[:1]
            around = [i for i in around if outer[i].winding(point)[0] > 0.5] or around
        if around:
            owner = min(around, key=lambda i: outer[i].volume)
            cavities.setdefault(owner, []).append(hole)
    components = []
    for i, c in enumerate(outer):
        holes = cavities.get(i, [])
        if holes:
            net = c.volume + sum(h.volume for h in holes)
            c = _Component(c.manifold, volume=net, shells=(c.manifold, *(h.manifold for h in holes)))
        components.append(c)
    return components, flat


def components(region: m3.Manifold) -> tuple[m3.Manifold, ...]:
    """The connected components of a region as the rules see them, as filled solids.

    The outer shells of ``region.decompose()`` (cavities belong to the shell around them),
    merged when they touch (gap up to TOUCH_TOLERANCE), since manifold3d separates solids
    meeting only at an edge or vertex. Flat pieces without volume are left out.
    """
    pieces, _ = _pieces(region)
    groups = _touch_groups(pieces, list(range(len(pieces))))
    return tuple(_merge([pieces[i] for i in g]).manifold for g in groups)


def _report(rule: str, parts: Sequence[_Component]) -> RemovedComponent:
    comp = _merge(parts)
    volume, moment = 0.0, np.zeros(3)
    for shell in comp.shells:
        v, m = _volume_moment(shell)
        volume, moment = volume + v, moment + m
    if volume > VOLUME_TOLERANCE:
        centroid = moment / volume
    else:
        # No volume to weight by (flat pieces): the centre of their bounding box.
        centroid = comp.bbox[:3] / 2.0 + comp.bbox[3:] / 2.0
    return RemovedComponent(rule=rule, volume=comp.volume, centroid=centroid, mesh=comp.manifold)


def _first_rule(
    comp: _Component,
    rules: Sequence[tuple[str, Callable[[_Component, PlausibilityContext], bool]]],
    ctx: PlausibilityContext,
) -> str | None:
    return next((name for name, fires in rules if fires(comp, ctx)), None)


def apply_plausibility(r2: m3.Manifold, ctx: PlausibilityContext) -> PlausibilityResult:
    """Remove the implausible components of R2: R3 = R2 minus every component failing a rule.

    Each enabled rule (``ctx.params.<rule>``) is evaluated in ``RULE_ORDER``; a component is
    removed by the first rule that fires and reported with it.

    Every rule is monotone (if it spares a set, it spares every superset), so a component
    kept on its own keeps every component touching it; only groups of touching components
    that would all be removed are judged again as one.

    Flat pieces (volume within VOLUME_TOLERANCE of zero, slivers that boolean operations
    leave behind) hold no space: when too_small is on and something else is removed, they
    are dropped too and reported together as one too_small removal.

    Args:
        r2: The region R2 (world frame).
        ctx: Zone, parameters, support, known objects and the previous cycle.

    Returns:
        R3, its kept components, and the removed components with rule, volume and centroid.

    Raises:
        GeometryError: If R2 or the resulting R3 is not a valid manifold.
    """
    if r2.status() != m3.Error.NoError:
        raise GeometryError(f"plausibility: R2 is not a valid manifold (status {r2.status().name})")
    if r2.is_empty():
        return PlausibilityResult(region=r2, kept=(), removed=())
    rules = [(name, _RULES[name]) for name in RULE_ORDER if getattr(ctx.params, name)]
    pieces, flat = _pieces(r2)
    first = [_first_rule(p, rules, ctx) if rules else None for p in pieces]
    keep = [rule is None for rule in first]
    removed_groups: list[tuple[str, list[int]]] = []
    for group in _touch_groups(pieces, [i for i, rule in enumerate(first) if rule is not None]):
        rule = None
        if not any(keep[i] for i in group):
            rule = first[group[0]] if len(group) == 1 else _first_rule(_merge([pieces[i] for i in group]), rules, ctx)
        if rule is None:
            for i in group:
                keep[i] = True
        else:
            removed_groups.append((rule, group))
    if not removed_groups:
        return PlausibilityResult(region=r2, kept=tuple(p.manifold for p in pieces), removed=())

    with_cavities = any(len(p.shells) > 1 for p, k in zip(pieces, keep, strict=True) if k)
    if with_cavities:
        # Uniting outer shells would fill the cavities (the robot or an obstacle inside):
        # subtract the removed solids from R2 instead, which is exact but slower. A removed
        # solid that encloses a kept component (in a cavity) stays.
        kept_parts = [p for p, k in zip(pieces, keep, strict=True) if k]
        still_removed = []
        for rule, group in removed_groups:
            if _encloses_any(_merge([pieces[i] for i in group]), kept_parts):
                for i in group:
                    keep[i] = True
            else:
                still_removed.append((rule, group))
        removed_groups = still_removed
    kept = [p for p, k in zip(pieces, keep, strict=True) if k]
    removed = [_report(rule, [pieces[i] for i in group]) for rule, group in removed_groups]
    if not removed:
        return PlausibilityResult(region=r2, kept=tuple(p.manifold for p in pieces), removed=())
    if with_cavities:
        region = r2 - m3.Manifold.batch_boolean([r.mesh for r in removed], m3.OpType.Add)
    else:
        if flat and ctx.params.too_small:
            removed.append(_report("too_small", flat))
        if len(kept) == 1:
            region = kept[0].manifold
        elif kept:
            region = m3.Manifold.batch_boolean([p.manifold for p in kept], m3.OpType.Add)
        else:
            region = m3.Manifold()
    if region.status() != m3.Error.NoError:
        raise GeometryError(f"plausibility: building R3 failed (status {region.status().name})")
    return PlausibilityResult(
        region=region, kept=tuple(p.manifold for p in kept), removed=tuple(removed)
    )


def _encloses_any(solid: _Component, parts: Sequence[_Component]) -> bool:
    """True if one of ``parts`` lies inside the filled outer solid of ``solid``."""
    for part in parts:
        lo, hi = part.bbox[:3], part.bbox[3:]
        if np.all(solid.bbox[:3] <= lo) and np.all(solid.bbox[3:] >= hi):
            if solid.winding(part.vertices[:1])[0] > 0.5:
                return True
    return False

