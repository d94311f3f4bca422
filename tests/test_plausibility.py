"""Tests of the plausibility rules (R2 -> R3) on hand-made components."""

from __future__ import annotations

import dataclasses

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from polyhull import plausibility as pl
from polyhull.cell import EntryArea, PlausibilityParams, Zone
from polyhull.errors import PolyhullError
from polyhull.plausibility import (
    RULE_ORDER,
    PlausibilityContext,
    apply_plausibility,
    components,
    is_flying,
    is_teleport,
    is_too_small,
    is_too_thin,
    is_unconnected_to_entry,
    mesh_volume_centroid,
    touches_boundary,
)

ZONE = Zone((0.0, 0.0, 0.0), (6.0, 6.0, 3.5))
TABLE_LO, TABLE_HI = (1.0, 1.0, 0.0), (2.0, 2.0, 0.8)


def box(lo, hi) -> m3.Manifold:
    lo = np.asarray(lo, dtype=float)
    return m3.Manifold.cube(tuple(np.subtract(hi, lo))).translate(tuple(lo))


TABLE = box(TABLE_LO, TABLE_HI)


def ctx_for(**kw) -> PlausibilityContext:
    params = kw.pop("params", PlausibilityParams())
    kw.setdefault("support", TABLE)
    kw.setdefault("known_objects", (TABLE,))
    return PlausibilityContext(ZONE, params, **kw)


def union(*parts: m3.Manifold) -> m3.Manifold:
    return m3.Manifold.batch_boolean(list(parts), m3.OpType.Add)


@dataclasses.dataclass(frozen=True)
class _ParamsNoBoundaryKeep(PlausibilityParams):
    """Params with the proposed ``keep_at_boundary`` switch turned off."""

    keep_at_boundary: bool = False


# ----------------------------------------------------------------------------- flying


def test_component_on_floor_is_not_flying() -> None:
    assert not is_flying(box((3, 3, 0), (3.4, 3.3, 1.8)), ctx_for())


@pytest.mark.parametrize(
    ("gap", "flying"), [(0.0, False), (0.03, False), (0.049, False), (0.06, True), (0.5, True)]
)
def test_flying_above_floor(gap: float, flying: bool) -> None:
    assert is_flying(box((3, 3, gap), (3.3, 3.3, gap + 0.3)), ctx_for()) is flying


@pytest.mark.parametrize(
    ("gap", "flying"), [(0.0, False), (0.02, False), (0.049, False), (0.055, True), (0.3, True)]
)
def test_flying_above_table_top(gap: float, flying: bool) -> None:
    z = TABLE_HI[2] + gap
    assert is_flying(box((1.2, 1.2, z), (1.5, 1.5, z + 0.3)), ctx_for()) is flying


def test_support_counts_only_in_the_direction_of_gravity() -> None:
    # 2 cm beside the table at table height: close, but nothing below it.
    beside = box((2.02, 1.2, 0.5), (2.3, 1.5, 0.79))
    assert is_flying(beside, ctx_for())
    # Just under the table top region but overhanging the edge by 5 cm, 2 cm above the top.
    overhang = box((1.95, 1.2, 0.82), (2.4, 1.5, 1.0))
    assert not is_flying(overhang, ctx_for())
    # A blob under a shelf (support above it) is flying.
    shelf = box((3, 3, 1.0), (4, 4, 1.05))
    under = box((3.2, 3.2, 0.6), (3.5, 3.5, 0.98))
    assert is_flying(under, ctx_for(support=shelf, known_objects=(shelf,)))


def test_non_convex_component_supported_by_a_leg() -> None:
    # An arch whose only foot is 3 cm above the table top, far from its big top part.
    arch = union(box((1.4, 1.4, 0.83), (1.5, 1.5, 1.5)), box((1.4, 1.4, 1.5), (3.5, 1.5, 1.6)))
    assert not is_flying(arch, ctx_for())
    assert is_flying(arch.translate((0, 0, 0.04)), ctx_for())


