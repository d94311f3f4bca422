"""``polyhull place``: outputs, the optimised cell file, and errors."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from polyhull.cellfile import load_cell
from polyhull.commands import place
from polyhull.errors import PolyhullError
from polyhull.placement.optimizer import pan_tilt_rotation
from polyhull.placement.report import rotation_to_quaternion, toml_text

CELL = """
name = "tiny cell"

[zone]
min = [0.0, 0.0, 0.0]
max = [3.0, 3.0, 2.0]

[[cameras]]
name = "a"
resolution = [80, 60]
intrinsics = [60.0, 60.0, 39.5, 29.5]
position = [0.1, 0.1, 1.9]
look_at = [1.5, 1.5, 0.5]
range = [0.3, 6.0]

[[cameras]]
name = "b"
type = "color"
resolution = [80, 60]
intrinsics = [60.0, 60.0, 39.5, 29.5]
position = [2.9, 2.9, 1.9]
look_at = [1.5, 1.5, 0.5]
range = [0.3, 6.0]
noise = 0.0

[[obstacles]]
name = "table"
box = { center = [2.2, 1.0, 0.4], size = [0.8, 0.6, 0.8] }

[[obstacles]]
name = "pillar"
mesh = "pillar.stl"
pose = { position = [0.6, 2.4, 0.0] }

[[mounting]]
name = "ceiling"
origin = [0.0, 0.0, 1.95]
edge_u = [3.0, 0.0, 0.0]
edge_v = [0.0, 3.0, 0.0]

