"""Replay: the bag fixture gives the verdicts of the in-memory run, the command writes one
JSON object per cycle, and recorded pace follows the stamps."""

from __future__ import annotations

import importlib.util
import itertools
import json
from pathlib import Path
from types import ModuleType, SimpleNamespace

import numpy as np
import pytest
from conftest import FIXTURES, SMALL_CELL

from polyhull.cell import Cell
from polyhull.cli import main
from polyhull.monitor import Monitor
from polyhull.recordings import Cycle, open_recording, recording_cycles
from polyhull.recordings.replay import cycle_record, replay

BAG = FIXTURES / "recordings" / "small_walk"
PNG = FIXTURES / "recordings" / "small_walk_png"
_SAME = ("min_distance", "closest_link", "speed_scale", "separation_distance", "faults", "counts", "q", "stamp")


def _make_recordings() -> ModuleType:
    path = FIXTURES / "recordings" / "make_recordings.py"
    spec = importlib.util.spec_from_file_location("make_recordings", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_replay_of_the_bag_equals_the_in_memory_run(small_cell: Cell, fresh_monitor: Monitor) -> None:
    """The first walk cycles read from the MCAP bag give the same verdicts as the same
    cycles rendered by the simulator and stepped in memory."""
    mk = _make_recordings()
    entries = mk.timeline()
    first = next(i for i, e in enumerate(entries) if e["phase"] == "walk")
    chosen = slice(first, first + 3)
    rendered = mk.render(entries[chosen])
    memory = []
    for c in rendered:
        v = fresh_monitor.step(c.frames, c.q, stamp=c.stamp, q_stamp=c.stamp)
        memory.append(cycle_record(Cycle(c.stamp, dict(c.frames), c.q, c.stamp), v))
    fresh_monitor.reset()
    cycles = itertools.islice(recording_cycles(open_recording(BAG, small_cell), small_cell), chosen.start, chosen.stop)
    replayed = [cycle_record(c, v) for c, v in replay(fresh_monitor, cycles, fast=True)]
    assert len(replayed) == 3
    assert any(r["counts"]["unexplained_pixels"] > 2000 for r in replayed)  # the person is in view
    for a, b in zip(memory, replayed, strict=True):
        for key in _SAME:
            if key == "stamp":
                assert a[key] == pytest.approx(b[key], abs=1e-6)
            else:
                assert a[key] == b[key], key


def test_replay_command_writes_json_lines(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cycles.jsonl"
    plot = tmp_path / "timeline.png"
    code = main(
        ["replay", str(SMALL_CELL), str(PNG), "--fast", "--seconds", "0.4", "--json-lines", str(out), "--plot", str(plot), "--json"]
    )
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert summary["cycles"] == len(records) == 3
    assert [r["stamp"] for r in records] == sorted(r["stamp"] for r in records)
    for r in records:
        assert r["cameras"] == ["ne", "sw"] and r["missing"] == []
        assert 0.0 <= r["speed_scale"] <= 1.0 and r["cycle_ms"] > 0 and r["q"] is not None
        assert set(r) >= {"min_distance", "separation_distance", "faults", "timings_ms", "counts"}
    # the timeline plot of the same cycles
    assert summary["written"] == [str(plot)]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_replay_plot_must_be_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(SMALL_CELL), str(PNG), "--plot", str(tmp_path / "t.svg")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--plot" in err and ".png" in err


def test_replay_command_bad_recording_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(SMALL_CELL), str(tmp_path / "missing.mcap"), "--fast"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.mcap: no such recording" in err


def test_recorded_pace_follows_the_stamps() -> None:
    """At recorded pace each cycle waits for its stamp's offset from the first; --fast never waits."""
    now = [100.0]
    slept: list[float] = []

    def sleep(s: float) -> None:
        slept.append(s)
        now[0] += s

    class Stub:
        def step(self, frames, q, stamp=None, q_stamp=None):  # noqa: ANN001, ANN202
            now[0] += 0.05  # the monitor's own time
            return SimpleNamespace(stamp=stamp)

    cycles = [Cycle(t, {}, np.zeros(1), t) for t in (5.0, 5.2, 5.25, 5.6)]
    done = list(replay(Stub(), cycles, clock=lambda: now[0], sleep=sleep))  # type: ignore[arg-type]
    assert [v.stamp for _, v in done] == [5.0, 5.2, 5.25, 5.6]
    # 0.2 s after the first, minus its 0.05 s step; the third is due as the second's step
    # ends (no wait); the fourth is due 0.6 s after the first, 0.3 s after the third's step
    assert slept == pytest.approx([0.15, 0.3])
    slept.clear()
    list(replay(Stub(), cycles, fast=True, clock=lambda: now[0], sleep=sleep))  # type: ignore[arg-type]
    assert slept == []
