"""The console script as a shell user meets it: --version, and a reader that goes away."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import polyhull


def _polyhull(*args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "polyhull.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=120)


def test_version() -> None:
    result = _polyhull("--version")
    assert result.returncode == 0
    assert result.stdout.strip() == f"polyhull {polyhull.__version__}"


def test_a_closed_pipe_is_not_a_traceback(monkeypatch) -> None:  # noqa: ANN001
    """``polyhull ... | head``: the reader is gone; the command stops quietly with exit 141
    (as a shell tool killed by SIGPIPE) instead of a BrokenPipeError traceback."""
    from polyhull import cli

    read_end, write_end = os.pipe()
    os.close(read_end)
    stdout = open(write_end, "w", buffering=1)  # noqa: SIM115 - closed below
    monkeypatch.setattr(sys, "stdout", stdout)
    try:
        assert cli.main(["render", "--help"]) == 141
    finally:
        stdout.close()


def test_help_does_not_import_the_engine() -> None:
    """``polyhull --help`` parses before the heavy libraries are loaded (the package's
    public names are imported when first used)."""
    code = (
        "import sys; from polyhull import cli; cli.build_parser(); "
        "print(sorted(m for m in ('trimesh', 'manifold3d', 'numba', 'fcl') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def _help(command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> str:
    """``polyhull COMMAND --help`` on one line (a wide terminal: argparse wraps at hyphens)."""
    from polyhull import cli

    monkeypatch.setenv("COLUMNS", "1000")
    with pytest.raises(SystemExit) as exc:
        cli.main([command, "--help"])
    assert exc.value.code == 0
    return " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize(
    ("command", "phrases"),
    [
        (
            "run",
            [
                "the verdict object (volumes [m^3], the distance, closest link",
                "S_p: the protective separation distance of ISO/TS 15066",
                "Exit status: 0 when every cycle ran", "not in the exit status); 2 on bad input",
                "130 when interrupted",
            ],
        ),
        (
            "replay",
            [
                "S_p: the protective separation distance of ISO/TS 15066",
                "Exit status: 0 when the recording was replayed to its end", "2 on bad input",
            ],
        ),
        (
            "place",
            [
                "f_opt: the objective's optimal value", "CMA-ES (default 0)", "baseline; default cma-es)",
                "budget per camera count [s] (default: off)", "units of the objective; default: off)",
            ],
        ),
        ("view", ["C(i) (each camera's occluded region", "C (the depth hull)", "M (the robot occlusion)"]),
        ("bench", ["(16..4096 px per side; default: the cell's)", "(1..16) of the first camera's kind (default: the cell's cameras)"]),
        ("soak", ["measured cycles after the warm-up, at least 2 (default 500)"]),
        ("render", ["--target MESH[@x,y[,z[,yaw]]]", "dropped out as 0, in [0, 1] (default 0.002)"]),
        ("demo", ["seed of the sensor noise (default 0)"]),
    ],
)
def test_help_says_what_the_code_enforces(
    command: str, phrases: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    text = _help(command, capsys, monkeypatch)
    for phrase in phrases:
        assert phrase in text, (phrase, text)
    assert "SPEC" not in text and "MESH[@x,y,z,yaw]" not in text


def test_one_cycle_is_singular(capsys: pytest.CaptureFixture[str]) -> None:
    from pathlib import Path

    from polyhull import cli

    cell = Path(__file__).resolve().parents[1] / "fixtures" / "cells" / "small_cell.toml"
    assert cli.main(["demo", "--cell", str(cell), "--cycles", "1", "--no-html", "--no-plot"]) == 0
    header = capsys.readouterr().out.splitlines()[0]
    assert header.endswith("(2 cameras), 1 cycle"), header
    from polyhull.commands import counted

    assert (counted(1, "cycle"), counted(0, "cycle"), counted(3, "evaluation")) == ("1 cycle", "0 cycles", "3 evaluations")
