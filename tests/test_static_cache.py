"""The static model's disk cache: a model read back is the one built, a damaged entry is
rebuilt, a cache that cannot be written is said, and the command line shows where it is."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

import polyhull.engine.static_model as static_module
from polyhull import cli
from polyhull.cell import Cell
from polyhull.engine.static_model import StaticModel
from polyhull.monitor import Monitor
from polyhull.person import make_person
from polyhull.simulator import Simulator

ROOT = Path(__file__).resolve().parents[1]
CELL = ROOT / "fixtures" / "cells" / "small_cell.toml"
FRAMES = ROOT / "fixtures" / "frames" / "small_walk_000.npz"


@pytest.fixture()
def always_cached(monkeypatch: pytest.MonkeyPatch) -> None:
    """Cache every build (the small cell's takes about a second, under ``CACHE_AFTER``)."""
    monkeypatch.setattr(static_module, "CACHE_AFTER", -1.0)


def _messages(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name.startswith("polyhull") and r.levelno == level]


def _same_model(a: StaticModel, b: StaticModel) -> None:
    for name in ("hull", "region_r2", "region", "solids"):
        assert getattr(a, name).volume() == pytest.approx(getattr(b, name).volume(), rel=1e-12, abs=1e-12), name
        assert getattr(a, name).num_tri() == getattr(b, name).num_tri(), name
    assert [f.volume() for f in a.free] == pytest.approx([f.volume() for f in b.free], rel=1e-12)
    assert a.sheets == b.sheets
    assert all(np.array_equal(x, y) for x, y in zip(a.sheet_heights, b.sheet_heights, strict=True))
    assert np.array_equal(a.touch.table, b.touch.table)
    assert [(r.rule, r.volume) for r in a.removed] == [(r.rule, r.volume) for r in b.removed]
    assert a.hull_volume == b.hull_volume


def test_a_cached_model_is_the_built_one_and_the_log_says_where(
    small_cell: Cell, small_sim: Simulator, tmp_path: Path, always_cached: None, caplog: pytest.LogCaptureFixture
) -> None:
    """Built once (INFO: building, then the cache file's path), read the second time
    (DEBUG only); the model read gives the same cycle as the model built."""
    caplog.set_level(logging.DEBUG, logger="polyhull")
    refs = small_sim.reference()
    built = StaticModel.load_or_build(small_cell, refs, cache_dir=tmp_path)
    (entry,) = tmp_path.glob("static-*.npz")
    info = _messages(caplog, logging.INFO)
    assert info[0] == "building the static model of cell 'small cell'"
    assert "cached in" in info[1] and str(entry) in info[1]
    caplog.clear()
    read = StaticModel.load_or_build(small_cell, refs, cache_dir=tmp_path)
    assert _messages(caplog, logging.INFO) == [] and _messages(caplog, logging.WARNING) == []
    assert any(str(entry) in m and "read from" in m for m in _messages(caplog, logging.DEBUG))
    _same_model(built, read)
    # the same frame through a monitor of each: the same distance, region and removals
    person = make_person(height=1.75, pose="reaching", position=(1.3, 2.1), yaw=0.4)
    q = np.asarray(small_cell.robot.q, dtype=np.float64)
    frames = small_sim.render(q, targets=[person], seed=7, stamp=1.0)
    verdicts = [Monitor(small_cell, references=refs, static=s, warm_up=False).step(frames, q, stamp=1.0) for s in (built, read)]
    assert verdicts[0].faults == verdicts[1].faults
    assert verdicts[0].min_distance == verdicts[1].min_distance
    # the lazily built region unites the static mesh with this cycle's pieces: a mesh read
    # back keeps its volume, not manifold3d's internal order, so the union's rounding
    # differs (2e-11 relative measured)
    assert verdicts[0].region.volume() == pytest.approx(verdicts[1].region.volume(), rel=1e-9)
    assert [r.rule for r in verdicts[0].removed] == [r.rule for r in verdicts[1].removed]


def test_a_damaged_entry_is_rebuilt_and_said(
    small_cell: Cell, small_sim: Simulator, tmp_path: Path, always_cached: None, caplog: pytest.LogCaptureFixture
) -> None:
    refs = small_sim.reference()
    built = StaticModel.load_or_build(small_cell, refs, cache_dir=tmp_path)
    (entry,) = tmp_path.glob("static-*.npz")
    entry.write_bytes(entry.read_bytes()[:1000])  # a write cut short
    caplog.set_level(logging.INFO, logger="polyhull")
    again = StaticModel.load_or_build(small_cell, refs, cache_dir=tmp_path)
    (warning,) = _messages(caplog, logging.WARNING)
    assert str(entry) in warning and "could not be read" in warning and "rebuilding" in warning
    assert "building the static model of cell 'small cell'" in _messages(caplog, logging.INFO)
    _same_model(built, again)
    assert entry.stat().st_size > 1000  # written again, whole


def test_a_cache_that_cannot_be_written_is_said_and_the_model_still_built(
    small_cell: Cell, small_sim: Simulator, tmp_path: Path, always_cached: None, caplog: pytest.LogCaptureFixture
) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    caplog.set_level(logging.INFO, logger="polyhull")
    model = StaticModel.load_or_build(small_cell, small_sim.reference(), cache_dir=blocker / "polyhull")
    (warning,) = _messages(caplog, logging.WARNING)
    assert "not cached" in warning and str(blocker / "polyhull") in warning and "POLYHULL_CACHE_DIR" in warning
    assert model.region.volume() > 0


def test_the_command_line_shows_the_build_on_stderr_only(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, always_cached: None, capsys: pytest.CaptureFixture[str]
) -> None:
    """``polyhull run`` with an empty cache: its stderr says that the static model is built
    and where it is cached, stdout stays one JSON document; the second run reads the cache
    and says nothing of it. The command leaves the library's logger as it found it."""
    monkeypatch.setenv("POLYHULL_CACHE_DIR", str(tmp_path))
    logger = logging.getLogger("polyhull")
    handlers, level = list(logger.handlers), logger.level
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), "--json"]) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    (entry,) = tmp_path.glob("static-*.npz")
    lines = captured.err.splitlines()
    assert "polyhull run: building the static model of cell 'small cell'" in lines, captured.err
    assert any(line.startswith("polyhull run: static model built in") and str(entry) in line for line in lines)
    assert logger.handlers == handlers and logger.level == level
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), "--json"]) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    assert "static model" not in captured.err
