"""polyhull soak: the ring's replay order, the growth slope, the heap sampler (it sees a
block allocated and freed), a few cycles on the small cell (its JSON fields and text lines,
the verdict on the heap in use, the RSS verdict without a heap sampler) and the rejection of
bad flag values. No timing assertions."""

from __future__ import annotations

import contextlib
import ctypes
import io
import json
import math

import pytest
from conftest import SMALL_CELL

from polyhull.cli import main
from polyhull.commands.soak import (
    GROWTH_LIMIT_MB,
    RSS_GROWTH_LIMIT_MB,
    HeapSample,
    growth_per_1000,
    heap_reader,
    ring_order,
    run_soak,
)

SMALL = ("--cell", str(SMALL_CELL), "--cycles", "4", "--warmup", "1", "--ring", "3")


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["soak", *argv])
    return code, out.getvalue(), err.getvalue()


def test_ring_order_goes_forth_and_back_without_jumps() -> None:
    for ring in (2, 3, 20):
        order = [ring_order(ring, i) for i in range(5 * ring)]
        assert order[:ring] == list(range(ring))
        assert set(order) == set(range(ring))
        assert all(abs(b - a) == 1 for a, b in zip(order, order[1:], strict=False))


def test_growth_is_the_least_squares_slope() -> None:
    cycles = list(range(50, 550))
    mb = 1024 * 1024
    # 1 MB every 500 cycles, plus an alternating +-64 kB that a slope must average out
    rss = [800 * mb + (c - 50) * mb // 500 + (65536 if c % 2 else -65536) for c in cycles]
    assert growth_per_1000(cycles, rss) == pytest.approx(2.0, abs=0.01)
    assert growth_per_1000(cycles, [900 * mb] * len(cycles)) == pytest.approx(0.0, abs=1e-9)


def test_heap_reader_sees_a_block_allocated_and_freed() -> None:
    heap = heap_reader()
    if heap is None:
        pytest.skip("no glibc mallinfo2 here")
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    # Counted in use while allocated, and no longer once freed. Whether it adds to what
    # glibc holds depends on what ran before: a free chunk that large in an arena serves it
    # without a new mapping (it did after the whole test suite), so only "held >= in use"
    # is asserted of the held bytes.
    size = 64 * 1024 * 1024
    before = heap()
    block = libc.malloc(size)
    assert block
    during = heap()
    libc.free(block)
    after = heap()
    assert during.in_use - before.in_use >= size
    assert during.held >= during.in_use and before.held >= before.in_use
    assert during.in_use - after.in_use >= size


@pytest.fixture(scope="module")
def soak_json() -> tuple[int, dict]:  # type: ignore[type-arg]
    """One small --json run (stdout must hold one JSON object and nothing else)."""
    code, out, err = _run(*SMALL, "--json")
    assert code in (0, 1), err
    return code, json.loads(out)


def test_soak_json_fields(soak_json: tuple[int, dict]) -> None:  # type: ignore[type-arg]
    code, result = soak_json
    w = result["workload"]
    assert (w["cycles"], w["warmup"], w["ring"], w["cameras"]) == (4, 1, 3, 2)
    rss = result["rss_mb"]
    assert 0 < rss["start"] <= rss["max"] and 0 < rss["end"] <= rss["max"]
    assert rss["end_minus_start"] == pytest.approx(rss["end"] - rss["start"])
    assert [c for c, _ in rss["trace"]] == [1, 4]  # the first and the last measured cycle
    assert rss["trace"][0][1] == rss["start"] and rss["trace"][-1][1] == rss["end"]
    assert math.isfinite(rss["growth_per_1000_cycles"])
    heap = result["heap_mb"]
    if heap_reader() is not None:  # glibc: the verdict is the heap in use's
        assert result["judged"] == "heap in use"
        assert result["growth_limit_mb_per_1000_cycles"] == GROWTH_LIMIT_MB
        assert result["growth_mb_per_1000_cycles"] == heap["in_use"]["growth_per_1000_cycles"]
        assert [c for c, _, _ in heap["trace"]] == [c for c, _ in rss["trace"]]  # the same cycles
        assert all(0 < in_use <= held for _, in_use, held in heap["trace"])
        # the RSS holds the heap in use (with the code and Python's own arenas besides)
        assert heap["in_use"]["start"] < rss["start"] and heap["in_use"]["end"] < rss["end"]
    else:
        assert heap is None and result["judged"] == "RSS"
    assert result["memory_flat"] == (
        result["growth_mb_per_1000_cycles"] < result["growth_limit_mb_per_1000_cycles"]
    )
    assert code == (0 if result["memory_flat"] else 1)  # the exit code follows the verdict
    c = result["cycle_ms"]
    assert 0 < c["p50"] <= c["p99"] <= c["max"]
    assert 0.0 <= result["speed_scale"]["min"] <= result["speed_scale"]["median"] <= 1.0
    # the replayed frames are restamped: no frame is duplicated, out of order, stale or missing
    # (on the small cell the walk brings the person against the robot: a contact fault)
    assert not [f for f in result["faults"] if "frame" in f["fault"] or "coverage" in f["fault"]]
    total = w["warmup"] + w["cycles"]  # every cycle run, the warm-up's included
    for f in result["faults"]:
        assert f["cycles"] == total - f["first_cycle"] >= 1  # faults latch until a reset
    for warning in result["warnings"]:
        assert warning["cycles"] >= 1 and warning["last"].startswith(warning["warning"])


def test_soak_text_output() -> None:
    code, out, _ = _run(*SMALL)
    assert code in (0, 1)
    lines = out.splitlines()
    assert lines[0].startswith("polyhull soak: 2 cameras, 4 cycles after 1 warm-up, ring of 3")
    assert any(line.startswith("RSS: ") and "per 1,000 cycles" in line for line in lines)
    if heap_reader() is not None:
        assert any(line.startswith("heap in use: ") and f"(limit {GROWTH_LIMIT_MB:g})" in line for line in lines)
    assert any(line.startswith("cycle [ms]: p50 ") for line in lines)
    assert "faults: none" in lines or "faults (cycles with it, first cycle):" in lines


def test_without_a_heap_sampler_the_rss_is_judged() -> None:
    result = run_soak(SMALL_CELL, cycles=3, warmup=1, ring=3, heap=None)
    assert result["heap_mb"] is None and result["judged"] == "RSS"
    assert result["growth_limit_mb_per_1000_cycles"] == RSS_GROWTH_LIMIT_MB
    assert result["growth_mb_per_1000_cycles"] == result["rss_mb"]["growth_per_1000_cycles"]


def test_a_growing_heap_is_not_flat() -> None:
    """A heap sampler that reports 1 kB more every cycle (1 MB per 1,000 cycles): not flat."""
    grown = iter(range(0, 10**9, 1024))

    def growing() -> HeapSample:
        n = 900 * 1024 * 1024 + next(grown)
        return HeapSample(n, n + 4096)

    result = run_soak(SMALL_CELL, cycles=3, warmup=1, ring=3, heap=growing)
    assert result["judged"] == "heap in use"
    assert result["growth_mb_per_1000_cycles"] == pytest.approx(1000 * 1024 / (1024 * 1024))
    assert result["memory_flat"] is False


@pytest.mark.parametrize(
    ("flags", "named"),
    [
        (("--cycles", "1"), "--cycles"),
        (("--warmup", "-1"), "--warmup"),
        (("--ring", "1"), "--ring"),
        (("--ring", "5000"), "--ring"),
        (("--seed", "-3"), "--seed"),
    ],
)
def test_bad_flags_give_one_line(flags: tuple[str, str], named: str) -> None:
    code, out, err = _run(*flags)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and named in err and "Traceback" not in err


def test_missing_cell_gives_one_line(tmp_path) -> None:  # noqa: ANN001
    missing = tmp_path / "nope.toml"
    code, out, err = _run("--cell", str(missing), "--cycles", "2")
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "nope.toml" in err
