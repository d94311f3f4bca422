"""The answer of one cycle (:class:`Verdict`) and the geometry it builds when read.

A verdict carries the cycle's decision (distance, speed, faults) at once; its regions
(``hull``, ``robot_occlusion``, ``region_r2``, ``region``, ``region_dynamic``) are manifold3d
Manifolds built from the cycle's pieces only when someone reads them, off the hot path.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import manifold3d as m3
import numpy as np

from .distance import hexahedra_triangles
from .engine.dynamic_rules import LazyMesh
from .engine.pieces import (
    CameraStack,
    PieceSet,
    merge_adjacent,
    piece_vertices,
    piece_volumes,
    vertex_bounds,
)
from .engine.robot_raster import RobotRaster
from .engine.static_model import StaticModel
from .plausibility import RemovedComponent
from .regions import check_manifold
from .typed import ArrayF64

__all__ = ["CycleImages", "Verdict", "gaps_removed", "hexahedra_manifold", "pieces_manifold", "pieces_removed"]


def hexahedra_manifold(vertices: ArrayF64) -> m3.Manifold:
    """The union of convex hexahedra (N, 8, 3) as one manifold."""
    hulls = [m3.Manifold.hull_points(v) for v in vertices]
    hulls = [h for h in hulls if not h.is_empty()]
    if not hulls:
        return m3.Manifold()
    return check_manifold(m3.Manifold.batch_boolean(hulls, m3.OpType.Add), "dynamic region")


def pieces_manifold(boxes: ArrayF64, stack: CameraStack) -> m3.Manifold:
    """The union of pieces ``boxes`` (N, 7) (:class:`polyhull.engine.pieces.PieceSet`) as
    one manifold.

    Per camera, its boxes are united as axis-aligned boxes in its image space (u and v
    [px], the pixels' edges, and z-depth [m]), then mapped to the world. The map to the
    camera frame, ``(u, v, z) -> ((u - cx) z / fx, (v - cy) z / fy, z)``, takes every plane
    to a plane and keeps orientation (its Jacobian is ``z^2 / (fx fy) > 0``), so each
    triangle goes to the triangle of its mapped corners: the result is the union of the
    pieces' world hexahedra, exactly. A camera's pieces meet face to face; united in
    image space their faces are axis-aligned (about 25 times faster than uniting the
    world hexahedra, whose coplanar faces at odd angles also lose slivers to manifold3d's
    tolerance). The cameras' unions are then united in the world. Siblings that carving
    split and the rules kept whole are merged back first (:func:`merge_adjacent`: the
    same set from about a third as many boxes).
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    b = merge_adjacent(b[(b[:, 6] > b[:, 5]) & (b[:, 2] >= b[:, 1]) & (b[:, 4] >= b[:, 3])])
    parts = []
    for c in np.unique(b[:, 0]).astype(np.int64):
        own = b[b[:, 0] == c]
        lo = np.column_stack([own[:, 1] - 0.5, own[:, 3] - 0.5, own[:, 5]])
        size = np.column_stack([own[:, 2] - own[:, 1] + 1.0, own[:, 4] - own[:, 3] + 1.0, own[:, 6] - own[:, 5]])
        cubes = [m3.Manifold.cube(tuple(e)).translate(tuple(o)) for o, e in zip(lo.tolist(), size.tolist(), strict=True)]
        united = m3.Manifold.batch_boolean(cubes, m3.OpType.Add)
        parts.append(united.warp_batch(functools.partial(_image_to_world, stack=stack, camera=int(c))))
    if not parts:
        return m3.Manifold()
    return check_manifold(m3.Manifold.batch_boolean(parts, m3.OpType.Add), "dynamic region")


def _image_to_world(points: np.ndarray, stack: CameraStack, camera: int) -> ArrayF64:
    """(N, 3) image-space points (u, v [px], z [m]) of ``camera`` to the world frame."""
    fx, fy, cx, cy = stack.intr[camera]
    p = np.asarray(points, dtype=np.float64)
    z = p[:, 2]
    local = np.column_stack([(p[:, 0] - cx) / fx * z, (p[:, 1] - cy) / fy * z, z])
    return np.asarray(local @ stack.R_wc[camera].T + stack.t_wc[camera], dtype=np.float64)


@dataclass(eq=False)
class CycleGeometry:
    """What a verdict needs to build its manifolds when they are read."""

    static: StaticModel
    zone: m3.Manifold
    pieces_parts: tuple[PieceSet, ...]  # all dynamic pieces before the rules (with memory)
    kept_pieces: ArrayF64  # (K, 8, 3) kept dynamic pieces
    kept_boxes: ArrayF64  # (K, 7) the same in their cameras' image space
    kept_residue: np.ndarray  # (K,) made only of a small gap's far part (no reading)
    stack: CameraStack  # the cameras, for the pieces' vertices
    sheet_boxes: ArrayF64  # (S, 8, 3) the sheet boxes under them
    robot_body: Callable[[], m3.Manifold]
    occlusion: Callable[[], m3.Manifold]
    full_pieces: Callable[[], PieceSet]
    lease: object = None  # holds the cycle's images (see :class:`polyhull.engine.buffers.Pool`)
    k_of_n: int = 1  # the cell's k-of-n rule (C_static's test)
    cache: dict[str, m3.Manifold] = field(default_factory=dict)

    @functools.cached_property
    def piece_set(self) -> PieceSet:
        """All dynamic pieces before the rules (with the memory's)."""
        return PieceSet.concat(self.pieces_parts)

    @property
    def pieces(self) -> ArrayF64:
        """(N, 8, 3) the world vertices of :attr:`piece_set`."""
        return self.piece_set.vertices

    @functools.cached_property
    def kept(self) -> ArrayF64:
        """(K, 8, 3) the kept dynamic pieces, then the sheet boxes."""
        return np.concatenate([self.kept_pieces, self.sheet_boxes])

    def get(self, name: str) -> m3.Manifold:
        if name not in self.cache:
            self.cache[name] = self._build(name)
        return self.cache[name]

    @functools.cached_property
    def merged_boxes(self) -> ArrayF64:
        """(M, 7) the kept pieces with siblings merged back (the same union from about a
        third as many pieces)."""
        return merge_adjacent(self.kept_boxes)

    def merged_pieces(self, unseen: bool = False) -> ArrayF64:
        """(M, 8, 3) the kept pieces with a reading (``unseen`` False) or those made only
        of a small gap's far part (True), siblings merged, as world vertices."""
        return piece_vertices(merge_adjacent(self.kept_boxes[self.kept_residue == unseen]), self.stack)

    def drawn_pieces(self, unseen: bool = False) -> ArrayF64:
        """(D, 8, 3) the merged kept pieces (:meth:`merged_pieces`) that add to the static
        region's drawing: not those whose corners (moved 2 % toward the piece's centre, off
        the surfaces pieces end on) all lie in C_static."""
        pieces = self.merged_pieces(unseen)
        if len(pieces) == 0:
            return pieces
        centre = pieces.mean(axis=1, keepdims=True)
        corners = centre + 0.98 * (pieces - centre)
        inside = self.static.hull_contains(corners.reshape(-1, 3), self.k_of_n).reshape(-1, 8).all(axis=1)
        return pieces[~inside]

    def unseen_drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """Triangles of the kept small gaps' residue (see :meth:`Verdict.region_unseen_drawing`)."""
        return hexahedra_triangles(self.drawn_pieces(unseen=True))

    def drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """Triangles of the dynamic region without its union and without the small gaps'
        residue (see :meth:`Verdict.region_dynamic_drawing`)."""
        pieces = self.drawn_pieces()
        pv, faces = hexahedra_triangles(pieces)
        sheets = self.get("sheets_added").to_mesh64()
        props = np.asarray(sheets.vert_properties, dtype=np.float64)
        sv = props.reshape(len(props), -1)[:, :3] if props.size else np.zeros((0, 3))
        sf = np.asarray(sheets.tri_verts, dtype=np.int64).reshape(-1, 3)
        return np.concatenate([pv, sv]), np.concatenate([faces, sf + len(pv)])

    def _build(self, name: str) -> m3.Manifold:
        s = self.static
        if name == "dynamic_sheets":
            # The sheet boxes are supersets of the static sheet they stand for: as a
            # manifold, only their part in R2_static (the removed sheet) is shown.
            return self.get("sheet_boxes") ^ s.region_r2
        if name == "sheet_boxes":
            return hexahedra_manifold(self.sheet_boxes)
        if name == "sheets_added":
            # what they add to R3_static: (H ^ R2_static) - R3_static = H ^ (R2_static -
            # R3_static), the static part built once (a boolean of the boxes with the whole
            # static region took about 1 s a call)
            return self.get("sheet_boxes") ^ s.region_removed
        if name == "region_dynamic":
            pieces = pieces_manifold(self.merged_boxes, self.stack) ^ self.zone
            return check_manifold(pieces + self.get("dynamic_sheets"), "dynamic region")
        if name == "region":
            return check_manifold(s.region + self.get("region_dynamic"), "region R3")
        if name == "region_r2":
            dyn = pieces_manifold(self.piece_set.boxes, self.stack) ^ self.zone
            return check_manifold((s.region_r2 + dyn) - s.solids - self.robot_body(), "region R2")
        if name == "hull":
            return check_manifold(s.hull + (pieces_manifold(self.full_pieces().boxes, self.stack) ^ self.zone), "hull C")
        if name == "robot_occlusion":
            return self.occlusion()
        raise KeyError(name)


@dataclass(frozen=True, eq=False)
class Verdict:
    """The answer of one cycle.

    Attributes:
        stamp: Cycle time [s].
        q: Joint positions used [rad] (empty when the joint state was unusable).
        removed: Components removed by the plausibility rules, each with its rule (the
            static ones, judged once, then this cycle's).
        min_distance: Minimum distance between the region and the robot [m] (inf: none).
        closest_points: (2, 3) closest points [m] (on the region, on the robot) or None.
        closest_link: Name of the closest robot link, or None.
        speed_scale: Allowed share of the robot's maximum speed in [0, 1]; 0 means stop.
        allowed_speed: Allowed robot speed [m/s].
        separation_distance: Protective separation distance S_p [m] at that speed.
        faults: Latched faults; non-empty means stop.
        warnings: Conditions reported without stopping (e.g. cycle over its deadline).
        timings: Duration of each stage and ``total`` [ms].
        counts: Per-cycle sizes: unexplained pixels, initial and kept pieces.

    The regions (``hull``, ``robot_occlusion``, ``region_r2``, ``region``,
    ``region_dynamic``) are manifold3d Manifolds built when first read.
    """

    stamp: float
    q: ArrayF64
    removed: tuple[RemovedComponent, ...]
    min_distance: float
    closest_points: ArrayF64 | None
    closest_link: str | None
    speed_scale: float
    allowed_speed: float
    separation_distance: float
    faults: tuple[str, ...]
    warnings: tuple[str, ...]
    timings: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    _geometry: CycleGeometry | None = field(default=None, repr=False)
    _fallback: m3.Manifold | None = field(default=None, repr=False)

    def _region(self, name: str) -> m3.Manifold:
        if self._geometry is None:
            if name in ("robot_occlusion", "region_dynamic"):
                return m3.Manifold()
            return self._fallback if self._fallback is not None else m3.Manifold()
        return self._geometry.get(name)

    @property
    def hull(self) -> m3.Manifold:
        """The depth hull C = R1 (world frame)."""
        return self._region("hull")

    @property
    def robot_occlusion(self) -> m3.Manifold:
        """The robot occlusion M of the padded robot."""
        return self._region("robot_occlusion")

    @property
    def region_r2(self) -> m3.Manifold:
        """R2 = C minus M (with shadow memory), the static solids and the robot."""
        return self._region("region_r2")

    @property
    def region(self) -> m3.Manifold:
        """R3, what the distance is measured to."""
        return self._region("region")

    @property
    def region_dynamic(self) -> m3.Manifold:
        """This cycle's part of R3: the kept dynamic pieces and the sheets under them."""
        return self._region("region_dynamic")

    def region_dynamic_drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """What this cycle adds to the static region, as triangles to draw fast: (V, 3)
        vertices [m] and (F, 3) vertex indices. For viewers, which draw the static region
        once: :attr:`region_dynamic` minus the static region, but without the union of the
        pieces (thousands near the robot: 1 to 2 s for a contact cycle of the paper cell;
        these triangles take a fraction of a second: the sheets' part is one boolean of
        their boxes with what the static rules removed, built once per monitor). The kept
        pieces' hexahedra as they are (merged siblings; their interiors may overlap, so
        some faces lie inside), less those lying wholly in the
        static hull C_static, then the sheets' exact part outside the static region. A
        drawing, not a set: a piece partly in the static region is drawn whole, and one
        wholly in C_static where the static rules removed a noise sheet is not drawn (the
        sheet kept under it is). The pieces made only of a small gap's far part are drawn
        apart (:meth:`region_unseen_drawing`); together the two are the drawing of
        :attr:`region_dynamic`. Empty without geometry (a stop verdict)."""
        if self._geometry is None:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        return self._geometry.drawing()

    def region_unseen_drawing(self) -> tuple[ArrayF64, np.ndarray]:
        """The kept pieces that hold no reading, as triangles (as
        :meth:`region_dynamic_drawing`): the far part of a dropout patch's rays (or of
        out-of-range pixels), where an object of ``plausibility.detection_size`` may hide
        unseen by that camera (the small_gaps rule freed the rest). For viewers, to tell
        them from what a camera saw. Empty without geometry."""
        if self._geometry is None:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        return self._geometry.unseen_drawing()

    @property
    def region_r1(self) -> m3.Manifold:
        """R1 = C, the paper's first approximation."""
        return self.hull

    def volumes(self) -> dict[str, float]:
        """Volumes [m^3] of C, M, R1, R2, R3 and the dynamic part (builds the manifolds)."""
        hull = self.hull.volume()
        return {
            "volume_hull": hull,
            "volume_robot_occlusion": self.robot_occlusion.volume(),
            "volume_r1": hull,
            "volume_r2": self.region_r2.volume(),
            "volume_region": self.region.volume(),
            "volume_region_dynamic": self.region_dynamic.volume(),
        }

    def to_json(self) -> dict[str, Any]:
        """The JSON object of ``polyhull run --json``."""
        out: dict[str, Any] = dict(self.volumes())
        out.update(
            {
                "min_distance": self.min_distance if math.isfinite(self.min_distance) else None,
                "closest_link": self.closest_link,
                "closest_points": None if self.closest_points is None else self.closest_points.tolist(),
                "speed_scale": self.speed_scale,
                "allowed_speed": self.allowed_speed,
                "separation_distance": self.separation_distance
                if math.isfinite(self.separation_distance)
                else None,
                "faults": list(self.faults),
                "warnings": list(self.warnings),
                "removed": [
                    {"rule": r.rule, "volume": r.volume, "centroid": np.asarray(r.centroid).tolist()}
                    for r in self.removed
                ],
                "counts": dict(self.counts),
                "timings_ms": dict(self.timings),
                "stamp": self.stamp,
            }
        )
        return out


@dataclass(frozen=True, eq=False)
class CycleImages:
    """One cycle's per-camera images (inspection, tests, the bench's oracles).

    Attributes:
        free: Camera name -> (H, W) engine free depth [m].
        end: Camera name -> (H, W) end of each pixel's segment [m].
        raster: Camera name -> the padded robot's raster.

    The images are the monitor's buffers, reused by a later cycle only once this object is
    gone (the free-depth and end images also wait for the cycle's verdict).
    """

    free: dict[str, np.ndarray]
    end: dict[str, np.ndarray]
    raster: dict[str, RobotRaster]
    # holds the images and rasters (see :class:`polyhull.engine.buffers.Pool`)
    _lease: object = field(default=None, repr=False)


def pieces_removed(rule: str, pieces: PieceSet, stack: CameraStack) -> RemovedComponent:
    """One removed component made of ``pieces`` (its mesh built when read)."""
    vols = piece_volumes(pieces.boxes, stack)
    centres = 0.5 * np.add(*vertex_bounds(pieces.vertices))
    centroid = (centres * vols[:, None]).sum(axis=0) / max(float(vols.sum()), 1e-12)
    b = pieces.boxes
    return RemovedComponent(
        rule, float(vols.sum()), centroid, LazyMesh(lambda idx: pieces_manifold(b[idx], stack), np.arange(len(b)), pieces.vertices)
    )


def gaps_removed(boxes: ArrayF64, verts: ArrayF64, stack: CameraStack) -> tuple[RemovedComponent, ...]:
    """The pixel segments (boxes (N, 7), vertices (N, 8, 3)) the small_gaps rule freed this
    cycle, as one reported removal (they are part of R2, before the rules)."""
    return (pieces_removed("small_gaps", PieceSet(boxes, verts), stack),) if len(boxes) else ()
