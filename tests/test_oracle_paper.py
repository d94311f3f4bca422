"""Zero misses in the paper cell over random scenes: one person (pose, place, heading)
anywhere on the floor, the robot at a random joint position, with or without sensor
noise; people beside obstacles, walking up to the robot, or hidden by another person
beside it. Hypothesis, derandomized (see conftest); ``HYPOTHESIS_PROFILE=explore`` searches.

Two oracles, both independent of the engine's geometry:

- every point the exact per-pixel free depth ``min(D, B) - tau(D)`` leaves possibly
  occupied lies in the engine's R2 (C_static or a dynamic piece), or in the padded
  robot's occlusion M (by its definition, or with the engine's declared static band and
  flying-pixel tolerances), or in a solid;
- every point of the person's body lies in R3, or in that shadow or a solid, or is one the
  exact free depth frees (a body point between two pixels' rays: the cameras' resolution).

A randomised search of this kind (60 scenes) found legs lost against a table's side
(``test_person_at_table``).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    exactly_possibly_occupied,
    in_declared_occlusion,
    in_robot_occlusion,
    manifold_contains,
    outside_r2,
    zone_and_person_points,
)
from hypothesis import HealthCheck, Phase, assume, example, given, settings
from hypothesis import strategies as st

from polyhull.distance import points_in_hexahedra
from polyhull.monitor import Monitor
from polyhull.oracles import in_solids
from polyhull.person import PersonTrack, make_person, sample_points_inside
from polyhull.simulator import SensorEffects, Simulator

# a few derandomized examples each (CI); HYPOTHESIS_PROFILE=explore draws fresh ones
SEARCH = settings(
    max_examples=5,
    deadline=None,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much],
)


@SEARCH
@given(
    x=st.floats(0.4, 5.6),
    y=st.floats(0.4, 5.6),
    yaw=st.floats(-np.pi, np.pi),
    pose=st.sampled_from(["standing", "walking", "reaching", "crouching"]),
    q01=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    effects=st.sampled_from(["none", "all", "no flying pixels"]),
    seed=st.integers(0, 10_000),
)
def test_random_scenes_have_no_misses_and_keep_the_person(
    paper: tuple[Monitor, Simulator], x: float, y: float, yaw: float, pose: str, q01: list[float], effects: str, seed: int
) -> None:
    monitor, sim = paper
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None
    # the person stands on the floor, not in an obstacle nor on the robot's base
    feet = np.array([[x, y, 0.3], [x, y, 1.0]])
    assume(not in_solids(cell, feet).any() and np.hypot(x - 3.0, y - 3.0) > 0.45)
    q = robot.lower + np.asarray(q01) * (robot.upper - robot.lower)
    person = make_person(pose=pose, position=(x, y), yaw=yaw)  # type: ignore[arg-type]
    # flying pixels are real readings between a person and the background: the exact free
    # depth frees space inside the person there too, and the body test excuses it
    chosen = {"none": SensorEffects.none(), "all": SensorEffects(), "no flying pixels": SensorEffects(flying_pixels=False)}
    frames = sim.render(q, targets=[person], seed=seed, stamp=1.0, effects=chosen[effects])
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.0)
    assert not any("internal" in f for f in v.faults), v.faults
    _assert_no_misses(monitor, frames, v, person, seed, 0)
    body = sample_points_inside(person, 200, seed=seed)
    body = body[cell.zone.contains(body)]
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
    ok = in_r3 | in_robot_occlusion(monitor, body) | in_solids(cell, body) | ~exactly_possibly_occupied(monitor, frames, body)
    assert ok.all(), f"{(~ok).sum()} person points outside R3: {body[~ok][:5]}"


def _beside(bounds: np.ndarray, side: int, along: float, gap: float) -> tuple[float, float]:
    """A floor position ``gap`` [m] out from one side (0: -x, 1: +x, 2: -y, 3: +y) of a box
    obstacle's footprint, at ``along`` (0..1) of that side."""
    (x0, y0, _), (x1, y1, _) = bounds
    if side < 2:
        return (x0 - gap if side == 0 else x1 + gap), y0 + along * (y1 - y0)
    return x0 + along * (x1 - x0), (y0 - gap if side == 2 else y1 + gap)


