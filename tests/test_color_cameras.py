"""Colour cameras (binary depth) in the monitor: the paper cell's four
cameras as colour cameras (320 x 240).

A changed pixel of a colour camera frees nothing, so in the empty cell with the robot a
pixel the robot covers hides its whole ray: the robot's occlusion M of a colour camera
starts at ``near``, not at the robot (``M = F_static minus F_static+robot``). Before, those
pixels were unexplained and their rays in front of the robot were kept: the empty cell's
region touched the robot (0 to 4 cm, a stop) at every joint position, at 1.2 s a cycle.
The shadow memory holds what M hides in front of the robot as well as behind it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import exactly_possibly_occupied, in_robot_occlusion, in_robot_span, manifold_contains

from polyhull.cellfile import default_cell_path, load_cell
from polyhull.commands.bench import rescale_camera
from polyhull.commands.demo import robot_motion
from polyhull.distance import STATIC_TOLERANCE, points_in_hexahedra
from polyhull.engine.memory import seen_parts
from polyhull.engine.pieces import CameraStack, piece_vertices
from polyhull.monitor import Monitor
from polyhull.oracles import in_solids
from polyhull.person import make_person, sample_points_inside
from polyhull.simulator import SensorEffects, Simulator


@pytest.fixture(scope="module")
def color() -> tuple[Monitor, Simulator]:
    base = load_cell(default_cell_path())
    cameras = tuple(
        replace(rescale_camera(c, 320, 240), kind="color", noise=0.0, tolerance_min=0.02) for c in base.cameras
    )
    cell = replace(base, cameras=cameras)
    sim = Simulator(cell)
    return Monitor(cell, references=sim.reference()), sim


def test_the_colour_cameras_free_the_floor_statically(color: tuple[Monitor, Simulator]) -> None:
    """A colour camera's band is not widened at static edges (that is for a depth camera's
    flying pixels; a widened colour band admits changed readings, so such pixels freed
    nothing). Before, every pixel whose 3 x 3 depth range exceeded the colour band (4 cm)
    counted as an edge: 76 to 80 % of these cameras' pixels in range, a slanted floor
    almost everywhere, and the static hull held most of the cell."""
    monitor, _ = color
    for s in monitor.statics:
        in_range = np.isfinite(s.reference) & (s.reference < s.camera.far)
        assert (s.free_static[in_range] <= s.camera.near).mean() < 0.1, s.camera.name


@pytest.mark.parametrize("effects", [SensorEffects.none(), SensorEffects(uint16=True)], ids=["clean", "effects"])
def test_the_empty_cell_is_the_static_region_and_the_robot_runs(
    color: tuple[Monitor, Simulator], effects: SensorEffects
) -> None:
    """Without sensor effects, and with the default ones (a colour camera gets no flying
    pixels or dropouts: with them every mixed pixel at a static edge was a changed ray, and
    a dropout patch's ray in front of the robot brought the region within 0.13 m of it)."""
    monitor, sim = color
    robot, model = monitor.robot, monitor._distance_model
    assert robot is not None and model is not None
    q0 = np.asarray(monitor.cell.robot.q)  # type: ignore[union-attr]
    monitor.reset()
    for k in range(4):
        t = 0.1 * k
        q = robot_motion(q0, robot.lower, robot.upper, t)
        v = monitor.step(sim.render(q, seed=k, stamp=t, effects=effects), q, stamp=t)
        static = model.distance(robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains)
        assert not v.faults, v.faults
        assert v.counts["unexplained_pixels"] == 0
        # the monitor measures to the static region simplified outward by STATIC_TOLERANCE
        assert v.min_distance == pytest.approx(static.distance, abs=2 * STATIC_TOLERANCE)
        assert v.min_distance > 1.0 and v.speed_scale > 0.5


def _near_robot(monitor: Monitor, over: bool = False) -> tuple[np.ndarray, object]:
    """The robot at its cell pose and a person reaching toward it (``over``: with the hand
    over the arm, where every camera that sees it has it in front of the robot)."""
    q = np.asarray(monitor.cell.robot.q)  # type: ignore[union-attr]
    if over:
        return q, make_person(height=1.808, pose="reaching", position=(2.836, 2.306), yaw=0.945)
    return q, make_person(height=1.8, pose="reaching", position=(2.35, 2.55), yaw=np.arctan2(0.45, 0.65))


def test_a_person_at_the_robot_is_in_r3_or_in_m(color: tuple[Monitor, Simulator]) -> None:
    """Every body point is in R3, in a solid, freed by the exact free depth, or in M by its
    definition (not merely in one camera's shadow)."""
    monitor, sim = color
    cell = monitor.cell
    q, person = _near_robot(monitor)
    frames = sim.render(q, targets=[person], seed=3, stamp=1.0, effects=SensorEffects.none())
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.0)
    assert not v.faults, v.faults
    body = sample_points_inside(person, 600, seed=3)
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
    ok = in_r3 | in_solids(cell, body) | ~exactly_possibly_occupied(monitor, frames, body) | in_robot_occlusion(monitor, body)
    assert ok.all(), f"{(~ok).sum()} body points outside R3 and M: {body[~ok][:5]}"
    assert in_r3.mean() > 0.9


