"""Region-robot distance with python-fcl against manifold3d min_gap; engine golden values."""

from __future__ import annotations

import importlib.util
import json
import math

import manifold3d as m3
import numpy as np
import pytest
from conftest import FIXTURES

from polyhull.cell import Cell, mesh_to_manifold
from polyhull.distance import RobotDistanceModel
from polyhull.robot import Robot

GOLDEN = FIXTURES / "golden" / "engine_small_walk.json"


@pytest.fixture(scope="module")
def robot(small_cell: Cell) -> Robot:
    return Robot.from_spec(small_cell.robot)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def model(robot: Robot) -> RobotDistanceModel:
    return RobotDistanceModel(robot.link_geometry())


def _box(center: tuple[float, float, float], size: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(size, True).translate(center)


def _min_gap(region: m3.Manifold, robot: Robot, q: np.ndarray) -> tuple[float, str]:
    best, best_link = math.inf, ""
    for name, mesh in robot.link_meshes(q).items():
        link = mesh_to_manifold(mesh, name)
        gap = region.min_gap(link, 2.0)
        if gap < best:
            best, best_link = gap, name
    return best, best_link


@pytest.mark.parametrize(
    ("center", "size", "q"),
    [
        ((0.6, 0.6, 0.8), (0.3, 0.3, 0.5), [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]),
        ((2.3, 1.5, 1.2), (0.2, 0.8, 0.3), [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]),
        ((1.5, 0.7, 1.0), (0.5, 0.2, 1.6), [0.5, -0.3, 0.9, 0.4, -0.6, 0.2]),
    ],
)
def test_distance_matches_min_gap(robot: Robot, model: RobotDistanceModel, center, size, q) -> None:  # noqa: ANN001
    q = np.asarray(q, dtype=np.float64)
    region = _box(center, size)
    result = model.distance(region, robot.link_transforms(q))
    gap, link = _min_gap(region, robot, q)
    assert 0.0 < gap < 2.0
    assert result.distance == pytest.approx(gap, abs=1e-3)
    assert result.link == link
    assert result.points is not None
    # The witness points are that far apart.
    assert np.linalg.norm(result.points[0] - result.points[1]) == pytest.approx(result.distance, abs=1e-6)


def test_contact_is_zero_and_names_link(robot: Robot, model: RobotDistanceModel) -> None:
    q = np.asarray([0.0, -0.6, 1.2, 0.0, 0.8, 0.0])
    T = robot.link_transforms(q)
    # A box around the gripper origin touches the gripper.
    p = T["gripper"][:3, 3]
    result = model.distance(_box(tuple(p), (0.1, 0.1, 0.1)), T)
    assert result.distance == 0.0
    assert result.link is not None
    assert result.points is None


def test_empty_region_is_inf(robot: Robot, model: RobotDistanceModel) -> None:
    result = model.distance(m3.Manifold(), robot.link_transforms(np.zeros(6)))
    assert math.isinf(result.distance)
    assert result.link is None and result.points is None


def test_golden_engine_values() -> None:
    """Volumes of C, M, R and the minimum distance of small_walk_000..002 stay put."""
    spec = importlib.util.spec_from_file_location("make_golden", FIXTURES / "golden" / "make_golden.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    got = module.compute()
    want = json.loads(GOLDEN.read_text())
    assert len(got["frames"]) == len(want["frames"]) == 3
    for g, w in zip(got["frames"], want["frames"], strict=True):
        assert g["file"] == w["file"]
        assert g["faults"] == w["faults"]
        for key in ("volume_hull", "volume_robot_occlusion", "volume_region", "min_distance"):
            if w[key] is None:
                assert g[key] is None
            else:
                assert np.isclose(g[key], w[key], rtol=1e-6, atol=1e-9), (w["file"], key, g[key], w[key])