@SEARCH
@given(
    obstacle=st.integers(0, 2),
    side=st.integers(0, 3),
    along=st.floats(0.0, 1.0),
    gap=st.floats(0.12, 0.45),
    height=st.floats(1.5, 1.95),
    yaw=st.floats(-np.pi, np.pi),
    pose=st.sampled_from(["standing", "walking", "reaching", "crouching"]),
    second=st.booleans(),
    q01=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    effects=st.sampled_from(["none", "all", "no flying pixels"]),
    seed=st.integers(0, 100_000),
)
def test_people_beside_an_obstacle_stay_in_r3(
    paper: tuple[Monitor, Simulator],
    obstacle: int, side: int, along: float, gap: float, height: float, yaw: float, pose: str,
    second: bool, q01: list[float], effects: str, seed: int,
) -> None:
    """People standing, walking, reaching or crouching beside a table's or the rack's side (where the
    noise sheets are up to 0.4 m deep), a second one anywhere: every body point in R3 or
    excused. A search of this kind found a person with their back to the rack lost, and a
    toe in the rack's corner by the wall (``test_person_at_table``)."""
    monitor, sim = paper
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None
    boxes = [o.mesh.bounds for o in cell.obstacles if not o.name.startswith("wall")]
    x, y = _beside(np.asarray(boxes[obstacle % len(boxes)]), side, along, gap)
    assume(0.15 < x < 5.85 and 0.15 < y < 5.85 and np.hypot(x - 3.0, y - 3.0) > 0.5)
    people = [make_person(height=height, pose=pose, position=(x, y), yaw=yaw)]  # type: ignore[arg-type]
    if second:
        rng = np.random.default_rng(seed)
        people.append(make_person(pose="walking", position=tuple(rng.uniform(0.4, 5.6, 2)), yaw=float(rng.uniform(-3, 3))))
    bodies = [sample_points_inside(p, 300, seed=seed + j) for j, p in enumerate(people)]
    assume(all(in_solids(cell, b).mean() <= 0.01 for b in bodies))  # nobody inside a solid
    q = robot.lower + np.asarray(q01) * (robot.upper - robot.lower)
    chosen = {"none": SensorEffects.none(), "all": SensorEffects(), "no flying pixels": SensorEffects(flying_pixels=False)}
    frames = sim.render(q, targets=people, seed=seed, stamp=1.0, effects=chosen[effects])
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.0)
    assert not any("internal" in f for f in v.faults), v.faults
    assume(not v.faults)  # a contact at random q stops the robot whatever the region
    body = np.concatenate(bodies)
    body = body[cell.zone.contains(body)]
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
    ok = in_r3 | in_robot_occlusion(monitor, body) | in_solids(cell, body) | ~exactly_possibly_occupied(monitor, frames, body)
    assert ok.all(), f"{(~ok).sum()} of {len(body)} body points outside R3: {body[~ok][:5]}"


def _assert_no_misses(monitor: Monitor, frames: dict, v: object, person: object, seed: int, cycle: int) -> None:  # type: ignore[type-arg]
    """Every one of 6,000 points (half in the zone, half around the person) that the
    exact per-pixel free depth ``min(D, B) - tau(D)`` leaves possibly occupied lies in R2 of
    verdict ``v``, in the padded robot's occlusion M (by its definition, or with the
    declared static band and flying-pixel tolerances), or in a solid."""
    points = zone_and_person_points(monitor.cell, person, np.random.default_rng(seed))
    occupied, out = outside_r2(monitor, frames, v, points)
    assert occupied > 100  # the oracle tests something
    misses = out[~in_declared_occlusion(monitor, frames, out)]
    assert len(misses) == 0, f"cycle {cycle}: {len(misses)} exactly occupied points outside R2: {misses[:5]}"


