"""Teaching the background: statistics with known noise, the robot left out, refusal of a
moving scene, the taught band in the static model (and its cache key), and dark-surface
dropouts taught as static."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import FIXTURES, make_camera

from polyhull.background import TaughtBackground, TaughtCamera, load_background, save_background
from polyhull.cell import Cell
from polyhull.cellfile import load_cell
from polyhull.cli import main
from polyhull.commands.teach import reference_in_cell_file
from polyhull.engine.static_model import StaticCamera, model_key
from polyhull.errors import CellError
from polyhull.monitor import Monitor
from polyhull.recordings import open_recording
from polyhull.recordings.write import RecordedCycle, write_folder
from polyhull.simulator import SensorEffects, Simulator
from polyhull.teaching import PixelStatistics, TeachingError, teach

BAG = FIXTURES / "recordings" / "small_walk"
PNG = FIXTURES / "recordings" / "small_walk_png"


def _cell_copy(tmp_path: Path) -> Path:
    """The small cell in a scratch directory laid out like fixtures/ (relative paths hold)."""
    (tmp_path / "cells").mkdir()
    for d in ("cameras", "robots"):
        (tmp_path / d).symlink_to(FIXTURES / d)
    path = tmp_path / "cells" / "small_cell.toml"
    path.write_text((FIXTURES / "cells" / "small_cell.toml").read_text())
    return path


def test_statistics_recover_known_noise() -> None:
    """A plane at 2 m with N(0, 1 cm) noise and 30 % dropouts on one column block: the median,
    the MAD sigma, the exact min/max and the valid share come out as drawn."""
    cam = make_camera(width=48, height=32, far=6.0)
    rng = np.random.default_rng(7)
    stats = PixelStatistics(cam, max_samples=60)
    frames = []
    for _ in range(150):
        d = (2.0 + 0.01 * rng.standard_normal(cam.shape)).astype(np.float32)
        drop = rng.random(cam.shape) < 0.3
        drop[:, :24] = False
        d[drop] = 0.0
        frames.append(d)
        stats.add(d)
    t = stats.result(min_valid_share=0.8)
    stack = np.stack(frames)
    valid = stack > 0
    assert np.array_equal(t.valid_share, (valid.sum(0) / 150).astype(np.float32))
    assert np.array_equal(t.min, np.where(valid, stack, np.inf).min(0))
    assert np.array_equal(t.max, np.where(valid, stack, -np.inf).max(0))
    assert np.all(t.observed == 150)
    # the median of >= 60 samples of N(2, 0.01): within 4 standard errors everywhere
    assert np.abs(t.median - 2.0).max() < 4 * 1.26 * 0.01 / np.sqrt(60 * 0.7)
    # MAD sigma: its median over the pixels within 5 % of the truth
    assert np.median(t.sigma) == pytest.approx(0.01, rel=0.05)
    # the 30 % dropout half is static-invalid, the other half taught valid
    assert t.static_invalid[:, 24:].mean() > 0.99 and not t.static_invalid[:, :24].any()
    assert len(stats._samples) < 2 * 60  # decimated: memory bounded


def test_covered_pixels_are_not_taught() -> None:
    cam = make_camera(width=16, height=12)
    stats = PixelStatistics(cam)
    covered = np.zeros(cam.shape, dtype=bool)
    covered[:, :8] = True
    for _ in range(10):
        stats.add(np.full(cam.shape, 2.0, dtype=np.float32), covered)
    t = stats.result()
    assert np.all(t.observed[:, :8] == 0) and np.all(t.observed[:, 8:] == 10)
    assert not t.taught[:, :8].any() and not t.static_invalid[:, :8].any()
    assert t.taught_valid[:, 8:].all()


def test_static_camera_uses_the_taught_band() -> None:
    """Taught-valid pixels take the taught median as reference and the taught band;
    static-invalid pixels free nothing; pixels not taught keep the CAD reference."""
    cam = make_camera(width=16, height=12)
    B = np.full(cam.shape, 3.0)
    ones = np.ones(cam.shape, dtype=np.float32)
    observed = np.full(cam.shape, 20.0, dtype=np.float32)
    observed[:, :4] = 0.0  # hidden by the robot throughout
    share = ones.copy()
    share[:, 12:] = 0.3  # a dark surface
    taught = TaughtCamera(
        observed=observed, valid_share=share, median=2.5 * ones, sigma=0.002 * ones,
        min=2.45 * ones, max=2.6 * ones, frames=20,
    )
    plain = StaticCamera.build(cam, B, 4)
    s = StaticCamera.build(cam, B, 4, taught)
    mid = (slice(None), slice(5, 11))
    assert np.allclose(s.reference[mid], 2.5) and np.all(s.lower[mid] <= 2.45) and np.all(s.upper[mid] >= 2.6)
    assert np.all(s.free_static[:, 12:] <= cam.near)  # frees nothing (float32 rounded down)
    assert np.all(s.free_static[mid] > cam.near) and np.all(s.free_static[mid] < 2.45)
    assert np.array_equal(s.reference[:, :3], plain.reference[:, :3])
    assert np.array_equal(s.free_static[:, :3], plain.free_static[:, :3])


def test_taught_background_enters_the_cache_key(small_cell: Cell, small_sim: Simulator, tmp_path: Path) -> None:
    refs = small_sim.reference()
    shape = small_cell.cameras[0].shape
    ones = np.ones(shape, dtype=np.float32)
    cam = TaughtCamera(observed=10 * ones, valid_share=ones, median=2 * ones, sigma=0.01 * ones, min=ones, max=3 * ones, frames=10)
    bg = TaughtBackground({"sw": cam})
    other = TaughtBackground({"sw": dataclasses.replace(cam, median=2.001 * ones)})
    keys = {
        model_key(small_cell, refs),
        model_key(dataclasses.replace(small_cell, background=bg), refs),
        model_key(dataclasses.replace(small_cell, background=other), refs),
    }
    assert len(keys) == 3
    # and it survives the file
    path = save_background(tmp_path / "bg.npz", bg)
    loaded = load_background(path, small_cell.cameras)
    assert model_key(dataclasses.replace(small_cell, background=loaded), refs) == model_key(
        dataclasses.replace(small_cell, background=bg), refs
    )


def test_bad_background_file_is_one_line(tmp_path: Path) -> None:
    cell_path = _cell_copy(tmp_path)
    np.savez(tmp_path / "cells" / "bg.npz", **{"sw.median": np.ones((3, 3), dtype=np.float32)})
    text = cell_path.read_text().replace('name = "small cell"', 'name = "small cell"\nbackground = "bg.npz"')
    cell_path.write_text(text)
    with pytest.raises(CellError) as exc:
        load_cell(cell_path)
    message = str(exc.value)
    assert "\n" not in message and "small_cell.toml: background:" in message and "missing field 'sw.observed'" in message
    cell_path.write_text(text.replace("bg.npz", "nothing.npz"))
    with pytest.raises(CellError, match="background: expected an existing taught background"):
        load_cell(cell_path)


def test_teach_refuses_a_moving_scene(small_cell: Cell) -> None:
    """The fixture bag's whole length includes the person walking: refused, naming a camera."""
    with pytest.raises(TeachingError, match=r"camera '(sw|ne)': \d+\.\d % of its pixels varied beyond the noise"):
        teach(small_cell, open_recording(BAG, small_cell), seconds=10.0)


