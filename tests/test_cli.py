"""The console script as a shell user meets it: --version, and a reader that goes away."""

from __future__ import annotations

import os
import subprocess
import sys

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
