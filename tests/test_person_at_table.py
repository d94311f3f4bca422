"""A person standing at a table in the paper cell keeps their legs in R3.

Found by a randomised search of the point oracle (people, poses, robot q): a person
reaching over the south table with their legs against its side. The legs lie in the
noise sheet in front of the table's side (closer to it than the sheet is thick, so the
far cameras read the table's side there and the near ones see the table top instead),
and the static model removes that sheet at precompute. Only the body above the table is
a dynamic piece; it reaches the side's sheet from above its upper edge, so the sheet is
kept from there down to the floor (:func:`polyhull.engine.dynamic_rules.sheets_under`).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import manifold_contains

from polyhull.cellfile import default_cell_path, load_cell
from polyhull.distance import points_in_hexahedra
from polyhull.monitor import Monitor
from polyhull.person import make_person, sample_points_inside
from polyhull.simulator import SensorEffects, Simulator

Q = [0.7271, -1.5896, -2.2518, 4.3725, -1.8492, -3.6519]


@pytest.fixture(scope="module")
def paper() -> tuple[Monitor, Simulator]:
    cell = load_cell(default_cell_path())
    sim = Simulator(cell)
    return Monitor(cell, references=sim.reference()), sim


@pytest.mark.parametrize("position", [(3.6765, 0.9125), (2.9, 0.95)])
def test_legs_against_a_table_side_stay_in_r3(paper: tuple[Monitor, Simulator], position: tuple[float, float]) -> None:
    monitor, sim = paper
    cell = monitor.cell
    person = make_person(pose="reaching", position=position, yaw=-2.0091)
    q = np.asarray(Q)
    frames = sim.render(q, targets=[person], seed=1001, stamp=1.0, effects=SensorEffects.none())
    monitor.reset()
    v = monitor.step(frames, q, stamp=1.0)
    assert not v.faults, v.faults
    body = sample_points_inside(person, 400, seed=1)
    body = body[cell.zone.contains(body)]
    solid = np.zeros(len(body), dtype=bool)
    for o in cell.solid_obstacles:
        b0, b1 = o.mesh.bounds
        solid |= np.all((body >= b0) & (body <= b1), axis=1)
    table = cell.solid_obstacles[0].mesh.bounds
    legs = ~solid & (body[:, 2] < table[1][2]) & (body[:, 1] < table[1][1] + 0.4)
    assert legs.sum() > 5  # the scene has what the test is about: legs in the side's sheet
    in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)
    ok = in_r3 | monitor.in_robot_shadow(body) | solid
    assert ok.all(), f"{(~ok).sum()} of {len(body)} body points outside R3: {body[~ok][:5]}"
