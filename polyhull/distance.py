"""Minimum distance between the region R and the robot with python-fcl.

Robot links are FCL BVH models built once in their link frames; each cycle only their
transforms change. The region has two parts:

- the static region R3_static: BVHs of its 0.5 m chunks (:class:`ChunkedMesh`), built when
  the monitor is built and reused every cycle (their transform is the identity), with each
  link's distance reused while its motion bounds the change (:class:`StaticDistance`);
- the dynamic part: convex hexahedra (N, 8, 3). Only the pieces whose lower bound (from
  the links' balls and boxes) can come nearer to a link than the best distance found so
  far go into small BVHs built for the cycle, nearest first.

FCL returns -1 or 0 for objects in collision and its witness points are unreliable there,
so a distance <= 0 is contact, and a fresh ``DistanceResult`` is built for every query.
FCL measures between surfaces: a link entirely inside the region would report a positive
distance, so a point inside every moving link is tested for containment (inside a
hexahedron by its face planes; inside the static region by its winding number) and counts
as contact.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import fcl
import manifold3d as m3
import numba as nb
import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from .errors import GeometryError
from .typed import ArrayF64

__all__ = [
    "ChunkedMesh",
    "DistanceResult",
    "RobotDistanceModel",
    "StaticCycle",
    "StaticDistance",
    "manifold_to_fcl",
    "hexahedra_triangles",
    "points_in_hexahedra",
    "winding_numbers",
]

_HEX_FACES = np.array(
    [[0, 1, 2, 3], [4, 7, 6, 5], [0, 4, 5, 1], [1, 5, 6, 2], [2, 6, 7, 3], [3, 7, 4, 0]], dtype=np.int64
)


DISTANCE_BATCH = 8
"""Dynamic pieces in the first BVH; they are taken nearest first (by a lower bound of
their distance), and each further batch is four times larger while some of its pieces can
still be nearer than the best distance so far."""

ROTATION_SLACK = 1e-6
"""Added to a rotation change's spectral norm (computed from the trace) in a link's
displacement bound: rotation matrices orthonormal only to machine precision round the
trace by about 1e-15, which moves the norm by at most about 3e-8."""


class DistanceResult(NamedTuple):
    """Minimum distance between the region and the robot.

    Attributes:
        distance: Minimum distance [m]; inf when the region is empty; 0 on contact.
        points: (2, 3) closest points [m] (on the region, on the robot), or None.
        link: Name of the closest robot link, or None.
    """

    distance: float
    points: ArrayF64 | None
    link: str | None


def _bvh(vertices: ArrayF64, faces: np.ndarray) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int32))
    model.endModel()
    return model


@nb.njit(cache=True, nogil=True)
def _chunk_bounds(lo, hi, box, T, c, r):  # pragma: no cover - compiled
    """(K,) lower bounds of the distance between chunks (boxes ``lo``, ``hi`` (K, 3),
    world frame) and a link at pose ``T`` (its link-frame box ``box`` (8, 3) corners, the
    least first and the greatest last, and its ball ``c``, ``r``): the largest of the
    separations along the world axes (the link's box in the world), along the link's
    axes (each chunk's box in the link frame; each an orthonormal basis, so the root of
    the summed squares is a lower bound) and to the link's ball."""
    blo = np.full(3, np.inf)
    bhi = np.full(3, -np.inf)
    for m in range(8):
        for a in range(3):
            x = T[a, 0] * box[m, 0] + T[a, 1] * box[m, 1] + T[a, 2] * box[m, 2] + T[a, 3]
            blo[a] = min(blo[a], x)
            bhi[a] = max(bhi[a], x)
    cw = np.empty(3)
    for a in range(3):
        cw[a] = T[a, 0] * c[0] + T[a, 1] * c[1] + T[a, 2] * c[2] + T[a, 3]
    out = np.empty(lo.shape[0])
    for k in range(lo.shape[0]):
        world = 0.0
        ball = 0.0
        own = 0.0
        for a in range(3):
            s = max(max(lo[k, a] - bhi[a], blo[a] - hi[k, a]), 0.0)
            world += s * s
            s = max(max(lo[k, a] - cw[a], cw[a] - hi[k, a]), 0.0)
            ball += s * s
        for b in range(3):
            # the chunk's centre and half extent along the link's axis b
            centre = 0.0
            half = 0.0
            for a in range(3):
                centre += 0.5 * (lo[k, a] + hi[k, a]) * T[a, b] - T[a, 3] * T[a, b]
                half += 0.5 * (hi[k, a] - lo[k, a]) * abs(T[a, b])
            s = max(max(centre - half - box[7, b], box[0, b] - centre - half), 0.0)
            own += s * s
        out[k] = max(max(np.sqrt(world), np.sqrt(own)), np.sqrt(ball) - r)
    return out


STATIC_CHUNK = 0.5
"""Edge [m] of the grid cells that split a large static mesh into chunks
(:class:`ChunkedMesh`)."""

STATIC_TOLERANCE = 1e-4
"""Tolerance [m] to which the static region is simplified for its distance
(:meth:`ChunkedMesh.of_manifold`). The static region is built at full pixel resolution:
163,000 triangles on the paper cell, most of them coplanar; at 0.1 mm it keeps 7,600, and
a link's distance to it costs 2.6 times less. The distance is reported that much nearer."""


class ChunkedMesh:
    """A large mesh (the static region) as spatial chunks, each its own FCL BVH.

    FCL's distance between a link and one BVH of the whole static region (~160 k
    triangles, mostly ~2 m away) visits many nodes whose bounds are all near the answer
    (~2.5 ms a link). Here the triangles longer than ``chunk`` are split, and each
    triangle goes to the chunk of the grid cell (edge ``chunk``) holding its centroid, and a link is measured against the chunks in order of
    their boxes' distance to the link's box, while that is below the link's best distance
    so far: the same minimum (over all triangles), measured against a few small BVHs
    (~0.8 ms). The chunks are triangle soups, as the whole mesh is to FCL: containment is
    tested separately (a point inside every link, by winding number).
    """

    def __init__(self, vertices: ArrayF64, triangles: np.ndarray, chunk: float = STATIC_CHUNK, tolerance: float = 0.0) -> None:
        self.tolerance = float(tolerance)
        """How far [m] the mesh's surface may lie from the region's it stands for: a
        distance measured to it, less this, is never above the region's."""
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(triangles):
            # triangles longer than a chunk are split (the same surface): one long triangle
            # would stretch its chunk's box over the cell and spoil every chunk's bound
            vertices, triangles = trimesh.remesh.subdivide_to_size(vertices, triangles, max_edge=chunk)
        key = np.floor(vertices[triangles].mean(axis=1) / chunk).astype(np.int64)
        _, label = np.unique(key, axis=0, return_inverse=True)
        label = label.ravel()
        order = np.argsort(label, kind="stable")
        starts = np.searchsorted(label[order], np.arange(int(label.max(initial=-1)) + 2))
        self.objects: list[fcl.CollisionObject] = []
        lo, hi = [], []
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            tris = triangles[order[a:b]]
            used, inverse = np.unique(tris, return_inverse=True)
            v = vertices[used]
            self.objects.append(fcl.CollisionObject(_bvh(v, inverse.reshape(-1, 3)), fcl.Transform()))
            lo.append(v.min(axis=0))
            hi.append(v.max(axis=0))
        self.lo = np.array(lo, dtype=np.float64).reshape(-1, 3)
        """(K, 3) the chunks' box minima [m]."""
        self.hi = np.array(hi, dtype=np.float64).reshape(-1, 3)
        """(K, 3) the chunks' box maxima [m]."""

    @classmethod
    def of_manifold(cls, region: m3.Manifold, chunk: float = STATIC_CHUNK, tolerance: float = 0.0) -> ChunkedMesh | None:
        """The chunks of a manifold's triangles (world frame), None if it is empty. With a
        ``tolerance`` [m], of the manifold simplified to it first (manifold3d's
        ``simplify``: a subset of the vertices, every surface moved by less than it)."""
        if region.is_empty():
            return None
        if tolerance > 0.0:
            region = region.simplify(tolerance)
        mesh = region.to_mesh64()
        return cls(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), chunk, tolerance)

    def __len__(self) -> int:
        return len(self.objects)