def test_flying_with_empty_support() -> None:
    ctx = ctx_for(support=m3.Manifold(), known_objects=())
    assert is_flying(box((1.2, 1.2, 0.8), (1.5, 1.5, 1.1)), ctx)
    assert not is_flying(box((1.2, 1.2, 0.0), (1.5, 1.5, 1.1)), ctx)


def test_occlusion_below_counts_as_support() -> None:
    occlusion = box((3, 3, 0), (4, 4, 1.0))  # the robot's shadow, a person's legs in it
    torso = box((3.2, 3.2, 1.0), (3.6, 3.5, 1.8))
    assert is_flying(torso, ctx_for())
    assert not is_flying(torso, ctx_for(occlusion=occlusion))
    # Occlusion only beside the blob does not hold it up.
    side = box((3.62, 3.2, 1.0), (3.9, 3.5, 1.8))
    assert is_flying(side.translate((0.4, 0, 0.01)), ctx_for(occlusion=occlusion))


def test_flying_spares_components_at_the_boundary() -> None:
    arm = box((0.0, 3.0, 1.2), (0.5, 3.1, 1.3))  # reaching in through the x = 0 wall
    assert not is_flying(arm, ctx_for())
    assert is_flying(arm, ctx_for(params=_ParamsNoBoundaryKeep()))
    assert is_flying(arm.translate((0.2, 0, 0)), ctx_for())


# ----------------------------------------------------------------------------- too small


def test_too_small() -> None:
    ctx = ctx_for()  # min_volume 1e-3 m^3
    assert is_too_small(box((3, 3, 0), (3.05, 3.05, 0.05)), ctx)
    assert is_too_small(box((3, 3, 0), (3.099, 3.1, 0.1)), ctx)
    assert not is_too_small(box((3, 3, 0), (3.101, 3.1, 0.1)), ctx)
    fingertip = box((5.98, 3, 1.0), (6.0, 3.02, 1.02))
    assert not is_too_small(fingertip, ctx)
    assert is_too_small(fingertip, ctx_for(params=_ParamsNoBoundaryKeep()))


# ----------------------------------------------------------------------------- too thin


def test_thin_slab_on_table_is_too_thin() -> None:
    ctx = ctx_for()  # shell 4 cm
    assert is_too_thin(box((1.1, 1.1, 0.8), (1.9, 1.9, 0.82)), ctx)
    assert is_too_thin(box((1.1, 1.1, 0.8), (1.9, 1.9, 0.839)), ctx)
    assert not is_too_thin(box((1.1, 1.1, 0.8), (1.9, 1.9, 0.845)), ctx)
    # Leaving the shell sideways: past the table's edge by more than the shell.
    assert not is_too_thin(box((1.1, 1.1, 0.8), (2.1, 1.9, 0.82)), ctx)
    # A sliver along the table's side.
    assert is_too_thin(box((2.0, 1.2, 0.1), (2.03, 1.8, 0.7)), ctx)
    assert not is_too_thin(box((2.0, 1.2, 0.1), (2.05, 1.8, 0.7)), ctx)


def test_too_thin_wraps_around_a_floating_object() -> None:
    link = box((3.0, 3.0, 1.0), (3.6, 3.2, 1.2))
    halo = box((2.98, 2.98, 0.98), (3.62, 3.22, 1.22)) - link
    ctx = ctx_for(known_objects=(TABLE, link))
    assert is_too_thin(halo, ctx)
    assert not is_too_thin(halo, ctx_for())  # the link is not a known object


def test_too_thin_with_non_convex_known_object() -> None:
    ell = union(box((3, 3, 0), (4, 3.3, 1)), box((3, 3, 0), (3.3, 4, 1)))
    sliver = box((3.3, 3.3, 0.2), (3.33, 3.9, 0.8))  # in the inner corner, along one arm
    ctx = ctx_for(support=ell, known_objects=(ell,))
    assert is_too_thin(sliver, ctx)
    assert not is_too_thin(box((3.3, 3.3, 0.2), (3.6, 3.9, 0.8)), ctx)


def test_too_thin_spares_the_inside_of_non_solid_objects() -> None:
    zone_obj = box((3, 3, 0), (4, 4, 2))  # non-solid: a person may be inside it
    inside = box((3.5, 3.5, 0.0), (3.52, 3.9, 1.5))
    assert not is_too_thin(inside, ctx_for(known_objects=(zone_obj,)))


