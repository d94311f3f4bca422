"""Tests of polyhull.timeline: the per-cycle record and the timeline plot."""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from polyhull import timeline
from polyhull.errors import MissingExtraError, PolyhullError


@dataclass
class FakeVerdict:
    """The fields of a Verdict that a record reads; reading ``region`` fails the test."""

    stamp: float = 1.5
    min_distance: float = 0.84
    separation_distance: float = 1.2
    speed_scale: float = 0.62
    closest_link: str | None = "link_3"
    faults: tuple[str, ...] = ()
    timings: dict[str, float] = field(default_factory=lambda: {"pixels": 3.0, "total": 41.5})

    @property
    def region(self) -> Any:
        raise AssertionError("record_of must not build the regions")

    region_dynamic = hull = robot_occlusion = region


def test_record_of_is_cheap_and_json_ready() -> None:
    record = timeline.record_of(FakeVerdict(), true_distance=1.1)
    assert list(record) == list(timeline.RECORD_KEYS)
    assert record == {
        "stamp": 1.5,
        "min_distance": 0.84,
        "separation_distance": 1.2,
        "speed_scale": 0.62,
        "closest_link": "link_3",
        "faults": [],
        "cycle_ms": 41.5,
        "true_distance": 1.1,
    }
    json.dumps(record)


def test_record_of_infinite_and_missing_values_are_none() -> None:
    verdict = FakeVerdict(
        min_distance=math.inf, separation_distance=math.inf, closest_link=None, faults=("stale frame: ne",), timings={}
    )
    record = timeline.record_of(verdict)
    assert record["min_distance"] is None and record["separation_distance"] is None
    assert record["cycle_ms"] is None and record["true_distance"] is None
    assert record["faults"] == ["stale frame: ne"]
    assert timeline.record_of(verdict, true_distance=math.inf)["true_distance"] is None


def _records(n: int, *, true: bool, fault_at: int | None = None) -> list[dict[str, Any]]:
    out = []
    for k in range(n):
        v = FakeVerdict(
            stamp=0.3 * k,
            min_distance=math.inf if k == 2 else 2.0 - 0.1 * k,
            separation_distance=1.0 + 0.05 * k,
            speed_scale=min(1.0, 0.1 * k),
            faults=("contact",) if k == fault_at else (),
            timings={"total": 10.0 + k},
        )
        out.append(timeline.record_of(v, true_distance=2.3 - 0.1 * k if true else None))
    return out


def _lines(ax: Any) -> dict[str, Any]:
    return {line.get_label(): line for line in ax.get_lines()}


def test_timeline_figure_draws_each_series(tmp_path: Path) -> None:
    records = _records(12, true=True, fault_at=5)
    fig = timeline.timeline_figure(records, title="demo")
    ax_d, ax_s, ax_c = fig.axes
    lines = _lines(ax_d)
    assert set(lines) == {"distance to the robot", "protective separation S_p", "true distance (simulated)"}
    assert lines["true distance (simulated)"].get_linestyle() == "--"
    assert lines["distance to the robot"].get_linestyle() == "-"
    np.testing.assert_allclose(lines["true distance (simulated)"].get_ydata(), [2.3 - 0.1 * k for k in range(12)])
    d = np.asarray(lines["distance to the robot"].get_ydata(), dtype=float)
    assert np.isnan(d[2]) and d[3] == pytest.approx(1.7)  # an infinite distance is a gap
    np.testing.assert_allclose(lines["distance to the robot"].get_xdata(), [0.3 * k for k in range(12)])
    faults = _lines(ax_s)["fault"]
    np.testing.assert_allclose(faults.get_xdata(), [1.5])
    assert ax_c.get_yscale() == "log"
    np.testing.assert_allclose(_lines(ax_c)["cycle time"].get_ydata(), [10.0 + k for k in range(12)])
    assert fig._suptitle.get_text() == "demo"
    # Without a true distance or a fault, those series are absent.
    fig = timeline.timeline_figure(_records(4, true=False))
    assert "true distance (simulated)" not in _lines(fig.axes[0])
    assert "fault" not in _lines(fig.axes[1])


def test_plot_timeline_writes_a_png(tmp_path: Path) -> None:
    out = timeline.plot_timeline(_records(12, true=True, fault_at=5), tmp_path / "a" / "t.png", title="demo")
    assert out == tmp_path / "a" / "t.png"
    with Image.open(out) as image:
        assert image.format == "PNG" and image.size == (800, 560)
        assert len(image.convert("RGB").getcolors(maxcolors=100_000) or []) > 50  # not blank


def test_plot_timeline_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(PolyhullError, match="no timeline record"):
        timeline.plot_timeline([], tmp_path / "t.png")
    with pytest.raises(PolyhullError, match="ending in .png"):
        timeline.plot_timeline(_records(2, true=False), tmp_path / "t.svg")
    bad = _records(2, true=False)
    del bad[1]["speed_scale"]
    with pytest.raises(PolyhullError, match="record 1: the key 'speed_scale' is missing"):
        timeline.plot_timeline(bad, tmp_path / "t.png")
    bad = _records(2, true=False)
    bad[0]["min_distance"] = "far"
    with pytest.raises(PolyhullError, match="record 0: 'min_distance' must be a number"):
        timeline.plot_timeline(bad, tmp_path / "t.png")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(PolyhullError, match="cannot write"):
        timeline.plot_timeline(_records(2, true=False), blocker / "t.png")


def test_missing_matplotlib_is_a_missing_extra_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(MissingExtraError, match=r"polyhull\[placement\]"):
        timeline.plot_timeline(_records(2, true=False), tmp_path / "t.png")
