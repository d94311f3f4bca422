"""polyhull.benchplot: the bench's cycles drawn as stacked stage times; the bars add up to
each cycle's time, and bad records or paths give one clear error."""

from __future__ import annotations

from pathlib import Path

import pytest

from polyhull.benchplot import STAGES, plot_stages, stages_figure
from polyhull.errors import PolyhullError

pytest.importorskip("matplotlib")


def _records() -> list[dict]:  # type: ignore[type-arg]
    out = []
    for i, total in enumerate((30.0, 55.0, 80.0)):
        stages = {s: 2.0 + i + k for k, s in enumerate(STAGES)} | {"kinematics": 0.5, "frames": 0.1}
        out.append({
            "cycle": i, "total_ms": total, "stages_ms": stages, "pieces": 100 * (i + 1),
            "distance_m": 1.5 - 0.5 * i, "true_distance_m": 1.7 - 0.5 * i,
        })
    # a cycle whose stages add up to more than its time (timer rounding): "other" is 0
    out.append({"cycle": 3, "total_ms": 5.0, "stages_ms": dict.fromkeys(STAGES, 1.0), "pieces": None,
                "distance_m": None, "true_distance_m": None})
    return out


def test_bars_add_up_to_each_cycles_time() -> None:
    records = _records()
    fig = stages_figure(records, title="t")
    ax = fig.axes[0]
    tops: dict[float, float] = {}
    for bar in ax.patches:
        x = round(bar.get_x() + bar.get_width() / 2, 6)
        tops[x] = max(tops.get(x, 0.0), bar.get_y() + bar.get_height())
    expected = [r["total_ms"] for r in records[:3]] + [float(len(STAGES))]
    assert [tops[float(i)] for i in range(4)] == pytest.approx(expected)
    # one colour (legend entry) per stage drawn (the two image stages in one), and the rest
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[0].startswith("images") and labels[1:] == ["pieces", "shadow memory", "plausibility", "distance", "other"]


def test_plot_writes_a_png(tmp_path: Path) -> None:
    out = plot_stages(_records(), tmp_path / "b.png")
    assert out.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize(
    ("records", "message"),
    [
        ([], "no bench cycle"),
        ([{"total_ms": 3.0}], "record 0"),
        ([{"total_ms": "fast", "stages_ms": {}}], "'total_ms'"),
    ],
)
def test_bad_records_are_named(records: list, message: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(PolyhullError, match=message):
        stages_figure(records)


def test_plot_path_must_be_png(tmp_path: Path) -> None:
    with pytest.raises(PolyhullError, match="PNG"):
        plot_stages(_records(), tmp_path / "b.svg")
    with pytest.raises(PolyhullError, match="cannot write"):
        plot_stages(_records(), tmp_path / "missing" / "b.png")
