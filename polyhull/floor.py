"""The floor-shell rule: depth noise above the floor is not a person unless something stands on it.

Every camera leaves a band of roughly ``2 tau`` above the floor unfree (its free depth stops
short of the floor by the depth tolerance), so R2 always holds a thin sheet over the whole
floor. That sheet is what SPEC rule 3 ("too thin: lies inside a shell around known objects,
where sensor noise creates slivers") describes, with the floor as the known object; but it
touches everything standing on the floor, so a rule over whole components cannot remove it.

This rule works below a plane at ``height`` above the floor: the part of R2 under the plane
is kept only within ``margin`` (horizontally) of the slice, at that plane, of everything
possibly occupied (the hull C, which also holds what the robot hides). A person
standing, walking or crouching crosses the plane with their legs, and their feet lie within
``margin`` of the legs' cross-section, so every part of them is kept. The assumption, stated:
no person lies flat with a body thinner than ``height``.
"""

from __future__ import annotations

import manifold3d as m3

from .cell import Zone
from .regions import check_manifold

__all__ = ["floor_shell"]


def floor_shell(
    region: m3.Manifold,
    occupied: m3.Manifold,
    zone: Zone,
    height: float,
    margin: float,
    not_people: m3.Manifold | None = None,
) -> tuple[m3.Manifold, m3.Manifold]:
    """Remove the floor noise sheet from ``region``.

    Args:
        region: R2 (world frame).
        occupied: Everything possibly occupied (the hull C), a superset of ``region``: a
            person whose legs the robot hides still keeps their feet.
        zone: The zone; its min z is the floor.
        height: Height [m] of the shell above the floor (above the noise band).
        margin: Horizontal distance [m] around the slice at ``height`` that is kept below it.
        not_people: What stands on the floor but is no person (the robot body, solid
            obstacles): its cross-section does not keep the noise around it.

    Returns:
        (kept region, removed part); the removed part is empty when nothing was removed.
    """
    if region.is_empty() or height <= 0:
        return region, m3.Manifold()
    floor = zone.floor_z
    lo, hi = zone.min, zone.max
    shell = m3.Manifold.cube((hi[0] - lo[0] + 2.0, hi[1] - lo[1] + 2.0, height)).translate(
        (lo[0] - 1.0, lo[1] - 1.0, floor - 1e-6)
    )
    section = occupied.slice(floor + height)
    if not_people is not None and not not_people.is_empty():
        section = section - not_people.slice(floor + height)
    keep_zone = shell
    if not section.is_empty():
        grown = section.offset(margin, m3.JoinType.Round) if margin > 0 else section
        prism = m3.Manifold.extrude(grown, height + 2e-6).translate((0.0, 0.0, floor - 1e-6))
        keep_zone = shell - prism
    removed = region ^ keep_zone
    if removed.is_empty():
        return region, removed
    kept = region - keep_zone
    return check_manifold(kept, "region after the floor-shell rule"), removed