def test_too_thin_off_without_known_objects_or_shell() -> None:
    slab = box((1.1, 1.1, 0.8), (1.9, 1.9, 0.82))
    assert not is_too_thin(slab, ctx_for(known_objects=()))
    assert not is_too_thin(slab, ctx_for(params=PlausibilityParams(shell_thickness=0.0)))


def _dist_to_box(points: np.ndarray, lo, hi) -> np.ndarray:
    d = np.maximum(0.0, np.maximum(np.asarray(lo) - points, points - np.asarray(hi)))
    return np.linalg.norm(d, axis=1)


@settings(max_examples=40, deadline=None)
@given(
    lo=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    size=st.tuples(*[st.floats(0.01, 1.0)] * 3),
    size2=st.tuples(*[st.floats(0.01, 1.0)] * 3),
    s=st.floats(0.001, 0.2),
    yaw=st.floats(0.0, np.pi),
)
def test_grown_objects_never_exceed_the_shell(lo, size, size2, s, yaw) -> None:
    """The grown object lies within s of the object: the rule can only fire less often."""
    lo = np.asarray(lo)
    hi = lo + np.asarray(size)
    convex = box(lo, hi)
    grown = pl._grow(convex, s)
    v = np.asarray(grown.solid.to_mesh64().vert_properties)[:, :3]
    assert np.all(_dist_to_box(v, lo, hi) <= s * (1 + 1e-6) + 1e-9)
    assert grown.planes is not None
    # Non-convex: two boxes in an L; distance to the union is the min over the boxes.
    lo2 = lo.copy()
    hi2 = lo2 + np.asarray(size2) + np.array([0.0, 0.0, 0.0])
    lo2[0] = hi[0] - 0.005
    hi2[0] = lo2[0] + size2[0] + 0.01
    ell = union(convex, box(lo2, hi2))
    grown2 = pl._grow(ell, s)
    v2 = np.asarray(grown2.solid.to_mesh64().vert_properties)[:, :3]
    d = np.minimum(_dist_to_box(v2, lo, hi), _dist_to_box(v2, lo2, hi2))
    assert np.all(d <= s * (1 + 1e-6) + 1e-9)
    # A rotated convex object still grows by at most s (checked against its hull planes).
    rotated = convex.rotate((0.0, 0.0, float(np.degrees(yaw))))
    grown3 = pl._grow(rotated, s)
    v3 = np.asarray(grown3.solid.to_mesh64().vert_properties)[:, :3]
    tri = trimesh.Trimesh(
        np.asarray(rotated.to_mesh64().vert_properties)[:, :3],
        np.asarray(rotated.to_mesh64().tri_verts),
    )
    _, dist, _ = trimesh.proximity.closest_point(tri, v3)
    assert np.all(dist <= s * (1 + 1e-6) + 1e-9)


def test_grown_convex_object_is_tight() -> None:
    """The inscribed polytope grows a box face by exactly s and its edges by > 0.9 s."""
    s = 0.04
    grown = pl._grow(TABLE, s)
    lo, hi = np.asarray(grown.solid.bounding_box()).reshape(2, 3)
    assert np.allclose(lo, np.asarray(TABLE_LO) - s, atol=1e-9)
    assert np.allclose(hi, np.asarray(TABLE_HI) + s, atol=1e-9)
    exact_volume = 0.8 + 2 * s * (1.0 + 0.8 + 0.8) + np.pi * s**2 * (1 + 1 + 0.8) + 4 / 3 * np.pi * s**3
    assert 0.97 * exact_volume < grown.solid.volume() <= exact_volume


# ----------------------------------------------------------------------------- entry


def test_entry_needs_history() -> None:
    far = box((3, 3, 0), (3.4, 3.3, 1.8))
    params = PlausibilityParams(entry=True, teleport=True)
    assert not is_unconnected_to_entry(far, ctx_for(params=params))
    assert not is_unconnected_to_entry(far, ctx_for(params=params, previous=(), dt=None))
    assert not is_teleport(far, ctx_for(params=params))
    assert not is_teleport(far, ctx_for(params=params, previous=(), dt=None))
    result = apply_plausibility(far, ctx_for(params=params))
    assert result.removed == ()
    assert result.region is far


