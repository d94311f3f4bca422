"""Where polyhull caches what it computes once: static models and compiled kernels.

Standard library only: the package's ``__init__`` uses it before numba is imported.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

__all__ = ["cache_directory", "kernel_cache_directory", "kernel_sources_digest", "kernels_cached", "use_numba_cache"]

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
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if b"njit" in text:
            h.update(path.relative_to(root).as_posix().encode() + b"\0" + text + b"\0")
    return h.hexdigest()[:16]


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
