"""polyhull bench: a small run of the reference workload, its JSON figures, the text table,
the synthetic camera ring and the rejection of bad flag values. No timing assertions."""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
import pytest

from polyhull.cellfile import default_cell_path, load_cell
from polyhull.cli import main
from polyhull.commands.bench import rescale_camera, ring_cameras

SMALL = ("--cycles", "2", "--warmup", "1", "--empty-cycles", "2", "--tightness-samples", "20000", "--resolution", "320x240")


def _run(*argv: str) -> int:
    return main(["bench", *argv])


@pytest.fixture(scope="module")
def bench_json() -> dict:  # type: ignore[type-arg]
    """One small --json run, shared by the checks below (stdout must hold one JSON object)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = _run(*SMALL, "--json")
    assert code == 0, err.getvalue()
    return json.loads(out.getvalue())  # the whole of stdout: one object and nothing else


def test_bench_json_timings(bench_json: dict) -> None:  # type: ignore[type-arg]
    cycle = bench_json["cycle_ms"]
    assert cycle["median"] > 0 and cycle["p99"] >= cycle["median"]
    stages = bench_json["stages_ms_median"]
    for stage in ("frames", "kinematics", "robot_raster", "pixels", "pieces", "plausibility", "distance", "speed"):
        assert stage in stages and stages[stage] >= 0
        assert bench_json["stages_cycles"][stage] == 2
    assert "total" not in stages
    first = bench_json["first_cycles_ms"]
    assert len(first) == 2 and all(ms > 0 for ms in first)
    w = bench_json["workload"]
    assert w["cameras"] == 4 and w["resolution"] == [320, 240] and w["cycles"] == 2 and w["warmup"] == 1


def test_bench_json_cycle_records(bench_json: dict, tmp_path) -> None:  # type: ignore[type-arg, no-untyped-def]
    """One record per timed cycle: its stages add up to no more than its time, the reported
    distance is never above the person's true one, and --plot's drawing accepts them."""
    from polyhull.benchplot import STAGES, plot_stages

    cycles = bench_json["cycles"]
    assert [c["cycle"] for c in cycles] == [0, 1]
    stamps = [c["stamp_s"] for c in cycles]
    assert stamps[1] > stamps[0]
    for c in cycles:
        assert set(STAGES) <= set(c["stages_ms"])
        assert 0 < sum(c["stages_ms"].values()) <= c["total_ms"] * (1 + 1e-9)
        assert c["pieces"] >= 0 and c["kept_pieces"] <= c["pieces"] and c["refined_pieces"] >= 0
        assert c["unexplained_pixels"] >= 0 and 0.0 <= c["speed_scale"] <= 1.0
        assert c["distance_m"] <= c["true_distance_m"] + 1e-6
    out = plot_stages(cycles, tmp_path / "bench.png", title="bench")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_repeat_pools_passes_of_the_same_walk(bench_json: dict) -> None:  # type: ignore[type-arg]
    """--repeat 2: both passes' cycles pooled, each pass's median reported, and the reset
    monitor's second pass gives the one-pass run's distances (the same frames, no history)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = _run(*SMALL[:4], "--empty-cycles", "0", "--tightness-samples", "0", *SMALL[-2:], "--repeat", "2", "--json")
    assert code == 0, err.getvalue()
    result = json.loads(out.getvalue())
    assert result["workload"]["repeat"] == 2
    assert len(result["cycle_ms"]["pass_medians"]) == 2 and all(ms > 0 for ms in result["cycle_ms"]["pass_medians"])
    assert all(n == 4 for n in result["stages_cycles"].values())  # 2 timed cycles a pass
    # one record per timed cycle, its times the passes' median, its distances the last pass's
    assert [c["cycle"] for c in result["cycles"]] == [0, 1]
    assert [c["distance_m"] for c in result["cycles"]] == [c["distance_m"] for c in bench_json["cycles"]]
    assert result["person"]["distance_m"] == bench_json["person"]["distance_m"]
    assert isinstance(result["machine"]["cpu"], str) and result["machine"]["logical_cpus"] >= 1