def test_entry_rule() -> None:
    params = PlausibilityParams(entry=True)  # v_max 2 m/s, eps 5 cm
    person_before = box((3, 3, 0), (3.4, 3.3, 1.8))
    ctx = ctx_for(params=params, previous=(person_before,), dt=0.1)  # reach 0.25 m
    assert not is_unconnected_to_entry(person_before.translate((0.1, 0, 0)), ctx)
    assert not is_unconnected_to_entry(box((3.64, 3, 0), (3.8, 3.3, 1.8)), ctx)
    assert is_unconnected_to_entry(box((3.66, 3, 0), (3.8, 3.3, 1.8)), ctx)
    # Touching a wall, or the ceiling, within eps: may come from outside.
    assert not is_unconnected_to_entry(box((0.04, 1, 0), (0.4, 1.3, 1.8)), ctx)
    assert is_unconnected_to_entry(box((0.06, 1, 0), (0.4, 1.3, 1.8)), ctx)
    assert not is_unconnected_to_entry(box((4, 1, 3.0), (4.2, 1.3, 3.46)), ctx)
    # The floor is not an entry.
    assert touches_boundary(box((3, 3, 0), (3.4, 3.3, 1.8)), ZONE, 0.05) is False


def test_entry_areas_and_occlusion() -> None:
    door = EntryArea("door", (4.0, 4.0, 0.0), (5.0, 5.0, 2.0))
    params = PlausibilityParams(entry=True, teleport=True, entry_areas=(door,))
    ctx = ctx_for(params=params, previous=(), dt=0.05)
    in_door = box((4.2, 4.2, 0), (4.6, 4.5, 1.8))
    near_door = box((4.2, 3.6, 0), (4.6, 3.97, 1.8))
    away = box((4.2, 3.0, 0), (4.6, 3.3, 1.8))
    for rule in (is_unconnected_to_entry, is_teleport):
        assert not rule(in_door, ctx)
        assert not rule(near_door, ctx)
        assert rule(away, ctx)
        # Out of the robot's shadow: the person may have hidden in it.
        shadow = box((4.6, 2.5, 0), (5.0, 3.5, 1.5))
        assert not rule(away, dataclasses.replace(ctx, occlusion=shadow))


def test_entry_non_convex_component_near_entry_area_bbox_only() -> None:
    door = EntryArea("door", (4.0, 4.0, 0.0), (5.0, 5.0, 2.0))
    params = PlausibilityParams(entry=True, entry_areas=(door,))
    ctx = ctx_for(params=params, previous=(), dt=0.05)
    # An L whose bounding box covers the door but which stays 20 cm from it.
    ell = union(box((3.0, 3.0, 0), (3.8, 3.2, 1)), box((3.6, 3.0, 0), (3.8, 5.5, 1)))
    assert is_unconnected_to_entry(ell, ctx)


# ----------------------------------------------------------------------------- teleport


def test_teleport_rule() -> None:
    params = PlausibilityParams(teleport=True)
    before = box((3, 3, 0), (3.4, 3.3, 1.8))
    ctx = ctx_for(params=params, previous=(before,), dt=0.1)  # reach 0.2 m
    assert not is_teleport(before.translate((0.3, 0, 0)), ctx)  # overlaps
    assert not is_teleport(box((3.59, 3, 0), (3.9, 3.3, 1.8)), ctx)
    assert is_teleport(box((3.61, 3, 0), (3.9, 3.3, 1.8)), ctx)
    # Nobody was there: a component in the middle teleported, one at a wall entered.
    empty = dataclasses.replace(ctx, previous=())
    assert is_teleport(before, empty)
    assert not is_teleport(box((5.7, 3, 0), (5.99, 3.3, 1.8)), empty)
    # dt = 0: only what touches the previous region is continuous.
    zero = dataclasses.replace(ctx, dt=0.0)
    assert not is_teleport(box((3.4, 3, 0), (3.6, 3.3, 1.8)), zero)
    assert is_teleport(box((3.41, 3, 0), (3.6, 3.3, 1.8)), zero)


