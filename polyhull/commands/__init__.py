"""Sub-commands of the ``polyhull`` command line, one module each."""

import importlib.util

from ..errors import MissingExtraError


def counted(n: int, noun: str) -> str:
    """``"1 cycle"``, ``"0 cycles"``, ``"3 cycles"``: ``n`` and ``noun``, plural unless one."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def require_extra(module: str, feature: str, extra: str) -> None:
    """Raise :class:`MissingExtraError` for ``feature`` (naming ``extra``) when ``module`` is
    not installed: checked before a command does any work."""
    if importlib.util.find_spec(module) is None:
        raise MissingExtraError(feature, extra)
