"""The exception hierarchy of polyhull.

Every error polyhull raises is a :class:`PolyhullError`; errors of the libraries below
(manifold3d, python-fcl, trimesh, yourdfpy) are wrapped so they never leak. Messages name
the file, the entry (``cameras[2].intrinsics``) and what was expected, and say how to fix it.
"""

from __future__ import annotations

__all__ = [
    "PolyhullError",
    "CellError",
    "CameraError",
    "FrameError",
    "GeometryError",
    "RobotError",
    "MissingExtraError",
]


class PolyhullError(Exception):
    """Base class of every error raised by polyhull."""


class CellError(PolyhullError):
    """A cell file (or an entry of it) is invalid; nothing was applied."""


class CameraError(PolyhullError):
    """Camera intrinsics, pose or range are invalid."""


class FrameError(PolyhullError):
    """A depth frame has the wrong shape, dtype or metadata."""


class GeometryError(PolyhullError):
    """A mesh is empty or non-finite, or the geometry engine (manifold3d, FCL) failed."""


class RobotError(PolyhullError):
    """The robot description (URDF) or a joint vector is invalid."""


class MissingExtraError(PolyhullError, ImportError):
    """An optional part of polyhull was used without its extra installed."""

    def __init__(self, feature: str, extra: str) -> None:
        super().__init__(
            f"{feature} needs the optional '{extra}' extra: pip install 'polyhull[{extra}]'"
        )