def test_teleport_nested_previous() -> None:
    params = PlausibilityParams(teleport=True)
    big = box((2, 2, 0), (4, 4, 2))
    ctx = ctx_for(params=params, previous=(big,), dt=0.0)
    assert not is_teleport(box((2.8, 2.8, 0.0), (3.2, 3.2, 1.0)), ctx)  # shrank inside


def test_bad_dt_rejected() -> None:
    with pytest.raises(PolyhullError, match="dt"):
        ctx_for(dt=-0.1)
    with pytest.raises(PolyhullError, match="dt"):
        ctx_for(dt=float("nan"))


# ----------------------------------------------------------------------------- apply


def _scene() -> tuple[m3.Manifold, dict[str, m3.Manifold]]:
    parts = {
        "person": box((3, 3, 0), (3.4, 3.3, 1.8)),
        "on_table": box((1.2, 1.2, 0.8), (1.5, 1.5, 1.1)),
        "flying": box((4.5, 1.0, 1.0), (4.8, 1.3, 1.3)),
        "too_small": box((5.0, 4.0, 0.0), (5.05, 4.05, 0.05)),
        "too_thin": box((1.6, 1.1, 0.8), (1.9, 1.9, 0.82)),
        "far": box((4.5, 4.5, 0.0), (4.9, 4.8, 1.7)),
    }
    return union(*parts.values()), parts


def test_apply_reports_rule_volume_centroid() -> None:
    r2, parts = _scene()
    before = box((3, 3, 0), (3.4, 3.3, 1.8)).translate((-0.1, 0, 0))
    params = PlausibilityParams(entry=True, teleport=True)
    result = apply_plausibility(
        r2, ctx_for(params=params, previous=(before, parts["on_table"]), dt=0.05)
    )
    by_rule = {r.rule: r for r in result.removed}
    assert sorted(by_rule) == ["entry", "flying", "too_small", "too_thin"]
    for rule, removed in by_rule.items():
        expect = parts[rule if rule != "entry" else "far"]
        lo, hi = np.asarray(expect.bounding_box()).reshape(2, 3)
        assert removed.volume == pytest.approx(np.prod(hi - lo), rel=1e-9)
        np.testing.assert_allclose(removed.centroid, (lo + hi) / 2, atol=1e-9)
        assert removed.mesh.volume() == pytest.approx(removed.volume, rel=1e-9)
    assert len(result.kept) == 2
    kept_volume = 0.4 * 0.3 * 1.8 + 0.3 * 0.3 * 0.3
    assert result.region.volume() == pytest.approx(kept_volume, rel=1e-9)
    assert result.region.volume() + result.removed_volume == pytest.approx(r2.volume(), rel=1e-12)


@pytest.mark.parametrize("rule", RULE_ORDER)
def test_each_flag_switches_its_rule_off(rule: str) -> None:
    r2, parts = _scene()
    none = PlausibilityParams(flying=False, too_small=False, too_thin=False)
    only = dataclasses.replace(none, **{rule: True})
    previous = (parts["person"], parts["on_table"])
    on = apply_plausibility(r2, ctx_for(params=only, previous=previous, dt=0.05))
    off = apply_plausibility(r2, ctx_for(params=none, previous=previous, dt=0.05))
    assert {r.rule for r in on.removed} == {rule}
    assert off.removed == () and off.region is r2
    assert on.region.volume() < r2.volume()
    # Everything else on: switching this one off never removes more.
    every = PlausibilityParams(entry=True, teleport=True)
    all_on = apply_plausibility(r2, ctx_for(params=every, previous=previous, dt=0.05))
    all_but = apply_plausibility(
        r2, ctx_for(params=dataclasses.replace(every, **{rule: False}), previous=previous, dt=0.05)
    )
    assert rule not in {r.rule for r in all_but.removed}
    assert all_but.region.volume() >= all_on.region.volume() - 1e-12


def test_all_rules_off_keeps_r2() -> None:
    r2, _ = _scene()
    params = PlausibilityParams(flying=False, too_small=False, too_thin=False)
    result = apply_plausibility(r2, ctx_for(params=params))
    assert result.removed == () and result.region is r2 and len(result.kept) == 6


