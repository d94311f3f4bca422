"""What every recording reader yields: depth frames and joint samples in time order.

A reader (:mod:`.rosbag`, :mod:`.folder`) streams a recording as *events*, each a
:class:`~polyhull.frames.DepthFrame` of one camera or a :class:`JointSample`, in the order
they were recorded; nothing is loaded whole. :func:`polyhull.recordings.sync.cycles`
matches the frames of the cameras by time into :class:`Cycle` values, one per
monitor step.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

from ..frames import DepthFrame
from ..typed import ArrayF64

__all__ = ["JointSample", "Cycle", "Event", "Recording"]


class JointSample(NamedTuple):
    """One joint state.

    Attributes:
        stamp: Measurement time [s].
        q: (dof,) joint positions [rad] in URDF order.
    """

    stamp: float
    q: ArrayF64


Event = DepthFrame | JointSample


class Cycle(NamedTuple):
    """The input of one monitor step: frames matched by time and the joint state.

    Attributes:
        stamp: Cycle time [s]: the newest frame's stamp.
        frames: Camera name -> frame; a camera without a frame within the matching
            window is absent (the monitor reports it missing).
        q: (dof,) joint positions [rad], or None when the recording has no joint state.
        q_stamp: When ``q`` was measured [s], or None.
    """

    stamp: float
    frames: dict[str, DepthFrame]
    q: ArrayF64 | None
    q_stamp: float | None


class Recording(ABC):
    """A recording of a cell's cameras (and maybe its robot's joint state).

    Attributes:
        path: Where it is read from.
        cameras: The cell's camera names the recording holds frames of, in cell order.
    """

    path: Path
    cameras: tuple[str, ...]

    @abstractmethod
    def events(self, cameras: tuple[str, ...] | None = None, joints: bool = True) -> Iterator[Event]:
        """Stream the frames of ``cameras`` (all when None) and, with ``joints``, the joint
        samples, in recorded order."""

    @abstractmethod
    def frame_count(self, camera: str) -> int:
        """How many frames the recording holds for ``camera`` (without reading them)."""

    @property
    @abstractmethod
    def has_joints(self) -> bool:
        """Whether the recording holds joint states."""
