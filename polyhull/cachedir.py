"""Where polyhull caches what it computes once: static models and compiled kernels.

Standard library only: the package's ``__init__`` uses it before numba is imported.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import os
import sys
from pathlib import Path

__all__ = [
    "cache_directory",
    "imported_sources_digest",
    "kernel_cache_directory",
    "kernel_sources_digest",
    "kernels_cached",
    "use_numba_cache",
]

_OFF = ("", "0", "off", "none", "false")


def cache_directory() -> Path | None:
    """Where static models are cached: ``POLYHULL_CACHE_DIR`` (None when it is ``off``),
    else ``$XDG_CACHE_HOME/polyhull`` or ``~/.cache/polyhull``."""
    env = os.environ.get("POLYHULL_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "polyhull"


def kernel_sources_digest(root: Path | None = None) -> str:
    """A digest of every module under ``root`` (the package when None) that defines
    compiled kernels (its path there and its text): the name of their cache folder."""
    root = Path(__file__).resolve().parent if root is None else root
    texts = {path: path.read_bytes() for path in root.rglob("*.py")}
    return _sources_digest(root, {path: text for path, text in texts.items() if b"njit" in text})


def _sources_digest(root: Path, texts: dict[Path, bytes]) -> str:
    """A digest of modules by their path under ``root`` and their text."""
    h = hashlib.sha256()
    for path in sorted(texts):
        h.update(path.relative_to(root).as_posix().encode() + b"\0" + texts[path] + b"\0")
    return h.hexdigest()[:16]


@functools.cache
def imported_sources_digest(module: str, root: Path | None = None) -> str:
    """A digest of the module ``module`` (dotted, within the package under ``root``, the
    package itself when None) and of every module of the package it imports, transitively
    (relative imports and absolute ones of the package, anywhere in a module: at its top,
    inside functions, under ``TYPE_CHECKING``), by path and text. A cache of what that
    module computes, keyed by it, is never read by other code: an edited module it uses
    gives a new digest without a version bump. Parent packages' ``__init__`` modules are
    not followed, only what is imported by name."""
    root = Path(__file__).resolve().parent if root is None else root
    start = _module_file(root, module.split(".")[1:] if module.split(".")[0] == root.name else module.split("."))
    if start is None:
        raise ValueError(f"no module {module!r} under {root}")
    texts: dict[Path, bytes] = {}
    todo = [start]
    while todo:
        path = todo.pop()
        if path in texts:
            continue
        texts[path] = path.read_bytes()
        here = path.relative_to(root).parent.parts  # the package the module is in
        for node in _imports(texts[path], root.name):
            names: list[list[str]] = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    up = node.level - 1
                    if up > len(here):
                        continue
                    base = [*here[: len(here) - up], *(node.module.split(".") if node.module else [])]
                elif node.module and node.module.split(".")[0] == root.name:
                    base = node.module.split(".")[1:]
                else:
                    continue
                names = [base] + [[*base, a.name] for a in node.names]  # ``from . import x``: module x
            elif isinstance(node, ast.Import):
                names = [a.name.split(".")[1:] for a in node.names if a.name.split(".")[0] == root.name]
            for parts in names:
                found = _module_file(root, parts)
                if found is not None:
                    todo.append(found)
    return _sources_digest(root, texts)


def _imports(text: bytes, package: str) -> list[ast.stmt]:
    """The import statements of a module's source, wherever they stand: each statement's
    lines parsed alone (parsing whole modules took 0.1 s for the static model's 14), the
    whole module when a statement of the package does not parse so (a backslash line)."""
    out: list[ast.stmt] = []
    lines = text.decode("utf-8").splitlines()
    ours = ("from .", f"from {package}", f"import {package}")
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line.startswith(("from ", "import ")):
            continue
        stmt = line
        while stmt.count("(") > stmt.count(")") and i < len(lines):  # ``from x import (a,\n b)``
            stmt += " " + lines[i].strip()
            i += 1
        try:
            out.extend(n for n in ast.parse(stmt).body if isinstance(n, ast.Import | ast.ImportFrom))
        except SyntaxError:
            if stmt.startswith(ours):
                return [n for n in ast.walk(ast.parse(text)) if isinstance(n, ast.Import | ast.ImportFrom)]
            # else prose in a docstring that reads like an import
    return out


def _module_file(root: Path, parts: list[str]) -> Path | None:
    """The file of the package's module ``parts`` (a module or a package's ``__init__``)."""
    if not parts:
        return None  # the package's own ``__init__``: not followed
    path = root.joinpath(*parts)
    for f in (path.with_suffix(".py"), path / "__init__.py"):
        if f.is_file():
            return f.resolve()
    return None


def use_numba_cache() -> None:
    """Cache the compiled kernels under the cache directory's ``numba/<digest>`` folder
    (unless ``NUMBA_CACHE_DIR`` is set), not next to the sources: numba's files written
    into site-packages outlive ``pip uninstall``, and their empty ``polyhull`` folder then
    shadows a later editable install as a namespace package. With ``POLYHULL_CACHE_DIR``
    off, the kernels still go to the default place under the user's cache.

    The digest (:func:`kernel_sources_digest`) makes a stale kernel impossible: numba
    checks only the stamp of the file that defines a kernel, so a kernel that inlines or
    calls one from another module (:mod:`polyhull.engine.rounding`, say) would keep the
    old callee's code after only that module changed. Folders of other digests are left
    for other installed versions (delete ``numba`` under the cache directory to reclaim
    them)."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    base = cache_directory()
    if base is None:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg) if xdg else Path.home() / ".cache") / "polyhull"
    path = str(base / "numba" / kernel_sources_digest())
    os.environ["NUMBA_CACHE_DIR"] = path
    config = sys.modules.get("numba.core.config")
    if config is not None:  # numba imported first: it read its settings already
        config.CACHE_DIR = path  # type: ignore[attr-defined]


def kernel_cache_directory() -> Path | None:
    """Where numba caches the compiled kernels (``NUMBA_CACHE_DIR``; None when unset)."""
    config = sys.modules.get("numba.core.config")
    path = getattr(config, "CACHE_DIR", None) or os.environ.get("NUMBA_CACHE_DIR")
    return Path(path) if path else None


def kernels_cached() -> bool:
    """Whether the kernel cache folder holds compiled kernels (numba's ``.nbi`` index
    files): False on a first run of this version, which compiles them."""
    path = kernel_cache_directory()
    return path is not None and path.is_dir() and next(path.rglob("*.nbi"), None) is not None