def test_the_memory_holds_what_m_hides_in_front_of_the_robot(color: tuple[Monitor, Simulator]) -> None:
    """The same person, reaching over the robot's arm, seen again a cycle later: what M
    hides of them is held by the shadow memory, whose part in front of the robot (the
    colour cameras') holds the robot pixels' segments from the free depth to the robot.
    Every body point in M within a person's reach in a cycle of what the first cycle saw
    of them (the memory's seeds) is in R3, but those within the padded robot's depth span
    in every camera that sees the robot there (the padded robot, the declared tolerance,
    and the gaps between its pieces along a ray, which the memory does not hold)."""
    monitor, sim = color
    cell = monitor.cell
    q, person = _near_robot(monitor, over=True)
    monitor.reset()
    for k in range(2):
        if k == 1:  # what the first cycle saw of the person: the memory's seeds
            seed_lo, seed_hi = monitor._seed_lo, monitor._seed_hi
            assert seed_lo is not None and seed_hi is not None and len(seed_lo)
        frames = sim.render(q, targets=[person], seed=4 + k, stamp=1.0 + 0.1 * k, effects=SensorEffects.none())
        v = monitor.step(frames, q, stamp=1.0 + 0.1 * k)
        assert not v.faults, v.faults
    body = sample_points_inside(person, 600, seed=4)
    # the memory follows a person's reach in a cycle from what was seen of them
    reach = cell.safety.human_speed * 0.1
    gap = np.maximum(0.0, np.maximum(seed_lo[None] - body[:, None], body[:, None] - seed_hi[None]))
    near_seeds = np.sqrt((gap**2).sum(axis=-1)).min(axis=1) <= reach
    hidden = in_robot_occlusion(monitor, body) & exactly_possibly_occupied(monitor, frames, body) & ~in_robot_span(monitor, body)
    hidden &= near_seeds
    assert hidden.sum() >= 5  # the scene tests the memory
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
    lost = hidden & ~in_r3 & ~in_solids(cell, body)
    assert not lost.any(), f"{lost.sum()} of {hidden.sum()} body points in M not held: {body[lost][:5]}"
    # the front part's segments: on the robot's pixels, from the free depth to the padded
    # robot's front, none behind it
    front = monitor._shadow_front
    assert front is not None and front.stacks is not None
    starts, ends = front.stacks
    assert monitor.last_images is not None
    segments = 0
    for i, cam in enumerate(cell.cameras):
        r = monitor.last_images.raster[cam.name]
        f, e = starts.image(i), ends.image(i)
        seg = e > f
        segments += int(seg.sum())
        assert r.covered[seg].all()
        assert (e[seg] <= r.front[seg]).all() and (f[seg] >= cam.near).all()
    assert segments > 100


def test_a_colour_cameras_pieces_seed_the_memory_whole() -> None:
    """A colour camera measures no surface (a changed pixel frees nothing): the memory's
    seeds are its pieces whole, not their first ``SEED_DEPTH`` behind ``near``, which held
    next to nothing of a person seen only by colour cameras; but a dropout patch's pieces
    (no reading at all) seed nothing, as a depth camera's."""
    cell = load_cell(default_cell_path())
    stack = CameraStack.of(cell.cameras)
    H, W = cell.cameras[0].shape
    free = np.full((H, W), cell.cameras[0].near, dtype=np.float32)  # changed: frees nothing
    boxes = np.array([[0, 200, 207, 100, 107, 2.0, 4.5]])
    frees = [free] + [None] * (len(cell.cameras) - 1)
    assert len(seen_parts(boxes, frees, stack)) == 0  # a depth camera: beyond near + SEED_DEPTH
    binary = [True] + [False] * (len(cell.cameras) - 1)
    whole = seen_parts(boxes, frees, stack, binary)
    np.testing.assert_allclose(whole, piece_vertices(boxes, stack))
    # a piece of pixels without any reading (a dropout patch) saw nothing
    invalid = np.zeros((H, W), dtype=bool)
    invalid[100:108, 200:208] = True
    invalids = [invalid] + [None] * (len(cell.cameras) - 1)
    assert len(seen_parts(boxes, frees, stack, binary, invalids)) == 0
    invalid[103, 204] = False  # one pixel with a changed reading: the piece is seen
    np.testing.assert_allclose(seen_parts(boxes, frees, stack, binary, invalids), whole)
