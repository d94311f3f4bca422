"""The ``polyhull`` command line: one sub-command per module in :mod:`polyhull.commands`.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` to a function taking the parsed arguments and returning the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from .errors import PolyhullError

__all__ = ["main", "build_parser"]

# Order is the order of --help.
COMMANDS = ("demo", "run", "render", "view", "place", "bench", "soak", "teach", "replay")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every available sub-command."""
    parser = argparse.ArgumentParser(
        prog="polyhull",
        description=(
            "Polyhedral safety surveillance of human/robot work cells: depth hull, robot "
            "occlusion, distance and speed-and-separation monitoring."
        ),
    )
    from . import __version__

    parser.add_argument("--version", action="version", version=f"polyhull {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"polyhull.commands.{name}")
        module.register(sub)
    for command in sub.choices.values():
        command.set_defaults(command_parser=command)  # who reports a sub-command's stray arguments
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``polyhull`` console script; returns the exit code."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()  # inside the try: a closed pipe shows here, not at exit
    except BrokenPipeError:
        # The reader of stdout went away (``polyhull ... | head``): stop quietly, as a
        # shell tool does, and keep Python from reporting the flush at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        # reported by the sub-command's parser: its usage, and ``polyhull demo: error: ...``
        getattr(args, "command_parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    logger = logging.getLogger("polyhull")
    handler = _StderrLines(args.command)
    level = logger.level
    logger.addHandler(handler)
    if level == logging.NOTSET or level > logging.INFO:
        logger.setLevel(logging.INFO)
    try:
        return int(args.func(args))
    except PolyhullError as exc:
        print(f"polyhull {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"polyhull {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


class _StderrLines(logging.Handler):
    """The library's log records (INFO and above: a static model built and where it is
    cached, kernels compiled on a first run, a cache that cannot be written) as lines
    ``polyhull COMMAND: ...`` on the stderr of the moment (stdout stays the command's
    output, ``--json`` only JSON)."""

    def __init__(self, command: str) -> None:
        super().__init__(logging.INFO)
        self.command = command

    def emit(self, record: logging.LogRecord) -> None:
        try:
            kind = "warning: " if record.levelno >= logging.WARNING else ""
            sys.stderr.write(f"polyhull {self.command}: {kind}{record.getMessage()}\n")
            sys.stderr.flush()
        except Exception:  # noqa: BLE001 - logging's own contract: report, never raise
            self.handleError(record)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