def test_rule_order_reports_first_rule() -> None:
    # Small and flying: reported as too_small, the first in RULE_ORDER.
    speck = box((4, 4, 2), (4.02, 4.02, 2.02))
    result = apply_plausibility(speck, ctx_for())
    assert [r.rule for r in result.removed] == ["too_small"]
    no_small = PlausibilityParams(too_small=False)
    assert [r.rule for r in apply_plausibility(speck, ctx_for(params=no_small)).removed] == ["flying"]
    assert result.region.is_empty() and result.kept == ()


def test_empty_r2() -> None:
    result = apply_plausibility(m3.Manifold(), ctx_for())
    assert result.region.is_empty() and result.kept == () and result.removed == ()


def test_pieces_touching_along_an_edge_are_one_component() -> None:
    legs = box((3, 3, 0), (3.4, 3.3, 1.0))
    torso = box((3.4, 3.3, 1.0), (3.8, 3.6, 1.8))  # meets the legs along one edge only
    r2 = union(legs, torso)
    assert len(r2.decompose()) == 2
    assert len(components(r2)) == 1
    result = apply_plausibility(r2, ctx_for())
    assert result.removed == ()
    assert result.region.volume() == pytest.approx(r2.volume())
    # Apart by 1 mm, the torso floats.
    r2b = union(legs, torso.translate((0.001, 0, 0)))
    assert [r.rule for r in apply_plausibility(r2b, ctx_for()).removed] == ["flying"]


def test_mesh_volume_centroid_matches_trimesh() -> None:
    shape = union(box((0, 0, 0), (1, 1, 1)), box((0.5, 0.5, 0.5), (2.0, 1.2, 1.3))).translate(
        (100.0, -50.0, 3.0)
    )
    volume, centroid = mesh_volume_centroid(shape)
    mesh = shape.to_mesh64()
    tm = trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))
    assert volume == pytest.approx(tm.volume, rel=1e-9)
    np.testing.assert_allclose(centroid, tm.center_mass, atol=1e-9)
    assert mesh_volume_centroid(m3.Manifold())[0] == 0.0


# ----------------------------------------------------------------------------- properties

person_strategy = st.fixed_dictionaries(
    {
        "x": st.floats(0.0, 1.0),
        "y": st.floats(0.0, 1.0),
        "sx": st.floats(0.3, 0.6),
        "sy": st.floats(0.2, 0.5),
        "sz": st.floats(1.0, 2.0),
        "at_table": st.booleans(),
        "arm": st.booleans(),
        "arm_len": st.floats(0.3, 0.9),
        "arm_z": st.floats(0.8, 1.0),
    }
)


def _person(p: dict) -> m3.Manifold:
    """A standing box person, maybe at the table with an arm reaching over it, minus the table.

    At the table, the body stands against the table's +x side (x in [2.0, 2.3]) and the
    arm (10 cm x 8 cm) reaches over the table top in -x, resting on it or up to 20 cm above.
    """
    size = np.array([p["sx"], p["sy"]])
    if p["at_table"]:
        lo = np.array([2.0 + 0.3 * p["x"], 1.0 + (1.0 - p["sy"]) * p["y"]])
    else:
        lo = np.array(ZONE.min[:2]) + np.array([p["x"], p["y"]]) * (np.array(ZONE.size[:2]) - size)
    body = box((lo[0], lo[1], 0.0), (lo[0] + p["sx"], lo[1] + p["sy"], p["sz"]))
    parts = [body]
    if p["arm"]:
        z0 = min(p["arm_z"], p["sz"] - 0.1)
        if p["at_table"]:
            x0, x1 = lo[0] - p["arm_len"], lo[0] + p["sx"] / 2
        else:
            x0, x1 = lo[0] + p["sx"] / 2, lo[0] + p["sx"] / 2 + p["arm_len"]
        y0 = lo[1] + p["sy"] / 2 - 0.05
        parts.append(box((x0, y0, z0), (x1, y0 + 0.1, z0 + 0.08)))
    person = union(*parts) - TABLE
    return person ^ ZONE.manifold()


