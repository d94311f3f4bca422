"""``polyhull run``: one cycle from a recorded frames file, as text or as JSON only."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from polyhull import cli

ROOT = Path(__file__).resolve().parents[1]
CELL = ROOT / "fixtures" / "cells" / "small_cell.toml"
FRAMES = ROOT / "fixtures" / "frames" / "small_walk_000.npz"


def test_json_with_export_keeps_stdout_json_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "regions"
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), "--json", "--export", str(out)]) == 0
    captured = capsys.readouterr()
    verdict = json.loads(captured.out)  # the whole of stdout is one JSON document
    assert verdict["volume_hull"] > 0
    assert "wrote" in captured.err
    assert sorted(p.name for p in out.iterdir()) == ["hull.ply", "region.ply", "robot_occlusion.ply"]


class _Terminal:
    """A stderr that says it is a terminal 100 columns wide (tqdm draws its bar there)."""

    def __init__(self) -> None:
        self.text: list[str] = []

    def write(self, s: str) -> int:
        self.text.append(s)
        return len(s)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return True

    def fileno(self) -> int:
        raise OSError("no descriptor")


def test_building_the_regions_shows_a_bar_on_a_terminal_only(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The volumes build every manifold (seconds to a minute on a large cell): a progress
    bar on a terminal's stderr names the region being built; stdout stays JSON only, and a
    stderr that is not a terminal (a log, a pipe) gets no bar."""
    monkeypatch.setenv("COLUMNS", "100")
    terminal = _Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["volume_region"] > 0
    bar = "".join(terminal.text)
    assert "building the regions" in bar and "region_r2" in bar and "region_dynamic" in bar, bar
    monkeypatch.undo()
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), "--json"]) == 0
    captured = capsys.readouterr()
    assert "building the regions" not in captured.err
    json.loads(captured.out)


def test_text_summarises_removals_per_rule(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("removed")]
    rules = [line.split()[1].rstrip(":") for line in lines]
    assert rules, "the noisy small-walk frames leave artifacts to remove"
    assert len(rules) == len(set(rules)), lines  # one line per rule
    assert all(" part" in line and "m^3" in line for line in lines)


def test_the_distance_line_names_the_link_or_why_there_is_none(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A measured cycle names its closest link; a stop verdict (here the paper cell's
    frames of the two cameras the small cell names too, 640 x 480 for its 320 x 240) says
    it measured nothing."""
    from polyhull.frames import load_frames, save_frames

    assert cli.main(["run", str(CELL), "--frames", str(FRAMES)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("min distance"))
    assert " m to " in line and "None" not in line, line
    paper = load_frames(ROOT / "fixtures" / "frames" / "paper_walk_000.npz")
    wrong = save_frames(tmp_path / "wrong.npz", {n: paper.frames[n] for n in ("sw", "ne")}, paper.q, paper.stamp)
    assert cli.main(["run", str(CELL), "--frames", str(wrong)]) == 0
    out = capsys.readouterr().out.splitlines()
    line = next(x for x in out if x.startswith("min distance"))
    assert line.endswith("(a stop: the cycle measured nothing, see the faults)"), line
    assert any(x.startswith("FAULT") and "frame shape" in x for x in out)


def test_broken_frames_files_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(FRAMES.read_bytes()[:3000])
    objects = tmp_path / "objects.npz"
    np.savez(objects, sw=np.array([object()], dtype=object), q=np.zeros(6), stamp=1.0)
    single = tmp_path / "single.npy"
    np.save(single, np.zeros((4, 4)))
    for path, words in ((truncated, "not a readable .npz"), (objects, "field 'sw' cannot be read"), (single, "not an .npz")):
        assert cli.main(["run", str(CELL), "--frames", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and str(path) in err and words in err, err


def test_several_frames_files_give_a_line_per_cycle_and_a_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    files = [ROOT / "fixtures" / "frames" / f"small_walk_00{k}.npz" for k in range(2)]
    plot = tmp_path / "plots" / "timeline.png"
    assert cli.main(["run", str(CELL), "--frames", *map(str, files), "--json", "--plot", str(plot)]) == 0
    captured = capsys.readouterr()
    cycles = json.loads(captured.out)["cycles"]  # stdout is JSON only
    assert [c["file"] for c in cycles] == [str(f) for f in files]
    assert [c["stamp"] for c in cycles] == pytest.approx([0.0, 0.1])
    assert all(set(c) >= {"min_distance", "separation_distance", "speed_scale", "faults", "cycle_ms"} for c in cycles)
    assert f"wrote {plot}" in captured.err
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # A directory is its .npz files in name order; text mode prints a line per file.
    recording = tmp_path / "recording"
    recording.mkdir()
    for f in reversed(files):
        (recording / f.name).write_bytes(f.read_bytes())
    (recording / "notes.txt").write_text("not a frames file")
    assert cli.main(["run", str(CELL), "--frames", str(recording)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("small_walk_000.npz") and lines[1].startswith("small_walk_001.npz")
    assert lines[2] == f"last cycle ({recording / 'small_walk_001.npz'}):"


def test_run_flags_are_checked_before_the_monitor(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    for argv, words in (
        (["--frames", str(FRAMES), "--plot", str(tmp_path / "t.svg")], "--plot"),
        (["--frames", str(empty)], "holds no .npz"),
        (["--frames", str(FRAMES), str(tmp_path / "nope.npz")], "no such frames file or directory"),
    ):
        assert cli.main(["run", str(CELL), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and words in err, err


def test_frames_of_another_cell_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    """A frames file with cameras the cell does not have is another cell's: one line naming
    the file and the cameras, before the monitor is built (not a stop every cycle)."""
    other = ROOT / "fixtures" / "frames" / "paper_walk_000.npz"
    assert cli.main(["run", str(CELL), "--frames", str(FRAMES), str(other)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.count("\n") == 0 and str(other) in err and "se, nw" not in err and "nw, se" in err, err
    assert "which the cell does not have" in err and captured.out == ""