def test_teach_command_on_the_png_fixture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``polyhull teach --json`` prints only JSON, writes the background and heat maps and
    references the background from the cell file, which then loads with it; a moving scene
    is one line on stderr and exit code 2."""
    cell_path = _cell_copy(tmp_path)
    assert main(["teach", str(cell_path), str(PNG), "--seconds", "1.1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["cameras"]) == {"sw", "ne"}
    for name, c in out["cameras"].items():
        assert c["frames"] == 6 and c["moving_share"] < 0.01 and Path(c["heat_map"]).is_file(), name
    cell = load_cell(cell_path)
    assert cell.background is not None and set(cell.background.cameras) == {"sw", "ne"}
    assert main(["teach", str(cell_path), str(PNG), "--seconds", "30", "--no-update-cell"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("polyhull teach: error: camera '")


def test_reference_in_cell_file_replaces_the_key(tmp_path: Path) -> None:
    cell_path = _cell_copy(tmp_path)
    bg = TaughtBackground({})
    for name in ("a.npz", "b.npz"):
        shape = (240, 320)
        ones = np.ones(shape, dtype=np.float32)
        bg = TaughtBackground({"sw": TaughtCamera(observed=ones, valid_share=ones, median=ones, sigma=ones, min=ones, max=ones, frames=1)})
        save_background(tmp_path / "cells" / name, bg)
        assert reference_in_cell_file(cell_path, tmp_path / "cells" / name) == name
    text = cell_path.read_text()
    assert text.count("background =") == 1 and 'background = "b.npz"' in text
    loaded = load_cell(cell_path).background
    assert loaded is not None and loaded.path == (tmp_path / "cells" / "b.npz").resolve()


DARK = (slice(128, 160), slice(32, 64))  # a floor patch of camera sw, away from the robot


def _dark_frames(cell: Cell, sim: Simulator, n: int, seed0: int) -> list[RecordedCycle]:
    """Frames in which a dark floor patch of camera sw loses 60 % of its pixels at random."""
    assert cell.robot is not None
    q = np.asarray(cell.robot.q)
    out = []
    for i in range(n):
        stamp = 10.0 + 0.2 * i
        frames = sim.render(q, seed=seed0 + i, stamp=stamp, effects=SensorEffects(uint16=True))
        d = np.array(frames["sw"].depth)
        rng = np.random.default_rng(seed0 + i)
        patch = d[DARK]
        patch[rng.random(patch.shape) < 0.6] = 0.0
        frames = dict(frames)
        frames["sw"] = dataclasses.replace(frames["sw"], depth=d)
        out.append(RecordedCycle(stamp, frames, q))
    return out


def test_dark_surface_dropouts_become_static(tmp_path: Path, small_cell: Cell, small_sim: Simulator, fresh_monitor: Monitor) -> None:
    """Taught, the dark patch is static-invalid: no unexplained pixel and no dynamic region
    there; with the CAD background alone the same frame makes it dynamic."""
    rec = write_folder(tmp_path / "dark", small_cell, _dark_frames(small_cell, small_sim, 10, 100))
    taught = teach(small_cell, open_recording(rec, small_cell), seconds=5.0)
    sw = taught.background.cameras["sw"]
    assert sw.static_invalid[DARK].mean() > 0.9
    assert [c.camera for c in taught.cameras] == ["sw", "ne"]
    frame = _dark_frames(small_cell, small_sim, 1, 500)[0]
    cad = fresh_monitor.step(frame.frames, frame.q, stamp=frame.stamp)
    cad_images = fresh_monitor.last_images
    cell_taught = dataclasses.replace(small_cell, background=taught.background)
    monitor = Monitor(cell_taught, references=small_sim.reference())
    learned = monitor.step(frame.frames, frame.q, stamp=frame.stamp)
    learned_images = monitor.last_images
    assert cad_images is not None and learned_images is not None

    def segments(images) -> np.ndarray:  # noqa: ANN001 - pixels with an occluded segment
        return images.free["sw"][DARK] < images.end["sw"][DARK]

    dropped = int((np.asarray(frame.frames["sw"].depth)[DARK] == 0).sum())
    assert dropped > 500
    assert segments(cad_images).sum() >= 0.9 * dropped  # the CAD background: dynamic
    # taught: the static-invalid pixels are static, nothing dynamic comes from them; the few
    # patch pixels that happened to be valid in >= 80 % of the taught frames may still be
    assert not (segments(learned_images) & sw.static_invalid[DARK]).any()
    assert segments(learned_images).sum() <= 0.05 * dropped
    assert cad.counts["unexplained_pixels"] - learned.counts["unexplained_pixels"] >= 0.9 * dropped


def test_a_moved_camera_disagrees_with_the_cad_model(small_cell: Cell) -> None:
    """Teaching the PNG fixture against a cell in which camera sw sits 15 cm lower than where
    it recorded: most of its pixels leave the CAD band, camera ne's do not."""
    cams = list(small_cell.cameras)
    T = np.array(cams[0].T_world_camera)
    T[2, 3] -= 0.15
    cams[0] = dataclasses.replace(cams[0], T_world_camera=T)
    moved = dataclasses.replace(small_cell, cameras=tuple(cams))
    result = teach(moved, open_recording(PNG, moved), seconds=1.1)
    share = {c.camera: c.disagree_share for c in result.cameras}
    assert share["sw"] is not None and share["sw"] > 0.3
    assert share["ne"] is not None and share["ne"] < 0.02
    sw = next(c for c in result.cameras if c.camera == "sw")
    img = sw.heat_map()
    assert img.shape == (240, 320, 3) and img.dtype == np.uint8
    warm = (img[..., 0] == 255) & (img[..., 2] == 0)  # yellow to red: outside the band
    assert warm.mean() == pytest.approx((sw.ratio[sw.compared] > 1).sum() / img[..., 0].size, abs=1e-9)