def manifold_to_fcl(region: m3.Manifold) -> fcl.CollisionObject | None:
    """An FCL collision object of a manifold's triangles (world frame), None if empty."""
    if region.is_empty():
        return None
    mesh = region.to_mesh64()
    verts = np.asarray(mesh.vert_properties)[:, :3]
    tris = np.asarray(mesh.tri_verts)
    return fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())


def hexahedra_triangles(vertices: ArrayF64) -> tuple[ArrayF64, np.ndarray]:
    """Vertices (8N, 3) and triangles (12N, 3) of hexahedra (N, 8, 3)."""
    n = vertices.shape[0]
    quads = _HEX_FACES[None, :, :] + 8 * np.arange(n)[:, None, None]  # (N, 6, 4)
    tris = np.concatenate([quads[:, :, [0, 1, 2]], quads[:, :, [0, 2, 3]]], axis=1).reshape(-1, 3)
    return vertices.reshape(-1, 3), tris


def points_in_hexahedra(points: ArrayF64, vertices: ArrayF64) -> np.ndarray:
    """(P,) whether each point lies inside (or on) some convex hexahedron (N, 8, 3).

    Candidate pairs come from a k-d tree of the points queried with each hexahedron's
    bounding sphere, so memory follows the pairs that can meet, not P x N.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(points), dtype=bool)
    if len(points) == 0 or vertices.shape[0] == 0:
        return out
    from scipy.spatial import cKDTree

    # only hexahedra whose bounding box holds a point
    lo, hi = vertices.min(axis=1), vertices.max(axis=1)
    if len(points) <= 64:
        near = np.zeros(len(vertices), dtype=bool)
        for p in points:
            near |= np.all((lo <= p) & (p <= hi), axis=1)
        if not near.any():
            return out
        vertices = vertices[near]
    f = vertices[:, _HEX_FACES]  # (N, 6, 4, 3)
    n = np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])
    n = n + np.cross(f[:, :, 2] - f[:, :, 0], f[:, :, 3] - f[:, :, 0])  # robust to a degenerate corner
    c = vertices.mean(axis=1)  # (N, 3), inside each convex piece
    d = np.einsum("nfk,nfk->nf", n, f[:, :, 0])
    outward = np.einsum("nfk,nk->nf", n, c) < d
    n = np.where(outward[:, :, None], n, -n)
    d = np.where(outward, d, -d)
    tol = 1e-9 * (1.0 + np.abs(d))
    radius = np.linalg.norm(vertices - c[:, None, :], axis=2).max(axis=1)
    tree = cKDTree(points)
    for lo in range(0, len(c), 4096):
        hits = tree.query_ball_point(c[lo : lo + 4096], radius[lo : lo + 4096] + 1e-9)
        counts = np.fromiter((len(h) for h in hits), dtype=np.int64, count=len(hits))
        if counts.sum() == 0:
            continue
        piece = np.repeat(np.arange(lo, lo + len(hits)), counts)
        pts = np.fromiter((i for h in hits for i in h), dtype=np.int64, count=int(counts.sum()))
        todo = ~out[pts]
        piece, pts = piece[todo], pts[todo]
        inside = (np.einsum("pfk,pk->pf", n[piece], points[pts]) <= (d + tol)[piece]).all(axis=1)
        out[pts[inside]] = True
    return out


def winding_numbers(points: ArrayF64, vertices: ArrayF64, triangles: np.ndarray) -> ArrayF64:
    """Generalised winding numbers (P,) of points w.r.t. a closed mesh (~1 inside, ~0 outside)."""
    out = np.zeros(len(points))
    a0, b0, c0 = (vertices[triangles[:, k]] for k in range(3))
    for i, p in enumerate(points):
        a, b, c = a0 - p, b0 - p, c0 - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
        den += np.einsum("ij,ij->i", c, a) * lb
        out[i] = np.arctan2(num, den).sum() / (2.0 * np.pi)
    return out


class RobotDistanceModel:
    """FCL models of the robot links, for distance queries at changing joint positions."""

    def __init__(
        self,
        link_geometry: Mapping[str, trimesh.Trimesh],
        link_pieces: Mapping[str, Sequence[ArrayF64]] | None = None,
    ) -> None:
        """Build one BVH per link, and the face planes that bound the dynamic pieces'
        distances before any BVH is built for them.

        Args:
            link_geometry: Collision mesh per link in the link frame.
            link_pieces: Vertices (K, 3) of convex pieces per link (link frame) whose
                union holds the link's mesh, e.g. :meth:`polyhull.robot.Robot.link_convex_pieces`:
                their face planes bound the distance more tightly than the mesh's hull.
                A link without them, or whose mesh has a vertex outside them, is bounded by
                its mesh's convex hull.
        """
        self._objects: dict[str, fcl.CollisionObject] = {}
        self._spheres: dict[str, tuple[ArrayF64, float]] = {}
        self._corners: dict[str, ArrayF64] = {}  # (8, 3) the link-frame box's corners
        self._inner: dict[str, ArrayF64] = {}
        for name, mesh in link_geometry.items():
            if len(mesh.faces) == 0:
                continue
            self._objects[name] = fcl.CollisionObject(_bvh(mesh.vertices, mesh.faces), fcl.Transform())
            v = np.asarray(mesh.vertices, dtype=np.float64)
            center = 0.5 * (v.min(axis=0) + v.max(axis=0))
            self._spheres[name] = (center, float(np.linalg.norm(v - center, axis=1).max()))
            lo, hi = v.min(axis=0), v.max(axis=0)
            self._corners[name] = np.array([[(hi if m & b else lo)[a] for a, b in enumerate((1, 2, 4))] for m in range(8)])
            # A point inside the link: the centroid of its volume (inside for convex parts,
            # else the vertex nearest to it, which is on the link).
            inner = np.asarray(mesh.centroid, dtype=np.float64)
            self._inner[name] = inner
        self._planes = _link_planes(
            {n: link_geometry[n] for n in self._objects}, {} if link_pieces is None else link_pieces
        )

    @property
    def link_names(self) -> tuple[str, ...]:
        """Links with geometry."""
        return tuple(self._objects)

    def _query(self, region_obj: fcl.CollisionObject, name: str, T: ArrayF64) -> tuple[float, ArrayF64 | None]:
        obj = self._objects[name]
        obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
        request = fcl.DistanceRequest(enable_nearest_points=True, enable_signed_distance=False)
        result = fcl.DistanceResult()
        try:
            d = float(fcl.distance(region_obj, obj, request, result))
        except Exception as exc:  # FCL raises plain RuntimeErrors
            raise GeometryError(f"FCL distance to link '{name}' failed: {exc}") from exc
        if not math.isfinite(d):
            raise GeometryError(f"FCL distance to link '{name}' is not finite: {d}")
        if d <= 0.0:
            return 0.0, None
        return d, np.array([result.nearest_points[0], result.nearest_points[1]], dtype=np.float64)

    def query_chunks(
        self, chunks: ChunkedMesh, name: str, T: ArrayF64, first: int = -1, bound: float = math.inf
    ) -> tuple[float, ArrayF64 | None, int]:
        """Distance, closest points (region, link) and the nearest chunk between link
        ``name`` at pose ``T`` and a chunked mesh: chunk ``first`` (e.g. the last nearest,
        when >= 0), then the chunks nearest first (by a lower bound of their distance: the
        larger of their box's distance to the link's box and to the link's ball) while they
        can be nearer than the best so far; (0, None, chunk) on contact.

        Only distances below ``bound`` are sought: when the link is at least ``bound``
        away, the result is a lower bound of its distance, itself at least ``bound``
        (the least of the distances measured and of the chunks' bounds not measured),
        with no points (the chunk -1 when none was measured)."""
        if len(chunks) == 0:
            return math.inf, None, -1
        c, r = self._spheres[name]
        gap = _chunk_bounds(chunks.lo, chunks.hi, self._corners[name], np.ascontiguousarray(T, dtype=np.float64), c, r)
        best, points, nearest = math.inf, None, -1
        # nearest first (the least bound; ties: the lower index, as a stable sort), the hint
        # first when it is below the bound; the chunks measured are marked +inf
        if 0 <= first < len(chunks) and gap[first] < bound:
            j = first
        else:
            j = int(np.argmin(gap))
        unmeasured = math.inf  # the least bound of a chunk left out
        while True:
            if gap[j] >= min(best, bound):
                unmeasured = float(gap[j])
                break
            gap[j] = math.inf
            d, pts = self._query(chunks.objects[j], name, T)
            if d <= 0.0:
                return 0.0, None, j
            if d < best:
                best, points, nearest = d, pts, j
            j = int(np.argmin(gap))
        if best < bound:
            return best, points, nearest
        return min(best, unmeasured), None, nearest

    def inner_points(self, T_world_links: Mapping[str, ArrayF64]) -> dict[str, ArrayF64]:
        """A point inside (or on) every link, world frame."""
        return {n: T_world_links[n][:3, :3] @ p + T_world_links[n][:3, 3] for n, p in self._inner.items()}

    def distance(
        self,
        T_world_links: Mapping[str, ArrayF64],
        *,
        static: fcl.CollisionObject | None = None,
        static_contains: Callable[[ArrayF64], np.ndarray] | None = None,
        pieces: ArrayF64 | None = None,
        region: m3.Manifold | None = None,
        best: DistanceResult | None = None,
        cutoff: float = math.inf,
    ) -> DistanceResult:
        """Minimum distance between the region and the robot at the given link poses.

        Args:
            T_world_links: (4, 4) pose of every link.
            static: The static region's FCL object (world frame), or None.
            static_contains: Which points (P, 3) are inside the static region.
            pieces: (N, 8, 3) convex hexahedra of the dynamic region [m], or None.
            region: A region given as one manifold instead (tests, inspection).
            best: The distance of another part of the region measured already (e.g.
                the static region's, reused while the dynamic pieces change): the
                result is the nearer of the two.
            cutoff: An upper bound [m] of another part's distance not measured yet:
                pieces that cannot be nearer than it are not measured (the result is
                then ``best``, and the caller measures that part).

        Raises:
            GeometryError: FCL failed.
        """
        if best is None:
            best = DistanceResult(math.inf, None, None)
        elif best.distance <= 0.0:
            return best
        names = list(self._objects)
        inner = self.inner_points(T_world_links)
        inner_pts = np.array([inner[n] for n in names]).reshape(-1, 3)
        if region is not None:
            static = manifold_to_fcl(region)
        if static is not None:
            if static_contains is not None and len(inner_pts):
                hit = static_contains(inner_pts)
                if hit.any():
                    return DistanceResult(0.0, None, names[int(np.argmax(hit))])
            for name in names:
                d, pts = self._query(static, name, T_world_links[name])
                if d <= 0.0:
                    return DistanceResult(0.0, None, name)
                if d < best.distance:
                    best = DistanceResult(d, pts, name)
        if pieces is not None and pieces.shape[0]:
            pieces = np.ascontiguousarray(pieces, dtype=np.float64)
            sph_c = np.empty((len(names), 3))
            sph_r = np.empty(len(names))
            poses = np.empty((len(names), 3, 4))
            boxes = np.empty((len(names), 2, 3))
            for j, name in enumerate(names):
                c, r = self._spheres[name]
                T = T_world_links[name]
                sph_c[j] = T[:3, :3] @ c + T[:3, 3]
                sph_r[j] = r
                poses[j] = T[:3, :4]
                boxes[j, 0], boxes[j, 1] = self._corners[name][0], self._corners[name][7]
            lower, near_inner, mid_gap = _piece_bounds(
                pieces, sph_c, sph_r, poses, boxes, np.ascontiguousarray(inner_pts, dtype=np.float64)
            )
            if near_inner.any():  # a link's inner point in a piece's box: the exact test
                inside = points_in_hexahedra(inner_pts, pieces[near_inner])
                if inside.any():
                    return DistanceResult(0.0, None, names[int(np.argmax(inside))])
            upper = min(best.distance, cutoff, mid_gap)
            low = lower.min(axis=0)
            # nearest first, in batches: a batch's BVH is built only while some of its
            # pieces can still be nearer than the best distance so far
            cand = np.nonzero(low < upper)[0]
            order = cand[np.argsort(low[cand], kind="stable")]
            b0, size = 0, DISTANCE_BATCH
            while b0 < len(order):
                batch = order[b0 : b0 + size]
                b0, size = b0 + size, 4 * size
                bound = min(best.distance, cutoff)
                batch = batch[low[batch] < bound]
                if len(batch) == 0:
                    break
                # the batch's bounds made tighter (costlier: only for the pieces examined)
                tight = np.maximum(lower[:, batch], _frame_box_gaps(pieces[batch], poses, boxes))
                _plane_gaps(pieces[batch], poses, *self._planes, tight, bound)
                keep = tight.min(axis=0) < bound
                batch, tight = batch[keep], tight[:, keep]
                if len(batch) == 0:
                    continue
                verts, tris = hexahedra_triangles(pieces[batch])
                obj = fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())
                for j, name in enumerate(names):
                    if float(tight[j].min()) >= min(best.distance, cutoff):
                        continue
                    d, pts = self._query(obj, name, T_world_links[name])
                    if d <= 0.0:
                        return DistanceResult(0.0, None, name)
                    if d < best.distance:
                        best = DistanceResult(d, pts, name)
        return best


@nb.njit(cache=True, nogil=True)
def _piece_bounds(pieces, sph_c, sph_r, poses, boxes, inner):  # pragma: no cover - compiled
    """For hexahedra (N, 8, 3) and the links' bounding balls (L, 3), (L,) and bounding
    boxes (L, 2, 3) in their frames (poses (L, 3, 4)): (L, N) lower bounds of each piece's
    distance to each link (the larger of: centre distance less both radii, and the
    distance from the piece's box centre to the link's box less the piece's radius, with
    its farthest vertex); (N,) whether some link's inner point
    (L, 3) lies in the piece's bounding box; and the least distance from a piece's vertex
    mean (inside the convex piece) to a link's inner point (an upper bound of the
    distance)."""
    n = pieces.shape[0]
    L = sph_c.shape[0]
    lower = np.empty((L, n))
    near = np.zeros(n, dtype=np.bool_)
    upper2 = np.inf  # squared (one root at the end)
    for i in range(n):
        # scalars, not per-piece arrays (an allocation a piece cost more than the bounds)
        lo0 = hi0 = pieces[i, 0, 0]
        lo1 = hi1 = pieces[i, 0, 1]
        lo2 = hi2 = pieces[i, 0, 2]
        m0 = m1 = m2 = 0.0
        for k in range(8):
            x, y, z = pieces[i, k, 0], pieces[i, k, 1], pieces[i, k, 2]
            lo0, hi0 = min(lo0, x), max(hi0, x)
            lo1, hi1 = min(lo1, y), max(hi1, y)
            lo2, hi2 = min(lo2, z), max(hi2, z)
            m0 += x
            m1 += y
            m2 += z
        c0 = 0.5 * (lo0 + hi0)
        c1 = 0.5 * (lo1 + hi1)
        c2 = 0.5 * (lo2 + hi2)
        rad2 = 0.0
        for k in range(8):
            dx = pieces[i, k, 0] - c0
            dy = pieces[i, k, 1] - c1
            dz = pieces[i, k, 2] - c2
            rad2 = max(rad2, dx * dx + dy * dy + dz * dz)
        rad = np.sqrt(rad2)
        for j in range(L):
            dx = c0 - sph_c[j, 0]
            dy = c1 - sph_c[j, 1]
            dz = c2 - sph_c[j, 2]
            ball = np.sqrt(dx * dx + dy * dy + dz * dz) - rad - sph_r[j]
            # the centre in the link's frame, and its distance to the link's box
            ex = c0 - poses[j, 0, 3]
            ey = c1 - poses[j, 1, 3]
            ez = c2 - poses[j, 2, 3]
            g2 = 0.0
            for a in range(3):
                x = poses[j, 0, a] * ex + poses[j, 1, a] * ey + poses[j, 2, a] * ez
                g = max(boxes[j, 0, a] - x, x - boxes[j, 1, a], 0.0)
                g2 += g * g
            lower[j, i] = max(ball, np.sqrt(g2) - rad)
            p0, p1, p2 = inner[j, 0], inner[j, 1], inner[j, 2]
            if lo0 <= p0 <= hi0 and lo1 <= p1 <= hi1 and lo2 <= p2 <= hi2:
                near[i] = True
            dx = m0 / 8.0 - p0
            dy = m1 / 8.0 - p1
            dz = m2 / 8.0 - p2
            upper2 = min(upper2, dx * dx + dy * dy + dz * dz)
    upper = np.sqrt(upper2)
    return lower, near, upper


PLANE_SLACK = 1e-9
"""[m] added to every face plane's offset (the bound only loosens): the planes' rounding (normals of unit
length to about 1e-16, coordinates of a few metres) is far below it."""


def _convex_planes(vertices: ArrayF64) -> ArrayF64:
    """(F, 4) outward unit normals and offsets ``n . x <= d`` of the faces of a convex
    piece's hull (coplanar triangles give one plane); ``d`` is the greatest ``n . v`` over
    the piece's vertices, so every vertex is on the inner side. A piece without a hull
    (flat, or too few vertices) is bounded by its box's six planes."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    try:
        # qhull's unit normals, one per plane (a face's triangles agree to rounding)
        normals = np.unique(np.round(ConvexHull(v).equations[:, :3], 12), axis=0)
        normals /= np.linalg.norm(normals, axis=1)[:, None]
    except (QhullError, ValueError):
        normals = np.concatenate([np.eye(3), -np.eye(3)])
    d = (normals @ v.T).max(axis=1)
    return np.column_stack([normals, d + PLANE_SLACK])


def _link_planes(
    meshes: Mapping[str, trimesh.Trimesh], pieces: Mapping[str, Sequence[ArrayF64]]
) -> tuple[ArrayF64, np.ndarray, np.ndarray]:
    """The face planes of each link's convex pieces, for :func:`_plane_gaps` (links in the
    order of ``meshes``): the given pieces where every vertex of the link's mesh lies in
    one of them, else the mesh's hull."""
    planes: list[ArrayF64] = []
    piece_start = [0]
    link_start = [0]
    for name, mesh in meshes.items():
        given = [_convex_planes(p) for p in pieces.get(name, ())]
        v = np.asarray(mesh.vertices, dtype=np.float64)
        held = bool(given) and bool(
            np.any([(v @ p[:, :3].T <= p[:, 3]).all(axis=1) for p in given], axis=0).all()
        )
        for p in given if held else [_convex_planes(v)]:
            planes.append(p)
            piece_start.append(piece_start[-1] + len(p))
        link_start.append(len(piece_start) - 1)
    return (
        np.ascontiguousarray(np.concatenate(planes) if planes else np.zeros((0, 4))),
        np.asarray(piece_start, dtype=np.int64),
        np.asarray(link_start, dtype=np.int64),
    )


@nb.njit(cache=True, nogil=True)
def _plane_gaps(pieces, poses, planes, piece_planes, link_pieces, tight, bound):  # pragma: no cover - compiled
    """Raise ``tight`` (L, N), lower bounds of each hexahedron's (N, 8, 3) distance to each
    link, to the separating-plane bound where it is below ``bound``: a link's convex piece
    lies on the inner side of each of its face planes (``planes`` (M, 4): unit outward
    normal and offset ``n . x <= d`` in the link frame, poses (L, 3, 4)), so a point ``x``
    is at least ``n . x - d`` from it, and the hexahedron, the hull of its vertices, at least
    the least of that over its vertices; the best plane of each piece, the nearest piece of
    the link (``piece_planes`` (P + 1,) each piece's first plane, ``link_pieces`` (L + 1,)
    each link's first piece)."""
    L = poses.shape[0]
    n = pieces.shape[0]
    x = np.empty((8, 3))
    for j in range(L):
        if link_pieces[j] == link_pieces[j + 1]:
            continue  # no piece: no bound
        for i in range(n):
            if tight[j, i] >= bound:
                continue
            for k in range(8):  # the vertices in the link's frame
                for a in range(3):
                    x[k, a] = (
                        poses[j, 0, a] * (pieces[i, k, 0] - poses[j, 0, 3])
                        + poses[j, 1, a] * (pieces[i, k, 1] - poses[j, 1, 3])
                        + poses[j, 2, a] * (pieces[i, k, 2] - poses[j, 2, 3])
                    )
            link = np.inf
            for p in range(link_pieces[j], link_pieces[j + 1]):
                best = 0.0
                for f in range(piece_planes[p], piece_planes[p + 1]):
                    g = np.inf
                    for k in range(8):
                        g = min(g, planes[f, 0] * x[k, 0] + planes[f, 1] * x[k, 1] + planes[f, 2] * x[k, 2] - planes[f, 3])
                    best = max(best, g)
                link = min(link, best)
                if link <= tight[j, i]:
                    break
            if link > tight[j, i]:
                tight[j, i] = link
    return tight


@nb.njit(cache=True, nogil=True)
def _frame_box_gaps(pieces, poses, boxes):  # pragma: no cover - compiled
    """(L, N) for hexahedra (N, 8, 3) and the links' bounding boxes (L, 2, 3) in their
    frames (poses (L, 3, 4)): the distance between each link's box and the box of each
    piece's vertices in that link's frame, which holds the convex piece (a lower bound of
    their distance; for a large or slanted piece much nearer the truth than its balls')."""
    n = pieces.shape[0]
    L = poses.shape[0]
    out = np.empty((L, n))
    for j in range(L):
        for i in range(n):
            g2 = 0.0
            for a in range(3):
                vlo = np.inf
                vhi = -np.inf
                for k in range(8):
                    x = (
                        poses[j, 0, a] * (pieces[i, k, 0] - poses[j, 0, 3])
                        + poses[j, 1, a] * (pieces[i, k, 1] - poses[j, 1, 3])
                        + poses[j, 2, a] * (pieces[i, k, 2] - poses[j, 2, 3])
                    )
                    vlo = min(vlo, x)
                    vhi = max(vhi, x)
                g = max(boxes[j, 0, a] - vhi, vlo - boxes[j, 1, a], 0.0)
                g2 += g * g
            out[j, i] = np.sqrt(g2)
    return out


def _nearer_by(d: float, points: ArrayF64 | None, tolerance: float) -> tuple[float, ArrayF64 | None]:
    """A distance ``d`` and its closest points (region, link) made ``tolerance`` [m]
    nearer: the region's point moved that far towards the link's (contact when
    ``d <= tolerance``)."""
    if tolerance <= 0.0 or d <= 0.0:
        return d, points
    if d <= tolerance or points is None:
        return (0.0, None) if d <= tolerance else (d - tolerance, None)
    region, link = points
    moved = region + (link - region) * (tolerance / d)
    return d - tolerance, np.array([moved, link], dtype=np.float64)


def _displacement(T0: ArrayF64, T1: ArrayF64, center: ArrayF64, radius: float) -> float:
    """An upper bound [m] of how far any point of a ball (link frame ``center``,
    ``radius``) moves from pose ``T0`` to pose ``T1``: the centre's displacement plus the
    rotation's change times the radius. The change ``R1 - R0`` of a rotation by an angle
    theta has the spectral norm ``2 sin(theta / 2) = sqrt(3 - trace(R0^T R1))`` (the
    Frobenius norm is sqrt(2) times that); ``ROTATION_SLACK`` covers the rounding of
    rotations that are orthonormal only to machine precision."""
    R0, R1 = T0[:3, :3], T1[:3, :3]
    dc = (R1 - R0) @ center + (T1[:3, 3] - T0[:3, 3])
    spectral = math.sqrt(max(3.0 - float(np.sum(R0 * R1)), 0.0)) + ROTATION_SLACK
    return float(np.linalg.norm(dc) + min(spectral, float(np.linalg.norm(R1 - R0))) * radius)


class StaticDistance:
    """The static region's distance to each robot link, reused across cycles.

    A link that moved by at most ``delta`` since its distance ``d`` was measured is at
    least ``d - delta`` away from the (unchanged) static region. Each cycle
    (:meth:`cycle`) gives every link that lower bound, and only links whose bound is below
    the distance sought are measured with FCL: the result is FCL's exact distance
    whenever the static region is the nearest part, and otherwise no static query runs.
    A mesh simplified to a tolerance (:attr:`ChunkedMesh.tolerance`) gives distances less
    that tolerance, their region point that much nearer the link.
    """

    def __init__(
        self,
        model: RobotDistanceModel,
        static: ChunkedMesh | None,
        contains: Callable[[ArrayF64], np.ndarray] | None,
    ) -> None:
        self._model = model
        self._static = static if static is not None and len(static) else None
        self._contains = contains
        # each link's pose when last measured, its distance then (or a lower bound of it)
        # and whether that was its distance
        self._last: dict[str, tuple[ArrayF64, float, bool]] = {}
        self._nearest: dict[str, int] = {}  # each link's nearest chunk when last measured

    def reset(self) -> None:
        """Forget the measured distances (the next cycle measures every link it needs)."""
        self._last.clear()
        self._nearest.clear()

    def cycle(self, T_world_links: Mapping[str, ArrayF64]) -> StaticCycle:
        """This cycle's static distance, measured lazily."""
        return StaticCycle(self, T_world_links)


class StaticCycle:
    """One cycle's static distance (see :class:`StaticDistance`)."""

    def __init__(self, owner: StaticDistance, T_world_links: Mapping[str, ArrayF64]) -> None:
        self._owner = owner
        self._T = T_world_links
        model = owner._model
        self._names = model.link_names
        # per measured link: its distance (or, at or above the bound it was sought below,
        # a lower bound of it), its points and that bound
        self._done: dict[str, tuple[float, ArrayF64 | None, float]] = {}
        self.contact: DistanceResult | None = None
        self.queries = 0
        lower, upper = [], []
        for name in self._names:
            last = owner._last.get(name)
            if last is None or owner._static is None:
                lower.append(0.0 if owner._static is not None else math.inf)
                upper.append(math.inf)
                continue
            c, r = model._spheres[name]
            delta = _displacement(last[0], T_world_links[name], c, r)
            lower.append(max(last[1] - delta, 0.0))
            upper.append(last[1] + delta if last[2] else math.inf)
        self._lower = np.array(lower, dtype=np.float64)
        self.upper = float(min(upper, default=math.inf))
        """An upper bound [m] of the static distance (inf when not known)."""
        if owner._static is not None and owner._contains is not None and self._names:
            inner = model.inner_points(T_world_links)
            hit = owner._contains(np.array([inner[n] for n in self._names]).reshape(-1, 3))
            if hit.any():
                self.contact = DistanceResult(0.0, None, self._names[int(np.argmax(hit))])

    def nearer(self, best: DistanceResult | None = None) -> DistanceResult:
        """The nearer of ``best`` and the static region (links measured only while their
        lower bound is below the best distance so far)."""
        if best is None:
            best = DistanceResult(math.inf, None, None)
        if self.contact is not None:
            return self.contact
        owner = self._owner
        if owner._static is None or best.distance <= 0.0:
            return best
        tol = owner._static.tolerance
        for j in np.argsort(self._lower, kind="stable"):
            name = self._names[int(j)]
            done = self._done.get(name)
            if done is not None and (done[0] < done[2] or done[0] >= best.distance):
                d, pts, _ = done  # exact, or a lower bound that cannot beat the best
            else:
                if self._lower[j] >= best.distance:
                    break
                # sought only below the best so far (plus the mesh's tolerance, which
                # the result loses): farther, a lower bound is all the cycle needs
                hint = owner._nearest.get(name, -1)
                d, pts, nearest = owner._model.query_chunks(owner._static, name, self._T[name], hint, best.distance + tol)
                if nearest >= 0:
                    owner._nearest[name] = nearest
                d, pts = _nearer_by(d, pts, tol)
                self.queries += 1
                self._done[name] = (d, pts, best.distance)
                owner._last[name] = (np.array(self._T[name], dtype=np.float64), d, d < best.distance)
            if d <= 0.0:
                return DistanceResult(0.0, None, name)
            if d < best.distance:
                best = DistanceResult(d, pts, name)
        return best