def _assert_body_in_r3(monitor: Monitor, frames: object, v: object, person: object, seed: int, cycle: int) -> None:
    """Every one of 300 body points of the person (in the zone) lies in R3 of verdict ``v``,
    in the padded robot's occlusion M by its definition, in a solid, or is one the exact
    free depth frees."""
    cell = monitor.cell
    body = sample_points_inside(person, 300, seed=seed)  # type: ignore[arg-type]
    body = body[cell.zone.contains(body)]
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[attr-defined]
    ok = in_r3 | in_robot_occlusion(monitor, body) | in_solids(cell, body) | ~exactly_possibly_occupied(monitor, frames, body)  # type: ignore[arg-type]
    assert ok.all(), f"cycle {cycle}: {(~ok).sum()} of {len(body)} body points outside R3: {body[~ok][:5]}"


@SEARCH
@example(  # crouching 0.7 m from the base, in its floor sheet, while the arm moves
    r0=0.7, bearing=0.5, heading=0.0, step=0.05, height=1.75, pose="crouching", q01=[0.5] * 6, dq=[0.03] * 6,
    effects="all", seed=11,
)
@given(
    r0=st.floats(0.6, 1.5),
    bearing=st.floats(-np.pi, np.pi),
    heading=st.floats(-1.2, 1.2),
    step=st.floats(0.05, 0.15),
    height=st.floats(1.5, 1.95),
    pose=st.sampled_from(["standing", "walking", "reaching", "crouching"]),
    q01=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    dq=st.lists(st.floats(-0.08, 0.08), min_size=6, max_size=6),
    effects=st.sampled_from(["none", "all", "no flying pixels"]),
    seed=st.integers(0, 100_000),
)
def test_people_walking_up_to_the_robot_stay_in_r3(
    paper: tuple[Monitor, Simulator],
    r0: float, bearing: float, heading: float, step: float, height: float, pose: str,
    q01: list[float], dq: list[float], effects: str, seed: int,
) -> None:
    """A person 0.6 to 1.5 m from the robot's base walks up to it (or past it) for four
    cycles of 0.1 s while the robot moves: where the robot's raster explains readings, its
    shadow is subtracted and the shadow memory carries what it hid. No miss in any cycle
    (the exact hull in R2 or excused), and every body point of every cycle in R3 or
    excused; a cycle that stops for a contact ends the walk."""
    monitor, sim = paper
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None
    bx, by = cell.robot.base[:2]  # type: ignore[union-attr]
    x0, y0 = bx + r0 * np.cos(bearing), by + r0 * np.sin(bearing)
    head = bearing + np.pi + heading
    q = robot.lower + np.asarray(q01) * (robot.upper - robot.lower)
    chosen = {"none": SensorEffects.none(), "all": SensorEffects(), "no flying pixels": SensorEffects(flying_pixels=False)}
    monitor.reset()
    for c in range(4):
        x, y = x0 + c * step * np.cos(head), y0 + c * step * np.sin(head)
        if np.hypot(x - bx, y - by) < 0.45:  # on the robot's base
            break
        person = make_person(height=height, pose=pose, position=(x, y), yaw=head)  # type: ignore[arg-type]
        qc = np.clip(q + c * np.asarray(dq), robot.lower, robot.upper)
        t = 1.0 + 0.1 * c
        frames = sim.render(qc, targets=[person], seed=seed + c, stamp=t, effects=chosen[effects])
        v = monitor.step(frames, qc, stamp=t)
        assert not any("internal" in f for f in v.faults), v.faults
        _assert_no_misses(monitor, frames, v, person, seed + c, c)
        if v.faults:  # a contact stops the robot whatever the region
            break
        _assert_body_in_r3(monitor, frames, v, person, seed + c, c)


