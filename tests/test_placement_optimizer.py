"""The placement optimiser: parameterisation, stopping, executors, and CMA-ES vs random."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.camera import Camera, Intrinsics
from polyhull.cell import Cell, MountingSurface, Zone
from polyhull.cellfile import load_cell
from polyhull.errors import CellError, PolyhullError
from polyhull.placement.objectives import PlacementProblem, evaluate_cameras
from polyhull.placement.optimizer import (
    CameraParameterisation,
    InlineExecutor,
    StopCriteria,
    evaluate_vector,
    make_executor,
    optimize,
    optimize_counts,
    pan_tilt_rotation,
)
from polyhull.placement.targets import sample_target_scenes

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "cells"

# A small empty cell with one mounting rectangle 6 m up, above a 2 m x 2 m x 1.5 m zone:
# a camera there looking (nearly) straight down sees all of Z, so f1_opt = 0 is reachable.
ZONE = Zone((0.0, 0.0, 0.0), (2.0, 2.0, 1.5))


def template(name: str = "cam") -> Camera:
    T = np.eye(4)
    T[:3, 3] = (1.0, 1.0, 3.0)
    # Noise 0: tau = 1 cm, under the lowest voxel centre (5 cm) even 6 m away.
    return Camera(
        name, "depth", Intrinsics(64, 48, 40.0, 40.0, 31.5, 23.5), T, near=0.3, far=12.0, noise=0.0
    )


HIGH = MountingSurface("high", origin=(0.0, 0.0, 6.0), edge_u=(2.0, 0.0, 0.0), edge_v=(0.0, 2.0, 0.0))
WALL = MountingSurface("wall", origin=(0.0, 0.0, 0.5), edge_u=(2.0, 0.0, 0.0), edge_v=(0.0, 0.0, 1.0))
EMPTY_CELL = Cell(name="empty", zone=ZONE, cameras=(template(),), mounting=(WALL, HIGH))
EMPTY_PROBLEM = PlacementProblem.from_cell(EMPTY_CELL, (), grid_shape=(20, 20, 15))


def test_pan_tilt_rotation_is_a_rotation_with_horizontal_image_x():
    for pan, tilt in [(0.0, 0.0), (1.0, 0.5), (-2.5, np.pi / 2), (3.0, -0.3)]:
        R = pan_tilt_rotation(pan, tilt)
        assert np.allclose(R.T @ R, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        assert R[2, 0] == pytest.approx(0.0)  # image x is horizontal
        assert R[:, 2] == pytest.approx(
            [np.cos(tilt) * np.cos(pan), np.cos(tilt) * np.sin(pan), -np.sin(tilt)]
        )
        if tilt < np.pi / 2 - 1e-9:
            assert R[2, 1] < 0  # image down points down in the world


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.02, 0.98), min_size=8, max_size=8))
def test_decode_then_encode_is_the_identity(values):
    param = CameraParameterisation(surfaces=(WALL, HIGH), templates=(template("a"), template("b")))
    x = np.array(values)
    # Keep the surface coordinate away from the seam between surfaces.
    x[[0, 4]] = np.clip(x[[0, 4]], 0.02, 0.98)
    x[[0, 4]] = np.where(np.abs(x[[0, 4]] - 0.5) < 0.02, 0.52, x[[0, 4]])
    cams = param.decode(x)
    for cam, s in zip(cams, param.settings(x), strict=True):
        surface = {"wall": WALL, "high": HIGH}[s.surface]
        assert cam.center == pytest.approx(surface.point(s.a, s.b))
    assert param.encode(cams) == pytest.approx(x, abs=1e-9)


def test_vary_fov_scales_the_focal_length():
    param = CameraParameterisation(surfaces=(HIGH,), templates=(template(),), vary_fov=True)
    assert param.dimension == 5
    x = np.array([0.5, 0.5, 0.5, 1.0, 0.0])
    (cam,) = param.decode(x)
    assert cam.intrinsics.fx == pytest.approx(0.5 * 40.0)
    assert cam.intrinsics.cx == 31.5
    assert param.encode([cam])[4] == pytest.approx(0.0, abs=1e-12)
    (cam,) = param.decode(np.array([0.5, 0.5, 0.5, 1.0, 1.0]))
    assert cam.intrinsics.fy == pytest.approx(2.0 * 40.0)


def test_parameterisation_needs_surfaces_and_counts():
    with pytest.raises(CellError, match="mounting"):
        CameraParameterisation(surfaces=(), templates=(template(),))
    no_mounting = Cell(name="bare", zone=ZONE, cameras=(template(),))
    with pytest.raises(CellError, match="mounting"):
        CameraParameterisation.for_cell(no_mounting)
    param = CameraParameterisation.for_cell(EMPTY_CELL, 3)
    assert [t.name for t in param.templates] == ["cam", "cam2", "cam3"]
    with pytest.raises(PolyhullError, match="entries|numbers"):
        param.decode(np.zeros(3))


def test_stop_criteria_validation():
    with pytest.raises(PolyhullError, match="at least one"):
        StopCriteria(max_evals=None)
    with pytest.raises(PolyhullError):
        StopCriteria(max_evals=0)
    with pytest.raises(PolyhullError):
        StopCriteria(max_seconds=-1.0)


def test_optimiser_reaches_f_opt_and_stops_on_eps():
    result = optimize(
        EMPTY_PROBLEM,
        CameraParameterisation.for_cell(EMPTY_CELL),
        "f1",
        StopCriteria(max_evals=400, eps=1e-9),
        seed=1,
        sigma0=0.3,  # from the centre of the box: explore both surfaces
    )
    assert result.optimum.f1 == 0.0
    assert result.stop_reason == "eps"
    assert result.best.f1 == 0.0
    assert result.evaluations < 400
    (cam,) = result.cameras
    assert cam.center[2] == pytest.approx(6.0)  # it chose the high surface
    # The reported best is what an independent evaluation gives.
    assert evaluate_cameras(EMPTY_PROBLEM, result.cameras) == result.best
    assert np.all(np.diff(result.best_so_far) <= 0)


def test_budget_of_evaluations_and_time():
    param = CameraParameterisation.for_cell(EMPTY_CELL)
    result = optimize(EMPTY_PROBLEM, param, "f3", StopCriteria(max_evals=17), seed=0)
    assert result.evaluations == 17 and result.stop_reason == "evaluations"
    timed = optimize(EMPTY_PROBLEM, param, "f3", StopCriteria(max_evals=None, max_seconds=0.3), seed=0)
    assert timed.stop_reason == "time"
    assert timed.evaluations >= 1
    with pytest.raises(PolyhullError, match="objective"):
        optimize(EMPTY_PROBLEM, param, "f9", StopCriteria(max_evals=1))  # type: ignore[arg-type]


def test_start_point_is_evaluated_first():
    param = CameraParameterisation.for_cell(EMPTY_CELL)
    x0 = param.encode(EMPTY_CELL.cameras)
    for method in ("cma-es", "random"):
        result = optimize(EMPTY_PROBLEM, param, "f1", StopCriteria(max_evals=5), x0=x0, method=method)
        assert result.values[0] == pytest.approx(evaluate_vector(EMPTY_PROBLEM, param, x0).f1)
        assert result.best_value <= result.values[0]


def test_optimize_counts_tries_each_count():
    chosen, results = optimize_counts(
        EMPTY_PROBLEM, EMPTY_CELL, [1, 2], "f1", StopCriteria(max_evals=12), seed=0
    )
    assert [len(r.cameras) for r in results] == [1, 2]
    assert chosen.best_value == min(r.best_value for r in results)
    assert [c.name for c in results[1].cameras] == ["cam", "cam2"]


def test_process_pool_gives_the_inline_result():
    param = CameraParameterisation.for_cell(EMPTY_CELL)
    stop = StopCriteria(max_evals=10)
    inline = optimize(EMPTY_PROBLEM, param, "f3", stop, InlineExecutor(), seed=3)
    with make_executor(workers=2) as pool:
        pooled = optimize(EMPTY_PROBLEM, param, "f3", stop, pool, seed=3)
    # Same samples and the same tell order: the same run, whatever the completion order.
    assert sorted(pooled.values) == pytest.approx(sorted(inline.values))
    assert pooled.best_x == pytest.approx(inline.best_x)


def test_dask_local_cluster_executor():
    distributed = pytest.importorskip("dask.distributed")
    param = CameraParameterisation.for_cell(EMPTY_CELL)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster, distributed.Client(cluster) as client:
        result = optimize(
            EMPTY_PROBLEM, param, "f3", StopCriteria(max_evals=8), client.get_executor(), seed=5
        )
    assert result.evaluations == 8
    assert evaluate_vector(EMPTY_PROBLEM, param, result.best_x) == result.best


def test_cma_es_beats_random_search_on_the_paper_cell():
    # Coarse grid, every 4th pixel and two people keep one evaluation near 0.1 s.
    cell = load_cell(FIXTURES / "paper_cell.toml")
    scenes = sample_target_scenes(cell, n_scenes=2, seed=0)
    problem = PlacementProblem.from_cell(cell, scenes, grid_shape=(30, 30, 18), step=4)
    param = CameraParameterisation.for_cell(cell)
    stop = StopCriteria(max_evals=60)
    best = {
        method: [
            optimize(problem, param, "f3", stop, seed=seed, method=method, sigma0=0.3).best_value
            for seed in range(5)
        ]
        for method in ("cma-es", "random")
    }
    assert np.median(best["cma-es"]) < np.median(best["random"])
