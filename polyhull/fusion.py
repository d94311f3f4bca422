"""Fusion of camera free regions (paper 3.2 and 4): the static hull and placement.

``C = Z \\ F`` with ``F = union_i F(i)``; with the k-of-n rule a point is free only if at
least k cameras see it free, i.e. ``F_k = union over k-subsets S of intersection_{i in S} F(i)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

import manifold3d as m3

__all__ = ["free_union"]


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