@SEARCH
@given(
    r0=st.floats(0.6, 1.3),
    bearing=st.floats(-np.pi, np.pi),
    camera=st.integers(0, 3),
    gap=st.floats(0.6, 1.5),
    side=st.floats(-0.25, 0.25),
    heights=st.tuples(st.floats(1.5, 1.95), st.floats(1.5, 1.95)),
    poses=st.tuples(
        st.sampled_from(["standing", "reaching", "crouching"]), st.sampled_from(["standing", "walking", "reaching"])
    ),
    q01=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    effects=st.sampled_from(["none", "all"]),
    seed=st.integers(0, 100_000),
)
def test_a_person_another_hides_beside_the_robot_stays_in_r3(
    paper: tuple[Monitor, Simulator],
    r0: float, bearing: float, camera: int, gap: float, side: float, heights: tuple[float, float],
    poses: tuple[str, str], q01: list[float], effects: str, seed: int,
) -> None:
    """Two people: one 0.6 to 1.3 m from the robot's base, the other 0.6 to 1.5 m from them
    towards one camera (off the line by up to 0.25 m), hiding them from it, while the robot
    hides them from others. No miss around either, and both bodies in R3 (or excused)."""
    monitor, sim = paper
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None
    bx, by = cell.robot.base[:2]  # type: ignore[union-attr]
    a = np.array([bx + r0 * np.cos(bearing), by + r0 * np.sin(bearing)])
    towards = cell.cameras[camera].center[:2] - a
    towards /= np.linalg.norm(towards)
    b = a + gap * towards + side * np.array([-towards[1], towards[0]])
    lo, hi = np.asarray(cell.zone.min)[:2] + 0.3, np.asarray(cell.zone.max)[:2] - 0.3
    assume(bool(np.all((lo <= b) & (b <= hi))) and np.hypot(b[0] - bx, b[1] - by) > 0.6)
    assume(not in_solids(cell, np.array([[*b, 0.3], [*b, 1.0], [*a, 0.3], [*a, 1.0]])).any())
    people = [
        make_person(height=heights[0], pose=poses[0], position=tuple(a), yaw=bearing + np.pi),  # type: ignore[arg-type]
        make_person(height=heights[1], pose=poses[1], position=tuple(b), yaw=float(np.arctan2(-towards[1], -towards[0]))),  # type: ignore[arg-type]
    ]
    q = robot.lower + np.asarray(q01) * (robot.upper - robot.lower)
    chosen = {"none": SensorEffects.none(), "all": SensorEffects()}
    frames = sim.render(q, targets=people, seed=seed, stamp=1.0, effects=chosen[effects])
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.0)
    assert not any("internal" in f for f in v.faults), v.faults
    for j, person in enumerate(people):
        _assert_no_misses(monitor, frames, v, person, seed + j, 0)
    if v.faults:  # a contact stops the robot whatever the region
        return
    for j, person in enumerate(people):
        _assert_body_in_r3(monitor, frames, v, person, seed + j, 0)


def _search_walk(monitor: Monitor, seed: int) -> tuple[list[tuple[object, np.ndarray, float]], SensorEffects]:
    """The walks of the randomised search that found the scenes below (seeded numpy, not
    hypothesis): a person 0.6 to 1.5 m from the base walks toward the robot (or past it)
    for four cycles of 0.1 s while the robot moves; (person, q, stamp) per cycle, and the
    sensor effects."""
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None and cell.robot is not None
    bx, by = cell.robot.base[:2]
    rng = np.random.default_rng(seed)
    r0, th = rng.uniform(0.6, 1.5), rng.uniform(-np.pi, np.pi)
    x, y = bx + r0 * np.cos(th), by + r0 * np.sin(th)
    head = th + np.pi + rng.uniform(-1.2, 1.2)
    step = rng.uniform(0.05, 0.15)
    yaw = head + rng.uniform(-0.5, 0.5)
    pose = str(rng.choice(["standing", "walking", "reaching"]))
    height = rng.uniform(1.5, 1.95)
    q = robot.lower + rng.random(6) * (robot.upper - robot.lower)
    dq = rng.uniform(-0.08, 0.08, 6)
    effects = [SensorEffects.none(), SensorEffects(), SensorEffects(flying_pixels=False)][int(rng.integers(3))]
    out = []
    for c in range(4):
        position = (x + c * step * np.cos(head), y + c * step * np.sin(head))
        person = make_person(height=height, pose=pose, position=position, yaw=yaw)  # type: ignore[arg-type]
        out.append((person, np.clip(q + c * dq, robot.lower, robot.upper), 1.0 + 0.1 * c))
    return out, effects


