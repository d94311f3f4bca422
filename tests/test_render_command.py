"""``polyhull render``: argument parsing, a smoke test on a cell file, and bad input."""

from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from polyhull.commands import render
from polyhull.errors import GeometryError, PolyhullError, RobotError
from polyhull.frames import load_frames

CELL = textwrap.dedent(
    """
    name = "render test"
    [zone]
    min = [0.0, 0.0, 0.0]
    max = [3.0, 3.0, 2.5]

    [[cameras]]
    name = "a"
    type = "depth"
    resolution = [80, 60]
    intrinsics = [60.0, 60.0, 39.5, 29.5]
    position = [0.1, 0.1, 2.4]
    look_at = [1.5, 1.5, 0.5]
    range = [0.3, 6.0]
    noise = 0.003

    [[cameras]]
    name = "b"
    type = "color"
    resolution = [64, 48]
    intrinsics = [50.0, 50.0, 31.5, 23.5]
    position = [2.9, 2.9, 2.4]
    look_at = [1.5, 1.5, 0.5]
    range = [0.3, 6.0]

    [[obstacles]]
    name = "table"
    box = { center = [2.5, 1.5, 0.375], size = [0.6, 1.2, 0.75] }
    """
)


@pytest.fixture()
def cell_file(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    path.write_text(CELL)
    return path


def run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="polyhull")
    sub = parser.add_subparsers()
    render.register(sub)
    args = parser.parse_args(["render", *argv])
    return int(args.func(args))


def test_render_writes_a_frames_file(cell_file, tmp_path, capsys):
    out = tmp_path / "frames.npz"
    code = run([str(cell_file), "--target", "person:walking:1.8@1.0,1.5", "--seed", "3", "--stamp", "2.5", "--out", str(out)])
    assert code == 0
    loaded = load_frames(out)
    assert set(loaded.frames) == {"a", "b"}
    assert loaded.frames["a"].shape == (60, 80)
    assert loaded.frames["b"].shape == (48, 64)
    assert loaded.stamp == 2.5
    assert loaded.q.shape == (0,)
    text = capsys.readouterr().out
    assert "wrote" in text and "80x60" in text


def test_a_target_outside_the_zone_is_warned_about(cell_file, tmp_path, capsys):
    out = tmp_path / "frames.npz"
    assert run([str(cell_file), "--target", "person@20,0", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "--target person@20,0 lies outside the zone" in err
    assert run([str(cell_file), "--target", "person@1.0,1.5", "--out", str(out)]) == 0
    assert "outside the zone" not in capsys.readouterr().err


def test_targets_show_up_and_exact_is_reproducible(cell_file, tmp_path):
    empty, person, again, mesh_file = (tmp_path / n for n in ("e.npz", "p.npz", "q.npz", "box.stl"))
    assert run([str(cell_file), "--exact", "--out", str(empty)]) == 0
    assert run([str(cell_file), "--exact", "--target", "person@1.2,1.4,0,1.0", "--out", str(person)]) == 0
    e = load_frames(empty).frames["a"].depth
    p = load_frames(person).frames["a"].depth
    assert np.all(p <= e)
    assert (p < e - 0.1).sum() > 20  # the person occludes the floor
    trimesh.creation.box(extents=(0.5, 0.5, 1.0)).export(mesh_file)
    assert run([str(cell_file), "--exact", "--target", f"{mesh_file}@1.2,1.4,0.5", "--out", str(again)]) == 0
    boxed = load_frames(again).frames["a"].depth
    assert (boxed < e - 0.1).sum() > 20


def test_effect_switches(cell_file, tmp_path):
    a, b, c = (tmp_path / n for n in ("a.npz", "b.npz", "c.npz"))
    run([str(cell_file), "--no-noise", "--no-flying-pixels", "--dropout", "0", "--out", str(a)])
    run([str(cell_file), "--exact", "--out", str(b)])
    run([str(cell_file), "--uint16", "--seed", "1", "--out", str(c)])
    da = load_frames(a).frames["a"].depth
    db = load_frames(b).frames["a"].depth
    in_range = (db >= 0.3) & (db <= 6.0)
    np.testing.assert_array_equal(da[in_range], db[in_range])
    assert np.all(da[~in_range] == 0)
    mm = load_frames(c).frames["a"].depth.astype(np.float64) * 1000
    np.testing.assert_allclose(mm, np.round(mm), atol=2e-3)


def test_parse_target():
    spec = render.parse_target("person:reaching:1.62:0.3@1,2,0.1,1.5")
    assert spec.is_person and spec.pose == "reaching"
    assert (spec.height, spec.phase, spec.xy, spec.z, spec.yaw) == (1.62, 0.3, (1.0, 2.0), 0.1, 1.5)
    default = render.parse_target("person")
    assert (default.pose, default.height, default.xy, default.z) == ("standing", 1.75, None, None)
    mesh = render.parse_target("parts/a@b.stl@1,2")
    assert mesh.source == "parts/a@b.stl" and mesh.xy == (1.0, 2.0) and not mesh.is_person
    for bad, match in (
        ("person:dancing", "pose"),
        ("person@1", "x,y"),
        ("person@1,2,3,4,5", "x,y"),
        ("person@1,zwei", "numbers"),
        ("person:standing:tall", "numbers"),
        ("@1,2", "missing"),
    ):
        with pytest.raises(PolyhullError, match=match):
            render.parse_target(bad)


def test_parse_q():
    np.testing.assert_array_equal(render.parse_q(["0,-0.6", "1.2"]), [0.0, -0.6, 1.2])
    assert render.parse_q(None) is None
    with pytest.raises(PolyhullError, match="--q"):
        render.parse_q(["1,x"])
    with pytest.raises(PolyhullError, match="finite"):
        render.parse_q(["nan"])


def test_bad_input_is_a_polyhull_error(cell_file, tmp_path):
    out = str(tmp_path / "x.npz")
    with pytest.raises(GeometryError, match="does not exist"):
        run([str(cell_file), "--target", "missing.stl", "--out", out])
    with pytest.raises(RobotError, match="no robot"):
        run([str(cell_file), "--q", "0.1", "--out", out])
    with pytest.raises(PolyhullError, match=".npz"):
        run([str(cell_file), "--out", str(tmp_path / "x.txt")])
    with pytest.raises(PolyhullError, match="dropout"):
        run([str(cell_file), "--dropout", "2", "--out", out])
    with pytest.raises(PolyhullError):
        run([str(tmp_path / "nope.toml"), "--out", out])
    assert not (tmp_path / "x.npz").exists()


def test_robot_cell_uses_default_q(tmp_path):
    cell = Path(__file__).parent.parent / "fixtures" / "cells" / "small_cell.toml"
    out = tmp_path / "robot.npz"
    assert run([str(cell), "--exact", "--out", str(out)]) == 0
    loaded = load_frames(out)
    np.testing.assert_allclose(loaded.q, [0.0, -0.6, 1.2, 0.0, 0.8, 0.0])
    moved = tmp_path / "moved.npz"
    assert run([str(cell), "--exact", "--q=1.0,-0.6,1.2,0,0.8,0", "--out", str(moved)]) == 0
    a = loaded.frames["sw"].depth
    b = load_frames(moved).frames["sw"].depth
    assert not np.array_equal(a, b)
