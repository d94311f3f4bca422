"""polyhull bench: a smoke run on the small cell, JSON fields and the tightness figure."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from polyhull.commands import bench
from polyhull.errors import PolyhullError

SMALL_CELL = Path(__file__).resolve().parents[1] / "fixtures" / "cells" / "small_cell.toml"


def _run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="polyhull")
    bench.register(parser.add_subparsers())
    args = parser.parse_args(["bench", *argv])
    return int(args.func(args))


def test_bench_json_has_the_figures(capsys: pytest.CaptureFixture[str]) -> None:
    code = _run(
        "--cell", str(SMALL_CELL), "--cycles", "1", "--warmup", "0", "--tightness-samples", "20000", "--json"
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["cycle_ms_median"] > 0 and out["cycle_ms_p99"] >= out["cycle_ms_median"]
    for stage in ("camera_regions", "fusion", "occlusion", "plausibility", "distance", "speed"):
        assert stage in out["stages_ms_median"]
    tight = out["tightness"]
    # C contains the exact depth hull: its volume is not below the sampled estimate (allowing
    # three standard errors of the Monte-Carlo share).
    share = tight["volume_exact_hull"] / (3.0 * 3.0 * 2.5)
    error = 3.0 * np.sqrt(share * (1 - share) / tight["samples"]) * (3.0 * 3.0 * 2.5)
    assert tight["volume_hull"] >= tight["volume_exact_hull"] - error
    # Each per-pixel approximation step only lowers free depth, so on the same samples the
    # hull only grows: the breakdown is ordered exactly.
    assert 0.0 <= tight["excess_static_band"] <= tight["excess_static_band_and_blocks"]
    # The per-frame block minima nest (2 px blocks lie in 4 px blocks lie in 8 px blocks).
    bounds = [tight[f"excess_frame_blocks_{b}"] for b in (2, 4, 8)]
    assert 0.0 <= bounds[0] <= bounds[1] <= bounds[2]
    assert out["workload"]["cameras"] == 2


def test_bench_block_overrides_the_cell(capsys: pytest.CaptureFixture[str]) -> None:
    """--block replaces the cell's reconstruction.block, and the workload says so."""
    code = _run("--cell", str(SMALL_CELL), "--cycles", "1", "--warmup", "0", "--tightness-samples", "0", "--block", "4", "--json")
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["workload"]["block_px"] == 4
    assert out["tightness"] is None


def test_bench_rejects_bad_counts() -> None:
    with pytest.raises(PolyhullError, match="--cycles"):
        _run("--cell", str(SMALL_CELL), "--cycles", "0")
    with pytest.raises(PolyhullError, match="--tightness-samples"):
        _run("--cell", str(SMALL_CELL), "--tightness-samples", "-1")
    with pytest.raises(PolyhullError, match="--block"):
        _run("--cell", str(SMALL_CELL), "--block", "0")