# Found by a search of 360 such walks (seeds 7000-7059, 20000-20149, 30000-30149), each
# with the default sensor effects but for 20077 (none):
# - 7030, 20077: the arm hides the person's shins from every camera; the body above them
#   is seen and stands on M, but nothing of it crossed the floor's sheet where the legs
#   were, so the sheet rule took their feet (18 and 8 of 300 body points) until the
#   columns of M under such a body kept the sheet (``hidden_legs``);
# - 20004, 30148: a hand (or a head) seen alone beside the robot, the arm (the neck) between
#   it and the body hidden by the robot: too small on its own, it went (1 of 300 points)
#   until such a part within an arm's length of a body that touches M is judged with it.
@pytest.mark.parametrize("seed", [7030, 20004, 20077, 30148])
def test_people_whose_limbs_the_robot_hides_stay_in_r3(paper: tuple[Monitor, Simulator], seed: int) -> None:
    monitor, sim = paper
    walk, effects = _search_walk(monitor, seed)
    monitor.reset()
    for c, (person, q, t) in enumerate(walk):
        frames = sim.render(q, targets=[person], seed=seed * 10 + c, stamp=t, effects=effects)
        v = monitor.step(frames, q, stamp=t)
        assert not any("internal" in f for f in v.faults), v.faults
        _assert_no_misses(monitor, frames, v, person, seed + c, c)
        if v.faults:  # a contact stops the robot whatever the region
            break
        _assert_body_in_r3(monitor, frames, v, person, seed + c, c)


def test_a_person_the_robot_hides_to_the_hips_keeps_their_feet(paper: tuple[Monitor, Simulator]) -> None:
    """Found by ``tests/search_walks.py`` (seed 7010, its walk's cycle 11): a person lunging
    at the robot's base and reaching over it, whom the base and the arm hide from every
    camera from the floor to 1.1 m. Their forward foot lies in the floor's sheet outside M,
    0.33 m from the base's axis; the body seen stands on M, but the legs' rule looked only
    under pieces starting below 1 m, so the sheet rule took the foot (1 of 2,000 body
    points) until every kept piece of a component touching M stood on the hidden legs."""
    monitor, sim = paper
    track = PersonTrack(
        start=(1.322072171860302, 1.9326324148411007), end=(4.26757443812544, 3.4520814217912212),
        speed=1.6601999899111575, end_pose="reaching",
    )
    q = np.array([-0.9433804497218096, -0.6510879265777954, 0.0026904190541092166, 2.9509456836846195, 0.6595817543514608, 0.39054145883085])
    person = track.mesh(1.1)
    frames = sim.render(q, targets=[person], seed=701011, stamp=1.1, effects=SensorEffects(flying_pixels=False))
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.1)
    assert not v.faults, v.faults  # no contact: the region is what keeps the foot
    _assert_no_misses(monitor, frames, v, person, 7010, 0)
    body = sample_points_inside(person, 2000, seed=1)
    foot = body[(body[:, 2] < 0.1) & (np.hypot(body[:, 0] - 3.0, body[:, 1] - 3.0) < 0.4)]
    assert len(foot) > 10  # the forward foot, beside the base
    cell = monitor.cell
    in_r3 = manifold_contains(monitor.static.region, foot) | points_in_hexahedra(foot, v._geometry.kept)  # type: ignore[union-attr]
    ok = in_r3 | in_robot_occlusion(monitor, foot) | in_solids(cell, foot) | ~exactly_possibly_occupied(monitor, frames, foot)
    assert ok.all(), f"{(~ok).sum()} of {len(foot)} points of the foot outside R3: {foot[~ok][:5]}"