[[mounting]]
name = "wall_west"
origin = [0.0, 0.0, 1.2]
edge_u = [0.0, 3.0, 0.0]
edge_v = [0.0, 0.0, 0.7]
"""


@pytest.fixture()
def cell_file(tmp_path: Path) -> Path:
    import trimesh

    pillar = trimesh.creation.cylinder(radius=0.15, height=2.0).apply_translation([0.0, 0.0, 1.0])
    (tmp_path / "cell").mkdir()
    pillar.export(tmp_path / "cell" / "pillar.stl")
    path = tmp_path / "cell" / "tiny.toml"
    path.write_text(CELL)
    return path


def run(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    place.register(sub)
    args = parser.parse_args(["place", *argv])
    return int(args.func(args))


def test_place_writes_report_plot_cell_and_scene(cell_file: Path, tmp_path: Path, capsys):
    out = tmp_path / "out"
    code = run(
        str(cell_file), "--budget-evals", "14", "--grid", "15,15,10", "--workers", "1",
        "--scenes", "2", "--out", str(out), "--no-progress", "--cameras", "2-3",
        "--importance", "0,0,0,3,3,1:3",
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "f3: before" in printed and "f_opt" in printed
    report = json.loads((out / "report.json").read_text())
    assert report["objective"] == "f3"
    assert report["grid"]["shape"] == [15, 15, 10]
    assert [r["cameras"] for r in report["runs"]] == [2, 3]
    assert all(r["evaluations"] == 14 for r in report["runs"])
    for name in ("f1", "f2", "f3", "f4"):
        for when in ("before", "after"):
            entry = report[when][name]
            assert entry["value"] >= entry["f_opt"] - 1e-9
            assert entry["gap"] == pytest.approx(entry["value"] - entry["f_opt"])
    # f2 weighs the lower metre three times.
    assert report["after"]["f2"]["value"] > report["after"]["f1"]["value"]
    # The chosen placement is the best run's.
    best = min(r["best"] for r in report["runs"])
    assert report["after"]["f3"]["value"] == pytest.approx(best)
    md = (out / "report.md").read_text()
    assert "| f3 |" in md and "Cameras after" in md
    assert (out / "convergence.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The optimised cell reads back, with the chosen cameras and the relative mesh path fixed.
    placed = load_cell(out / "tiny_placed.toml")
    assert len(placed.cameras) == len(report["cameras_after"])
    for cam, summary in zip(placed.cameras, report["cameras_after"], strict=True):
        assert cam.center == pytest.approx(summary["position"], abs=1e-4)
        assert cam.T_world_camera[:3, :3] @ [0, 0, 1] == pytest.approx(summary["look_direction"], abs=1e-3)
    assert [o.name for o in placed.obstacles] == ["table", "pillar"]
    assert placed.obstacles[1].mesh.volume == pytest.approx(load_cell(cell_file).obstacles[1].mesh.volume)
    assert placed.cameras[1].kind == "color"
    scene = out / "scene.html"
    try:
        import polyhull_viewer  # noqa: F401
    except ImportError:
        assert not scene.exists()
        assert "no scene.html" in printed
    else:
        assert scene.exists() and scene.stat().st_size > 1000


def test_place_errors(cell_file: Path, tmp_path: Path):
    with pytest.raises(SystemExit):
        run(str(cell_file), "--grid", "10,10")
    with pytest.raises(PolyhullError, match="--cameras"):
        place.parse_counts("x")
    with pytest.raises(PolyhullError, match="A <= B, got '5-2'"):
        place.parse_counts("5-2")
    for workers in ("0", "-1"):
        with pytest.raises(PolyhullError, match=f"--workers must be an integer >= 1, got {workers}"):
            run(str(cell_file), "--workers", workers)
    with pytest.raises(PolyhullError, match="--seed must be >= 0"):
        run(str(cell_file), "--seed", "-1", "--workers", "1")
    with pytest.raises(PolyhullError, match="--importance"):
        place.parse_importance(["0,0,0,1,1:2"])
    no_mounting = tmp_path / "cell" / "bare.toml"
    no_mounting.write_text(CELL.split("[[mounting]]")[0])
    with pytest.raises(PolyhullError, match="mounting"):
        run(str(no_mounting), "--budget-evals", "2", "--workers", "1", "--no-progress")
    with pytest.raises(PolyhullError, match="budget-evals"):
        run(str(cell_file), "--budget-evals", "0", "--workers", "1")
    for seconds in ("0", "-1", "nan"):
        with pytest.raises(PolyhullError, match="--budget-seconds"):
            run(str(cell_file), "--budget-seconds", seconds, "--workers", "1")


def test_one_evaluation_is_singular(cell_file: Path, tmp_path: Path, capsys):
    code = run(
        str(cell_file), "--budget-evals", "1", "--grid", "8,8,6", "--workers", "1", "--scenes", "1",
        "--out", str(tmp_path / "one"), "--no-progress",
    )
    assert code == 0
    assert "in 1 evaluation, " in capsys.readouterr().out


def test_parse_helpers():
    assert place.parse_grid("126,90,66") == (126, 90, 66)
    assert place.parse_counts("2-4") == [2, 3, 4]
    assert place.parse_counts("1,5") == [1, 5]
    imp = place.parse_importance(["0,0,0,1,1,1:2.5"])
    assert imp.regions[0].weight == 2.5


def test_quaternion_round_trip_and_toml_writer():
    from polyhull.camera import quaternion_to_rotation

    rng = np.random.default_rng(0)
    for _ in range(50):
        R = pan_tilt_rotation(rng.uniform(-np.pi, np.pi), rng.uniform(-1.5, 1.5707963))
        q = rotation_to_quaternion(R)
        assert quaternion_to_rotation(np.array(q)) == pytest.approx(R, abs=1e-12)
    # 180 degree rotations take the other branch.
    for R in (np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])):
        assert quaternion_to_rotation(np.array(rotation_to_quaternion(R))) == pytest.approx(R)
    text = toml_text({"a": 1, "t": {"x": [1.0, 2.0], "s": "q\""}, "arr": [{"b": {"c": True}}]}, header="h")
    import tomllib

    assert tomllib.loads(text) == {"a": 1, "t": {"x": [1.0, 2.0], "s": "q\""}, "arr": [{"b": {"c": True}}]}


def test_place_on_a_dask_scheduler(cell_file: Path, tmp_path: Path, capsys):
    distributed = pytest.importorskip("dask.distributed")
    out = tmp_path / "dask"
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        code = run(
            str(cell_file), "--budget-evals", "6", "--grid", "12,12,8", "--scenes", "1",
            "--scheduler", cluster.scheduler_address, "--out", str(out), "--no-progress",
        )
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["settings"]["scheduler"].startswith("inproc://")
    assert report["runs"][0]["evaluations"] == 6
    with pytest.raises(PolyhullError, match="Dask scheduler"):
        run(str(cell_file), "--budget-evals", "2", "--scheduler", "nonsense://host:1",
            "--out", str(out), "--no-progress")