def test_bench_json_person_and_empty_cell(bench_json: dict) -> None:  # type: ignore[type-arg]
    person = bench_json["person"]
    assert person["cycles"] == 3  # warm-up and timed cycles of the walk
    gap = person["true_minus_reported_m"]
    assert math.isfinite(gap["median"]) and gap["max"] >= gap["median"]
    assert isinstance(person["cycles_reported_above_true"], int) and person["cycles_reported_above_true"] >= 0
    assert 0.0 <= person["speed_scale"]["min"] <= person["speed_scale"]["median"] <= 1.0
    assert isinstance(person["faults"], list)
    # the exact hull's own gap: a conservative region holds the person, so its distance is at
    # most the person's (up to the grid) and at least 0
    exact_gap, loss = person["exact_hull_gap_m"], person["engine_minus_exact_m"]
    assert person["exact_hull_grid_m"] == 0.025 and 1 <= person["exact_hull_cycles"] <= 3
    assert 0 <= person["exact_hull_cycles_clipped"] <= 3 and person["exact_hull_seconds"] > 0
    assert 0 <= person["exact_hull_cycles_static_nearer"] <= person["exact_hull_cycles"]
    assert -0.05 <= exact_gap["median"] <= exact_gap["max"] < 6.0
    assert math.isfinite(loss["median"]) and loss["max"] >= loss["median"]
    # the cycles where the person's part of the exact hull, not the static region, is nearest
    decides = person["person_decides"]
    assert 0 <= decides["cycles"] <= person["exact_hull_cycles"] - person["exact_hull_cycles_static_nearer"]
    if decides["cycles"]:
        assert -0.05 <= decides["exact_hull_gap_m"]["median"] <= decides["exact_hull_gap_m"]["max"] < 6.0
        assert decides["true_minus_reported_m"]["median"] <= decides["true_minus_reported_m"]["max"]
    empty = bench_json["empty_cell"]
    assert empty["cycles"] == 2
    # timed back to back: the warm-up cycle left out of the two
    assert empty["cycle_ms"]["cycles"] == 1
    assert 0.0 < empty["cycle_ms"]["median"] <= empty["cycle_ms"]["p99"] <= empty["cycle_ms"]["max"]
    assert 0 <= empty["kept_pieces"]["min"] <= empty["kept_pieces"]["max"]
    assert 0 <= empty["cycles_with_kept_pieces"] <= 2 and 0 <= empty["cycles_distance_off_static"] <= 2
    assert 0.0 <= empty["speed_scale"]["min"] <= 1.0
    added = empty["dynamic_volume_outside_static_l"]
    assert 0.0 <= added["min"] <= added["median"] <= added["max"]
    assert empty["min_volume_l"] == pytest.approx(1.0)  # the default cell's too-small threshold
    assert 0 <= empty["cycles_dynamic_volume_over_min_volume"] <= 2
    assert empty["distance_m"]["min"] is None or empty["distance_m"]["min"] >= 0


def test_bench_json_tightness(bench_json: dict) -> None:  # type: ignore[type-arg]
    tight = bench_json["tightness"]
    assert tight["samples"] == 20000
    assert tight["volume_zone_m3"] == pytest.approx(6.0 * 6.0 * 3.5)
    assert 0 < tight["volume_exact_hull_m3"] < tight["volume_zone_m3"]
    assert 0 < tight["volume_engine_r2_m3"] < tight["volume_zone_m3"]
    assert math.isfinite(tight["excess_percent"])
    assert tight["volume_exact_hull_outside_robot_shadow_m3"] <= tight["volume_exact_hull_m3"]
    # the exact hull with the static band contains the exact hull (same samples)
    assert tight["volume_exact_hull_m3"] <= tight["volume_exact_banded_m3"] < tight["volume_zone_m3"]
    banded_excess = 100.0 * (tight["volume_engine_r2_m3"] / tight["volume_exact_banded_m3"] - 1.0)
    assert tight["excess_over_banded_percent"] == pytest.approx(banded_excess)
    assert tight["excess_over_banded_percent"] <= tight["excess_percent"]
    for key in ("misses", "misses_band", "misses_flying", "misses_unexcused"):
        assert isinstance(tight[key], int) and tight[key] >= 0
    # every point outside R2 is a miss or excused by exactly one of the declared tolerances
    assert tight["misses"] + tight["misses_band"] + tight["misses_flying"] <= tight["misses_unexcused"]


def test_bench_text_output(capsys: pytest.CaptureFixture[str]) -> None:
    code = _run("--cycles", "1", "--warmup", "0", "--empty-cycles", "0", "--tightness-samples", "0", "--resolution", "160x120")
    assert code == 0
    out = capsys.readouterr().out
    assert "stage" in out and "median [ms]" in out and "cycle p99" in out
    assert "person:" in out
    assert "exact hull around the person" in out and "engine against that exact hull" in out
    assert "tightness" not in out and "empty cell" not in out  # both skipped


