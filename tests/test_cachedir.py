"""The compiled kernels are cached under the user's cache directory, never next to the
package's sources: numba files written into site-packages outlive ``pip uninstall`` and
their folder then shadows a later editable install (``import polyhull`` finds an empty
namespace package and the command line fails)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from polyhull.cachedir import imported_sources_digest, kernel_sources_digest

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


def test_the_static_models_key_follows_the_modules_it_imports(tmp_path: Path) -> None:
    """The static model's cache key holds the digest of its module and of every module of
    the package it imports, transitively (relative or absolute imports, at the top or
    inside a function, on several lines): an edit of any of them gives a new key without a
    version bump; an edit of a module it does not import does not."""
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from .unused import x\n",
        "main.py": (
            '"""Computes things.\n\nfrom the camera import the depth (prose, not code)\n"""\n'
            "import os\nfrom .helper import (\n    f,\n    g,\n)\n\n\n"
            "def late():\n    from .sub.deep import h\n    import pkg.absolute\n    return h\n"
        ),
        "helper.py": "from . import leaf\n",
        "leaf.py": "LEAF = 1\n",
        "sub/__init__.py": "",
        "sub/deep.py": "H = 1\n",
        "absolute.py": "A = 1\n",
        "unused.py": "x = 1\n",
    }
    for name, text in files.items():
        (root / name).write_text(text)

    def digest() -> str:
        imported_sources_digest.cache_clear()
        return imported_sources_digest("pkg.main", root)

    seen = {digest()}
    for name in ("main.py", "helper.py", "leaf.py", "sub/deep.py", "absolute.py"):
        (root / name).write_text((root / name).read_text() + "# edited\n")
        d = digest()
        assert d not in seen, name
        seen.add(d)
    last = digest()
    (root / "unused.py").write_text("x = 2\n")  # the package's __init__ imports it; main does not
    assert digest() == last
    imported_sources_digest.cache_clear()


def test_the_static_model_key_holds_the_code_digest(monkeypatch, small_cell, small_sim) -> None:  # noqa: ANN001
    import polyhull.engine.static_model as static_module

    refs = small_sim.reference()
    key = static_module.model_key(small_cell, refs)
    monkeypatch.setattr(static_module, "imported_sources_digest", lambda module: "another build")
    assert static_module.model_key(small_cell, refs) != key
