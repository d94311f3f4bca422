"""The empty paper cell, robot moving, every sensor effect on: the region stays the static one.

What the issue of the second engine asked for: nobody present means no dynamic region that
brings the robot to a stop. Dropout patches and out-of-range pixels are freed by the
small_gaps rule, the shadow memory grows only from seen targets, so the distance is the
static region's own in most cycles and never a contact.
"""

from __future__ import annotations

import numpy as np
import pytest

from polyhull.cellfile import default_cell_path, load_cell
from polyhull.commands.demo import robot_motion
from polyhull.engine.pieces import CameraStack
from polyhull.monitor import SEED_DEPTH, Monitor, _seen_parts
from polyhull.simulator import SensorEffects, Simulator

CYCLES = 12
DT = 0.1  # [s], the bench's cycle


@pytest.fixture(scope="module")
def paper() -> tuple[Monitor, Simulator]:
    cell = load_cell(default_cell_path())
    sim = Simulator(cell)
    return Monitor(cell, references=sim.reference()), sim


def test_empty_cell_distance_is_the_static_one(paper: tuple[Monitor, Simulator]) -> None:
    monitor, sim = paper
    robot, model = monitor.robot, monitor._distance_model
    assert robot is not None and model is not None
    q0 = np.asarray(monitor.cell.robot.q)  # type: ignore[union-attr]
    same, lost = 0, []
    for k in range(CYCLES):
        q = robot_motion(q0, robot.lower, robot.upper, k * DT)
        frames = sim.render(q, seed=500 + k, stamp=k * DT, effects=SensorEffects(uint16=True))
        v = monitor.step(frames, q, stamp=k * DT)
        assert not v.faults, v.faults
        static = model.distance(
            robot.link_transforms(q), static=monitor.static.bvh, static_contains=monitor._static_contains
        ).distance
        assert v.min_distance <= static + 1e-9  # the dynamic part only adds
        same += abs(v.min_distance - static) <= 0.01
        lost.append(static - v.min_distance)
        assert v.counts["small_gap_pixels"] > 0  # the dropouts were there, and freed
    # measured: 8 of these 12 cycles (54 of 100 in `polyhull bench`); the others lose up to
    # ~0.35 m to pieces of flying pixels next to a table or the robot, or to dropout
    # patches next to the robot (never freed there)
    assert same >= CYCLES // 2 - 1, lost
    assert max(lost) < 0.5, lost


def test_memory_seeds_are_the_seen_depth() -> None:
    """A seed is the part of a piece within SEED_DEPTH behind its pixels' free depth."""
    from polyhull.cellfile import load_cell as load

    cell = load(default_cell_path())
    stack = CameraStack.of(cell.cameras)
    H, W = cell.cameras[0].shape
    free = np.full((H, W), 2.0, dtype=np.float32)
    free[100:102, 200:202] = 2.5
    boxes = np.array(
        [
            [0, 200, 201, 100, 101, 2.0, 4.0],  # starts before the surface, ends far behind
            [0, 10, 11, 10, 11, 3.0, 4.0],  # entirely deeper than 2.0 + SEED_DEPTH
        ]
    )
    seeds = _seen_parts(boxes, [free] + [None] * (len(cell.cameras) - 1), stack)
    assert seeds.shape == (1, 8, 3)
    cam = cell.cameras[0]
    _, z = cam.project(seeds[0])
    np.testing.assert_allclose(sorted(set(np.round(z, 6))), [2.5, 2.5 + SEED_DEPTH], atol=1e-6)
