"""A folder of depth images per camera (16-bit PNG millimetres or float32 TIFF metres).

Layout::

    RECORDING/
      <camera>/             one folder per camera name of the cell
        <stamp>.png         16-bit PNG, uint16 millimetres (REP 118, 0 = unknown), or
        <stamp>.tif[f]      32-bit float TIFF, metres (REP 117 special values)
        stamps.csv          optional: a header "file,stamp", then one row per image
      joint_states.csv      optional: "stamp,<joint names>" (see polyhull.recordings.joints)

Without ``stamps.csv`` the stamp comes from the file name: ``12.345678.png`` is seconds,
``1700000000123456789.png`` (an integer) nanoseconds, as ROS stamps. Images are read
one at a time (``imageio``) in stamp order.
"""

from __future__ import annotations

import csv
import heapq
import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import FrameError
from ..frames import DepthFrame
from .base import Event, Recording
from .joints import JointOrder, read_joint_csv

__all__ = ["FolderRecording", "IMAGE_SUFFIXES", "stamp_of_name"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
_NUMBER = re.compile(r"^\d+(\.\d+)?$")


def stamp_of_name(path: Path) -> float:
    """The stamp [s] in an image's file name (seconds with a decimal point, or integer
    nanoseconds)."""
    stem = path.stem
    if not _NUMBER.match(stem):
        raise FrameError(
            f"{path}: no stamp in the file name (expected seconds like 12.345678{path.suffix} or "
            f"integer nanoseconds), and no stamps.csv beside it"
        )
    return float(stem) if "." in stem else int(stem) * 1e-9


def _stamps_csv(path: Path, directory: Path) -> list[tuple[float, Path]]:
    out = []
    with path.open(newline="", encoding="utf-8") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None or [h.strip() for h in header[:2]] != ["file", "stamp"]:
            raise FrameError(f"{path}: line 1: expected a header 'file,stamp', got {header!r}")
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            try:
                stamp = float(row[1])
            except (IndexError, ValueError):
                raise FrameError(f"{path}: line {line}: expected 'file,stamp [s]', got {row!r}") from None
            if not math.isfinite(stamp):
                raise FrameError(f"{path}: line {line}: stamp must be finite, got {row[1]!r}")
            image = directory / row[0].strip()
            if not image.is_file():
                raise FrameError(f"{path}: line {line}: no such image {image}")
            out.append((stamp, image))
    return out


def read_depth_image(path: Path, camera: Camera) -> np.ndarray:
    """The (H, W) depth array of one image file: uint16 [mm] or float32 [m]."""
    import imageio.v3 as iio

    try:
        image = np.asarray(iio.imread(path))
    except Exception as exc:  # noqa: BLE001 - imageio's plugins raise many types; wrap them
        raise FrameError(f"{path}: not a readable image ({exc})") from None
    if image.dtype == np.uint16 or image.dtype == np.float32:
        pass
    elif image.dtype == np.float64:
        image = image.astype(np.float32)
    else:
        raise FrameError(
            f"{path}: depth images must be 16-bit (uint16 millimetres) or 32-bit float (metres), "
            f"got {image.dtype} {image.shape}"
        )
    if image.shape != camera.shape:
        raise FrameError(
            f"{path}: image shape {image.shape} != (H, W) {camera.shape} of camera '{camera.name}'"
        )
    return image


class FolderRecording(Recording):
    """Depth images in one folder per camera (see the module docstring).

    Args:
        path: The recording's folder.
        cameras: The cell's cameras; those with a sub-folder are read.
        joint_order: The robot's joint order (None: joint states are not read).
        joints_csv: A joint-state CSV (default: ``joint_states.csv`` in the folder, if any).
    """

    def __init__(
        self,
        path: str | Path,
        cameras: tuple[Camera, ...],
        joint_order: JointOrder | None = None,
        joints_csv: Path | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise FrameError(f"{self.path}: no such folder of depth images")
        self._cameras = {c.name: c for c in cameras}
        self._files: dict[str, list[tuple[float, Path]]] = {}
        for cam in cameras:
            directory = self.path / cam.name
            if not directory.is_dir():
                continue
            stamps = directory / "stamps.csv"
            if stamps.is_file():
                files = _stamps_csv(stamps, directory)
            else:
                files = [
                    (stamp_of_name(p), p)
                    for p in directory.iterdir()
                    if p.suffix.lower() in IMAGE_SUFFIXES
                ]
            if files:
                files.sort(key=lambda sp: sp[0])
                self._files[cam.name] = files
        if not self._files:
            raise FrameError(
                f"{self.path}: holds no depth images of the cameras {list(self._cameras)} "
                f"(expected {self.path}/<camera>/<stamp>.png)"
            )
        self.cameras = tuple(c.name for c in cameras if c.name in self._files)
        self._joint_order = joint_order
        csv_path = joints_csv if joints_csv is not None else self.path / "joint_states.csv"
        self._joints_csv = csv_path if joint_order is not None and csv_path.is_file() else None

    def frame_count(self, camera: str) -> int:
        return len(self._files.get(camera, ()))

    @property
    def has_joints(self) -> bool:
        return self._joints_csv is not None

    def _frames(self, name: str) -> Iterator[DepthFrame]:
        camera = self._cameras[name]
        for seq, (stamp, path) in enumerate(self._files[name]):
            try:
                yield DepthFrame(camera=name, depth=read_depth_image(path, camera), stamp=stamp, seq=seq)
            except FrameError as exc:
                message = str(exc)
                raise FrameError(message if message.startswith(str(path)) else f"{path}: {message}") from None

    def events(self, cameras: tuple[str, ...] | None = None, joints: bool = True) -> Iterator[Event]:
        names = self.cameras if cameras is None else tuple(c for c in cameras if c in self._files)
        streams: list[Iterator[Event]] = [self._frames(n) for n in names]
        if joints and self._joints_csv is not None and self._joint_order is not None:
            streams.append(read_joint_csv(self._joints_csv, self._joint_order))
        return heapq.merge(*streams, key=lambda e: e.stamp)
