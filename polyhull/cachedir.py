"""Where polyhull caches what it computes once: static models and compiled kernels.

Standard library only: the package's ``__init__`` uses it before numba is imported.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["cache_directory", "use_numba_cache"]

_OFF = ("", "0", "off", "none", "false")


def cache_directory() -> Path | None:
    """Where static models are cached: ``POLYHULL_CACHE_DIR`` (None when it is ``off``),
    else ``$XDG_CACHE_HOME/polyhull`` or ``~/.cache/polyhull``."""
    env = os.environ.get("POLYHULL_CACHE_DIR")
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "polyhull"


def use_numba_cache() -> None:
    """Cache the compiled kernels under the cache directory's ``numba`` folder (unless
    ``NUMBA_CACHE_DIR`` is set), not next to the sources: numba's files written into
    site-packages outlive ``pip uninstall``, and their empty ``polyhull`` folder then
    shadows a later editable install as a namespace package. With ``POLYHULL_CACHE_DIR``
    off, the kernels still go to the default place under the user's cache."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return
    base = cache_directory()
    if base is None:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg) if xdg else Path.home() / ".cache") / "polyhull"
    path = str(base / "numba")
    os.environ["NUMBA_CACHE_DIR"] = path
    config = sys.modules.get("numba.core.config")
    if config is not None:  # numba imported first: it read its settings already
        config.CACHE_DIR = path  # type: ignore[attr-defined]
