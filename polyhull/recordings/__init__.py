"""Recorded sensor data in: ROS bags and folders of depth images, streamed as frames.

:func:`open_recording` picks the reader for a path (:mod:`.rosbag`, :mod:`.folder`);
:func:`~.sync.cycles` matches the cameras' frames by time (``safety.max_frame_age``) into
monitor cycles with the joint state of each.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from ..cell import Cell
from ..errors import FrameError
from .base import Cycle, Event, JointSample, Recording
from .joints import JointOrder, read_joint_csv
from .sync import cycles

__all__ = [
    "Cycle",
    "Event",
    "JointSample",
    "JointOrder",
    "Recording",
    "cycles",
    "open_recording",
    "recording_cycles",
    "read_joint_csv",
]


def _joint_order(cell: Cell) -> JointOrder | None:
    if cell.robot is None:
        return None
    from ..robot import Robot

    return JointOrder(Robot.from_spec(cell.robot).joint_names)


def open_recording(path: str | Path, cell: Cell, *, joints_csv: str | Path | None = None) -> Recording:
    """Open a recording of ``cell``'s cameras.

    Args:
        path: A ROS bag (``.mcap``, ``.db3``, ``.bag``, or a ROS 2 bag directory with
            ``metadata.yaml``) or a folder of depth images (one sub-folder per camera).
        cell: The cell: its cameras (topics, shapes) and robot (joint names).
        joints_csv: Read the joint state from this CSV instead of the recording.

    Raises:
        FrameError: The path is missing or not a recording of the cell's cameras; the
            message names the path and what was expected.
    """
    from .folder import FolderRecording
    from .rosbag import BAG_SUFFIXES, BagRecording

    path = Path(path)
    order = _joint_order(cell)
    csv_path = None if joints_csv is None else Path(joints_csv)
    if csv_path is not None and not csv_path.is_file():
        raise FrameError(f"{csv_path}: no such joint-state CSV")
    if not path.exists():
        raise FrameError(f"{path}: no such recording (a ROS bag or a folder of depth images)")
    is_bag = path.suffix.lower() in BAG_SUFFIXES or (path.is_dir() and (path / "metadata.yaml").is_file())
    if is_bag:
        topic = cell.robot.joint_state_topic if cell.robot is not None else "/joint_states"
        recording: Recording = BagRecording(
            path, cell.cameras, joint_order=None if csv_path is not None else order, joint_topic=topic
        )
        if csv_path is not None and order is not None:
            return _WithJointCsv(recording, csv_path, order)
        return recording
    if path.is_dir():
        return FolderRecording(path, cell.cameras, joint_order=order, joints_csv=csv_path)
    raise FrameError(
        f"{path}: not a recording (expected a {', '.join(BAG_SUFFIXES)} bag, a ROS 2 bag "
        "directory or a folder of depth images)"
    )


class _WithJointCsv(Recording):
    """A recording whose joint state comes from a CSV file instead."""

    def __init__(self, inner: Recording, csv_path: Path, order: JointOrder) -> None:
        self.path = inner.path
        self.cameras = inner.cameras
        self._inner = inner
        self._csv = csv_path
        self._order = order

    def frame_count(self, camera: str) -> int:
        return self._inner.frame_count(camera)

    @property
    def has_joints(self) -> bool:
        return True

    def events(self, cameras: tuple[str, ...] | None = None, joints: bool = True) -> Iterator[Event]:
        import heapq

        streams: list[Iterator[Event]] = [self._inner.events(cameras, joints=False)]
        if joints:
            streams.append(read_joint_csv(self._csv, self._order))
        return heapq.merge(*streams, key=lambda e: e.stamp)


def recording_cycles(recording: Recording, cell: Cell) -> Iterator[Cycle]:
    """The monitor cycles of a recording: its frames matched within ``safety.max_frame_age``."""
    names = tuple(c.name for c in cell.cameras if c.name in recording.cameras)
    return cycles(recording.events(names), names, cell.safety.max_frame_age)