def test_camera_ring_and_resolution() -> None:
    cell = load_cell(default_cell_path())
    cams = ring_cameras(cell, 5)
    assert len({c.name for c in cams}) == 5
    for c in cams:
        assert c.intrinsics == cell.cameras[0].intrinsics and c.noise == cell.cameras[0].noise
        assert c.center[2] == pytest.approx(3.3)
        assert np.hypot(c.center[0] - 3.0, c.center[1] - 3.0) == pytest.approx(2.9)
        axis = c.T_world_camera[:3, 2]
        to_target = np.array([3.0, 3.0, 1.6]) - c.center
        assert axis @ to_target == pytest.approx(np.linalg.norm(to_target))  # looks at the target
    k = rescale_camera(cell.cameras[0], 320, 240).intrinsics
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (320, 240, 262.5, 262.5, 159.5, 119.5)


def test_bench_camera_ring_runs(capsys: pytest.CaptureFixture[str]) -> None:
    code = _run("--cameras", "3", "--resolution", "160x120", "--cycles", "1", "--warmup", "0",
                "--empty-cycles", "0", "--tightness-samples", "2000", "--json")
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["workload"]["cameras"] == 3 and out["workload"]["camera_layout"] == "ring"
    assert out["empty_cell"] is None and out["tightness"]["misses"] >= 0


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (("--cameras", "0"), "--cameras"),
        (("--cameras", "17"), "--cameras"),
        (("--resolution", "0x0"), "--resolution"),
        (("--resolution", "640"), "--resolution"),
        (("--cycles", "0"), "--cycles"),
        (("--warmup", "-1"), "--warmup"),
        (("--empty-cycles", "-1"), "--empty-cycles"),
        (("--tightness-samples", "-1"), "--tightness-samples"),
        (("--seed", "-1"), "--seed"),
        (("--pace", "0"), "--pace"),
        (("--pace", "nan"), "--pace"),
        (("--pace", "2000"), "--pace"),
        (("--spin",), "--spin"),
        (("--repeat", "0"), "--repeat"),
        (("--repeat", "51"), "--repeat"),
        (("--plot", "bench.jpg"), "--plot"),
        (("--plot", "no-such-directory/bench.png"), "--plot"),
    ],
)
def test_bench_rejects_bad_values(argv: tuple[str, ...], flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    code = _run(*argv)
    captured = capsys.readouterr()
    assert code != 0
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0], captured.err


def test_paced_cycles_start_at_their_ticks(monkeypatch: pytest.MonkeyPatch) -> None:
    """``--pace HZ``: cycle k starts no earlier than k / HZ after the first (the thread sleeps
    until then, as a controller waiting for its frames; with ``spin`` it waits without
    sleeping); without it the cycles run back to back, never sleeping."""
    import time
    from dataclasses import dataclass, field

    from polyhull.commands.bench import _time_walk

    @dataclass(frozen=True)
    class _Verdict:
        timings: dict = field(default_factory=lambda: {"total": 1.0})  # type: ignore[type-arg]
        _geometry: object = None

    class _Monitor:
        def __init__(self) -> None:
            self.started: list[float] = []

        def step(self, frames: object, q: object, stamp: float) -> _Verdict:
            self.started.append(time.perf_counter())
            return _Verdict()

    inputs = [({}, np.zeros(6), 0.1 * k, None) for k in range(5)]
    paced = _Monitor()
    stages, first, verdicts = _time_walk(paced, inputs, 1, 0, None, False, pace=50.0)  # type: ignore[arg-type]
    assert len(verdicts) == 5 and len(stages["total"]) == 4 and len(first) == 2
    gaps = np.diff(paced.started)
    assert np.all(np.asarray(paced.started) - paced.started[0] >= np.arange(5) / 50.0 - 1e-3), gaps

    def no_sleep(seconds: float) -> None:
        raise AssertionError(f"slept {seconds} s")

    monkeypatch.setattr(time, "sleep", no_sleep)
    spun = _Monitor()
    _time_walk(spun, inputs, 1, 0, None, False, pace=50.0, spin=True)  # type: ignore[arg-type]
    assert np.all(np.asarray(spun.started) - spun.started[0] >= np.arange(5) / 50.0 - 1e-3), np.diff(spun.started)
    back_to_back = _Monitor()
    _time_walk(back_to_back, inputs, 1, 0, None, False)  # type: ignore[arg-type]
    assert len(back_to_back.started) == 5


def test_plot_without_matplotlib_is_refused_before_any_work(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path
) -> None:  # type: ignore[no-untyped-def]
    """--plot without the 'placement' extra: one line naming it, exit 2, nothing run."""
    import importlib.util

    import polyhull.commands.bench as bench

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else real(name, *a))
    monkeypatch.setattr(bench, "run_bench", lambda *a, **k: pytest.fail("the bench ran"))
    code = _run("--plot", str(tmp_path / "b.png"))
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "--plot" in lines[0] and "placement" in lines[0], captured.err
