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

__all__ = ["CycleImages", "Verdict", "gaps_removed", "hexahedra_manifold", "pieces_removed"]


def hexahedra_manifold(vertices: ArrayF64) -> m3.Manifold:
    """The union of convex hexahedra (N, 8, 3) as one manifold."""
    hulls = [m3.Manifold.hull_points(v) for v in vertices]
    hulls = [h for h in hulls if not h.is_empty()]
    if not hulls:
        return m3.Manifold()
    return check_manifold(m3.Manifold.batch_boolean(hulls, m3.OpType.Add), "dynamic region")


@dataclass(eq=False)
class CycleGeometry:
    """What a verdict needs to build its manifolds when they are read."""

    static: StaticModel
    zone: m3.Manifold
    pieces_parts: tuple[ArrayF64, ...]  # (N_i, 8, 3) all dynamic pieces before the rules (with memory)
    kept_pieces: ArrayF64  # (K, 8, 3) kept dynamic pieces
    kept_boxes: ArrayF64  # (K, 7) the same in their cameras' image space
    stack: CameraStack  # the cameras, for the pieces' vertices
    sheet_boxes: ArrayF64  # (S, 8, 3) the sheet boxes under them
    robot_body: Callable[[], m3.Manifold]
    occlusion: Callable[[], m3.Manifold]
    full_pieces: Callable[[], ArrayF64]
    lease: object = None  # holds the cycle's images (see :class:`polyhull.engine.buffers.Pool`)
    cache: dict[str, m3.Manifold] = field(default_factory=dict)

    @functools.cached_property
    def pieces(self) -> ArrayF64:
        """(N, 8, 3) all dynamic pieces before the rules (with the memory's)."""
        return np.concatenate(self.pieces_parts)

    @functools.cached_property
    def kept(self) -> ArrayF64:
        """(K, 8, 3) the kept dynamic pieces, then the sheet boxes."""
        return np.concatenate([self.kept_pieces, self.sheet_boxes])

    def get(self, name: str) -> m3.Manifold:
        if name not in self.cache:
            self.cache[name] = self._build(name)
        return self.cache[name]

    def _build(self, name: str) -> m3.Manifold:
        s = self.static
        if name == "region_dynamic":
            # The sheet boxes are supersets of the static sheet they stand for: as a
            # manifold, only their part in R2_static (the removed sheet) is shown.
            # (the same union from a third as many pieces: siblings merged back)
            pieces = hexahedra_manifold(piece_vertices(merge_adjacent(self.kept_boxes), self.stack)) ^ self.zone
            sheets = hexahedra_manifold(self.sheet_boxes) ^ s.region_r2
            return check_manifold(pieces + sheets, "dynamic region")
        if name == "region":
            return check_manifold(s.region + self.get("region_dynamic"), "region R3")
        if name == "region_r2":
            dyn = hexahedra_manifold(self.pieces) ^ self.zone
            return check_manifold((s.region_r2 + dyn) - s.solids - self.robot_body(), "region R2")
        if name == "hull":
            return check_manifold(s.hull + (hexahedra_manifold(self.full_pieces()) ^ self.zone), "hull C")
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
        """The JSON object of ``polyhull run --json`` (SPEC section 6)."""
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
    return RemovedComponent(rule, float(vols.sum()), centroid, LazyMesh(hexahedra_manifold, pieces.vertices))


def gaps_removed(boxes: ArrayF64, verts: ArrayF64, stack: CameraStack) -> tuple[RemovedComponent, ...]:
    """The pixel segments (boxes (N, 7), vertices (N, 8, 3)) the small_gaps rule freed this
    cycle, as one reported removal (they are part of R2, before the rules)."""
    return (pieces_removed("small_gaps", PieceSet(boxes, verts), stack),) if len(boxes) else ()
