"""``polyhull demo``: the per-cycle lines, the timeline plot and its records.

The animated page is tested on :class:`polyhull_viewer.DemoRecorder` (tests/test_viewer.py)
and in the browser (tests/test_viewer_browser.py): building a verdict's dynamic region as
one manifold takes the engine tens of seconds per cycle on the small cell, too slow here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from polyhull import cli
from polyhull.cellfile import load_cell
from polyhull.commands.demo import FAST_WALK, WALK_SHARE, walk_speed

ROOT = Path(__file__).resolve().parents[1]
SMALL_CELL = ROOT / "fixtures" / "cells" / "small_cell.toml"


def test_demo_writes_the_plot_and_the_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png, records = tmp_path / "demo.png", tmp_path / "records.json"
    argv = ["demo", "--cell", str(SMALL_CELL), "--cycles", "3", "--dt", "0.2", "--no-html"]
    assert cli.main([*argv, "--plot", str(png), "--records", str(records)]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert f"wrote {png} (timeline plot)" in out and ".html" not in out
    # 0.45 s for the walk in and out: the header gives its speed, and stderr warns that no
    # person walks that fast
    cell = load_cell(SMALL_CELL)
    speed = walk_speed(np.asarray(cell.zone.min), np.asarray(cell.robot.base[:2]), WALK_SHARE * 3 * 0.2)
    assert speed > FAST_WALK and f"walks in and out at {speed:.2f} m/s" in out
    assert "faster than a person walks" in captured.err
    rows = json.loads(records.read_text())
    assert [r["stamp"] for r in rows] == pytest.approx([0.0, 0.2, 0.4])
    # The simulated person's true distance is known every cycle, and the reported distance
    # never exceeds it (the region contains the person).
    assert all(r["true_distance"] is not None and r["true_distance"] > 0 for r in rows)
    assert all(r["min_distance"] is None or r["min_distance"] <= r["true_distance"] + 1e-6 for r in rows)
    with Image.open(png) as image:
        assert image.format == "PNG"


def test_demo_rejects_a_plot_that_is_not_png_before_running(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["demo", "--cycles", "2", "--plot", str(tmp_path / "t.jpg"), "--no-html"]) == 2
    captured = capsys.readouterr()
    assert "--plot" in captured.err and captured.err.count("\n") == 1
    assert "cycles" not in captured.out  # nothing ran


def test_behaviour_line_names_the_speed_phases() -> None:
    from polyhull.commands.demo import behaviour

    scales = [1.0, 0.97, 0.5, 0.0, 0.0, 0.3, 1.0]
    records = [{"stamp": 0.3 * k, "speed_scale": s} for k, s in enumerate(scales)]
    assert behaviour(records) == "full speed 0.0-0.3 s, slower at 0.6 s, stop 0.9-1.2 s, slower at 1.5 s, full speed at 1.8 s"
    assert behaviour([]) == "no cycle"


def test_demo_scene_draws_a_cycle_every_scene_dt(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The monitor runs every --dt; the HTML scene gets a cycle every --scene-dt (each
    drawn cycle builds its region as a manifold)."""
    import polyhull_viewer

    drawn: list[float] = []

    class Recorder:
        def __init__(self, *args: object, **kwargs: object) -> None:
            pass

        def add_cycle(self, t: float, *args: object) -> None:
            drawn.append(t)

        def write_html(self, path: Path) -> Path:
            path.write_text("<html></html>")
            return path

    monkeypatch.setattr(polyhull_viewer, "DemoRecorder", Recorder)
    html = tmp_path / "demo.html"
    argv = ["demo", "--cell", str(SMALL_CELL), "--cycles", "5", "--dt", "0.1", "--scene-dt", "0.2"]
    assert cli.main([*argv, "--no-plot", "--html", str(html)]) == 0
    assert drawn == pytest.approx([0.0, 0.2, 0.4])
    assert f"wrote {html}" in capsys.readouterr().out
    assert cli.main(["demo", "--cycles", "2", "--scene-dt", "-1", "--no-plot"]) == 2
    assert "--scene-dt" in capsys.readouterr().err
