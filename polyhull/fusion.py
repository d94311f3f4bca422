"""Fusion of camera regions into the depth hull C (SPEC section 2, paper 3.2 and 4).

``C = Z \\ F`` with ``F = union_i F(i)``; with the k-of-n rule a point is free only if at
least k cameras see it free, i.e. ``F_k = union over k-subsets S of intersection_{i in S} F(i)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

import manifold3d as m3

from .regions import check_manifold

__all__ = ["clip_to_box", "free_union", "depth_hull"]


def free_union(free_regions: Sequence[m3.Manifold], k: int = 1) -> m3.Manifold:
    """Points free for at least ``k`` of the given per-camera free regions.

    Args:
        free_regions: F(i) per camera, world frame.
        k: The k of the k-of-n rule (1: plain union).

    Returns:
        The fused target-free region F (empty when fewer than k regions are given).
    """
    regions = [f for f in free_regions if not f.is_empty()]
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    if len(regions) < k:
        return m3.Manifold()
    if k == 1:
        return m3.Manifold.batch_boolean(regions, m3.OpType.Add)
    parts = [m3.Manifold.batch_boolean(list(s), m3.OpType.Intersect) for s in combinations(regions, k)]
    return m3.Manifold.batch_boolean(parts, m3.OpType.Add)


def clip_to_box(
    regions: Sequence[m3.Manifold], zone: m3.Manifold, margin: float = 0.01
) -> list[m3.Manifold]:
    """Each region intersected with the bounding box of ``zone`` grown by ``margin`` [m].

    Exact inside the zone: a point of Z is in ``F(i) & box`` iff it is in ``F(i)``. The
    part of a camera's region beyond the zone only costs boolean work, since a frustum
    reaches past the walls of the cell.
    """
    bb = zone.bounding_box()
    lo = [float(x) - margin for x in bb[:3]]
    hi = [float(x) + margin for x in bb[3:]]
    box = m3.Manifold.cube([b - a for a, b in zip(lo, hi, strict=True)]).translate(lo)
    return [f if f.is_empty() else f ^ box for f in regions]


def depth_hull(zone: m3.Manifold, free_regions: Sequence[m3.Manifold], k: int = 1) -> m3.Manifold:
    """The depth hull ``C = Z \\ F`` (k-of-n rule for F), a checked manifold.

    The regions are first clipped to the zone's bounding box (:func:`clip_to_box`), which
    leaves C unchanged and saves about a fifth of the fusion time on the paper cell.
    """
    regions = [f for f in clip_to_box(free_regions, zone) if not f.is_empty()]
    if k == 1:
        hull = m3.Manifold.batch_boolean([zone, *regions], m3.OpType.Subtract)
    else:
        hull = zone - free_union(regions, k)
    return check_manifold(hull, "depth hull C")