noise_strategy = st.lists(
    st.tuples(st.floats(0.2, 5.5), st.floats(0.2, 5.5), st.floats(0.3, 3.0), st.floats(0.01, 0.3)),
    max_size=6,
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(p=person_strategy, noise=noise_strategy, shift=st.tuples(*[st.floats(-1, 1)] * 2),
       all_rules=st.booleans(), history=st.booleans())
def test_person_is_never_removed(p, noise, shift, all_rules, history) -> None:
    person = _person(p)
    blobs = [box((x, y, z), (x + s, y + s, z + s)) for x, y, z, s in noise]
    r2 = union(person, *blobs) ^ ZONE.manifold()
    r2 = r2 - TABLE
    params = PlausibilityParams(entry=all_rules, teleport=all_rules)
    dt = 0.05
    previous = None
    if history:
        # Last cycle the person stood at most v_max * dt away.
        d = np.asarray(shift) / max(1.0, float(np.linalg.norm(shift))) * params.human_speed_max * dt
        previous = (person.translate((float(d[0]), float(d[1]), 0.0)),)
    result = apply_plausibility(r2, ctx_for(params=params, previous=previous, dt=dt))
    lost = person - result.region
    assert lost.volume() <= 1e-9 * max(1.0, person.volume())
    total = result.region.volume() + result.removed_volume
    assert total == pytest.approx(r2.volume(), rel=1e-6)
    for removed in result.removed:
        assert removed.rule in RULE_ORDER
        assert (removed.mesh ^ person).volume() <= 1e-12


@settings(max_examples=40, deadline=None)
@given(noise=st.lists(
    st.tuples(st.floats(0.0, 5.8), st.floats(0.0, 5.8), st.floats(0.0, 3.3), st.floats(0.005, 0.5)),
    min_size=1, max_size=8,
))
def test_volume_is_conserved(noise) -> None:
    blobs = [box((x, y, z), (x + s, y + s, z + s)) for x, y, z, s in noise]
    r2 = (union(*blobs) ^ ZONE.manifold()) - TABLE
    params = PlausibilityParams(entry=True, teleport=True)
    result = apply_plausibility(r2, ctx_for(params=params, previous=(blobs[0],), dt=0.1))
    assert result.region.volume() + result.removed_volume == pytest.approx(r2.volume(), rel=1e-6)
    kept_volume = sum(k.volume() for k in result.kept)
    assert kept_volume == pytest.approx(result.region.volume(), rel=1e-9, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    a=st.tuples(*[st.floats(0.0, 0.5)] * 3),
    size_a=st.tuples(*[st.floats(0.05, 0.5)] * 3),
    offset=st.tuples(*[st.sampled_from([-1e-3, -2e-5, 0.0, 5e-6, 2e-5, 1e-3, 0.1])] * 3),
    yaw=st.sampled_from([0.0, 15.0, 45.0]),
    sphere=st.booleans(),
)
def test_touch_agrees_with_min_gap(a, size_a, offset, yaw, sphere) -> None:
    """The triangle-pair touch test agrees with manifold3d's min_gap on disjoint solids."""
    first = box(a, np.add(a, size_a))
    lo, hi = np.asarray(first.bounding_box()).reshape(2, 3)
    # The second solid sits against the +x face of the first, shifted by the offset.
    second = m3.Manifold.sphere(0.1, 24) if sphere else box((0, -0.1, -0.1), (0.2, 0.1, 0.1))
    second = second.rotate((0.0, 0.0, yaw))
    s_lo = np.asarray(second.bounding_box())[:3]
    centre = np.array([hi[0], (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2])
    second = second.translate(tuple(centre - [s_lo[0], 0, 0] + np.asarray(offset)))
    if not (first ^ second).is_empty():
        return  # overlapping solids are not pieces of one region
    gap = first.min_gap(second, 1.0)
    if abs(gap - pl.TOUCH_TOLERANCE) < 1e-7:
        return  # too close to the threshold to compare
    expect = gap <= pl.TOUCH_TOLERANCE
    got = pl._touch(pl._Component(first), pl._Component(second))
    assert got == expect, (gap, got)


# ----------------------------------------------------------------------------- cavities


def _hollow(lo, hi, wall: float) -> m3.Manifold:
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    return box(lo, hi) - box(lo + wall, hi - wall)


def test_removal_keeps_the_cavities_of_kept_components() -> None:
    # A big component on the floor with the robot's body as a cavity inside, and a blob.
    hollow = _hollow((3, 3, 0), (4, 4, 2), 0.2)
    blob = box((1, 4, 1.5), (1.3, 4.3, 1.8))
    r2 = union(hollow, blob)
    assert sorted(round(p.volume(), 6) for p in r2.decompose()) == pytest.approx(
        sorted([2.0, -0.6 * 0.6 * 1.6, 0.027])
    )
    result = apply_plausibility(r2, ctx_for())
    assert [r.rule for r in result.removed] == ["flying"]
    assert result.region.volume() == pytest.approx(hollow.volume(), rel=1e-9)
    assert (result.region ^ box((3.3, 3.3, 0.5), (3.7, 3.7, 1.5))).is_empty()


def test_cavity_counts_in_the_net_volume() -> None:
    # 12 cm box with a 11.6 cm cavity: 0.0017 m^3 outside, 0.00014 m^3 net.
    shell = _hollow((3, 3, 0), (3.12, 3.12, 0.12), 0.002)
    result = apply_plausibility(shell, ctx_for())
    assert [r.rule for r in result.removed] == ["too_small"]
    assert result.removed[0].volume == pytest.approx(shell.volume(), rel=1e-9)
    np.testing.assert_allclose(result.removed[0].centroid, [3.06, 3.06, 0.06], atol=1e-9)


def test_removed_shell_around_a_kept_island_stays() -> None:
    """A removed solid whose cavity holds a kept component is not cut out of R2."""
    params = PlausibilityParams(flying=False, too_thin=False, min_volume=0.01)
    shell = _hollow((1.0, 3.0, 0.0), (1.5, 3.5, 0.5), 0.005)  # net 0.0074 m^3: too small
    island = box((1.1, 3.1, 0.1), (1.4, 3.4, 0.4))  # 0.027 m^3 in the cavity
    hollow = _hollow((3, 3, 0), (4, 4, 2), 0.2)  # a kept component with a cavity
    speck = box((5, 5, 0), (5.1, 5.1, 0.05))  # too small, removed
    r2 = union(shell, island, hollow, speck)
    result = apply_plausibility(r2, ctx_for(params=params))
    assert [r.rule for r in result.removed] == ["too_small"]
    assert result.removed[0].volume == pytest.approx(0.1 * 0.1 * 0.05)
    assert result.region.volume() == pytest.approx(r2.volume() - 0.1 * 0.1 * 0.05, rel=1e-9)
    # Without the hollow component the fast path unites the kept parts: the shell goes.
    r2b = union(shell, island, speck)
    result_b = apply_plausibility(r2b, ctx_for(params=params))
    assert sorted(r.rule for r in result_b.removed) == ["too_small", "too_small"]
    assert result_b.region.volume() == pytest.approx(island.volume(), rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    centre=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)),
    distance=st.floats(0.0, 0.3),
    yaw=st.floats(0.0, 90.0),
    sphere=st.booleans(),
)
def test_within_agrees_with_min_gap(centre, distance, yaw, sphere) -> None:
    """_within(a, b, d) is min_gap(a, b) <= d, nested solids included."""
    big = box((-0.3, -0.3, -0.3), (0.3, 0.3, 0.3))
    small = m3.Manifold.sphere(0.08, 20) if sphere else box((-0.05, -0.1, -0.05), (0.05, 0.1, 0.05))
    small = small.rotate((0.0, 0.0, yaw)).translate(centre)
    if not (big ^ small).is_empty() and not (small - big).is_empty():
        return  # crossing surfaces: not a configuration the rules meet
    gap = big.min_gap(small, 2.0)
    if abs(gap - distance) < 1e-6:
        return
    got = pl._within(pl._Component(big), pl._Component(small), distance)
    assert got == (gap <= distance), (gap, distance)
