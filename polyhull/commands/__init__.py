"""Sub-commands of the ``polyhull`` command line, one module each."""


def counted(n: int, noun: str) -> str:
    """``"1 cycle"``, ``"0 cycles"``, ``"3 cycles"``: ``n`` and ``noun``, plural unless one."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
