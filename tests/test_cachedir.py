"""The compiled kernels are cached under the user's cache directory, never next to the
package's sources: numba files written into site-packages outlive ``pip uninstall`` and
their folder then shadows a later editable install (``import polyhull`` finds an empty
namespace package and the command line fails)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from polyhull.cachedir import kernel_sources_digest

ROOT = Path(__file__).resolve().parents[1]

_KERNEL = """
import numpy as np
import polyhull.engine.pixels as px
lo, hi = px.window_range(np.arange(12.0).reshape(3, 4), np.array([[0, 1, 0, 1]]))
assert lo[0] == 0.0 and hi[0] == 5.0
import numba.core.config as c
print(c.CACHE_DIR)
"""


def _run(env: dict[str, str]) -> str:
    out = subprocess.run([sys.executable, "-c", _KERNEL], env=env, cwd=ROOT, capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "POLYHULL_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(extra)
    return env


def test_kernels_are_cached_under_the_user_cache(tmp_path: Path) -> None:
    digest = kernel_sources_digest()
    assert _run(_env(XDG_CACHE_HOME=str(tmp_path))) == str(tmp_path / "polyhull" / "numba" / digest)
    assert any((tmp_path / "polyhull" / "numba" / digest).rglob("*.nbi"))  # the kernel's index is there


def test_polyhull_cache_dir_and_numba_cache_dir_are_honoured(tmp_path: Path) -> None:
    digest = kernel_sources_digest()
    assert _run(_env(POLYHULL_CACHE_DIR=str(tmp_path / "p"))) == str(tmp_path / "p" / "numba" / digest)
    # the static model cache off: the kernels still go under the user's cache
    assert _run(_env(POLYHULL_CACHE_DIR="off", XDG_CACHE_HOME=str(tmp_path / "x"))) == str(
        tmp_path / "x" / "polyhull" / "numba" / digest
    )
    assert _run(_env(NUMBA_CACHE_DIR=str(tmp_path / "n"))) == str(tmp_path / "n")


def test_the_kernel_folder_follows_every_kernel_module(tmp_path: Path) -> None:
    """numba checks only the stamp of a kernel's own file: a kernel inlining one from another
    module would keep the old code after only that module changed. The folder's digest
    changes with any module defining kernels, not with the others."""
    (tmp_path / "engine").mkdir()
    caller, callee, plain = tmp_path / "engine" / "a.py", tmp_path / "engine" / "b.py", tmp_path / "c.py"
    caller.write_text("@nb.njit\ndef f(x):\n    return g(x)\n")
    callee.write_text("@nb.njit(inline='always')\ndef g(x):\n    return x + 1\n")
    plain.write_text("X = 1\n")
    before = kernel_sources_digest(tmp_path)
    plain.write_text("X = 2\n")
    assert kernel_sources_digest(tmp_path) == before
    callee.write_text("@nb.njit(inline='always')\ndef g(x):\n    return x + 2\n")
    changed = kernel_sources_digest(tmp_path)
    assert changed != before
    callee.rename(tmp_path / "b.py")  # the same text elsewhere is another module
    assert kernel_sources_digest(tmp_path) not in (before, changed)


_FIRST_RUN = """
from polyhull.cachedir import kernel_cache_directory, kernels_cached
before = kernels_cached()
import numpy as np
import polyhull.engine.pixels as px
px.window_range(np.arange(12.0).reshape(3, 4), np.array([[0, 1, 0, 1]]))
print(before, kernels_cached(), kernel_cache_directory())
"""


def test_a_first_run_is_told_from_a_cached_one(tmp_path: Path) -> None:
    """``kernels_cached`` (a monitor then says it compiles the kernels, and where they go)
    is False in an empty cache and True once a kernel was compiled into it."""
    env = _env(XDG_CACHE_HOME=str(tmp_path))
    folder = tmp_path / "polyhull" / "numba" / kernel_sources_digest()

    def run() -> list[str]:
        out = subprocess.run([sys.executable, "-c", _FIRST_RUN], env=env, cwd=ROOT, capture_output=True, text=True, check=True)
        return out.stdout.strip().splitlines()[-1].split(" ", 2)

    assert run() == ["False", "True", str(folder)]
    assert run() == ["True", "True", str(folder)]
