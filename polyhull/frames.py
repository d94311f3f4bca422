"""Depth frames and frames files.

A depth image is z-depth (not ray length) in [m] as float32, or uint16 millimetres as
RealSense, Kinect and ROS write it. Special values follow ROS REP 117: 0 and NaN are
unknown (the pixel frees nothing), -inf is "too close" (nothing free), +inf is "no return"
(free up to the rated range). Values outside the camera's range are invalid too.

A frames file is ``.npz``: one float32 (H, W) depth array [m] per camera name, plus ``q``
(joint positions [rad]) and ``stamp`` [s].
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import FrameError
from .typed import ArrayF32, ArrayF64

__all__ = ["DepthFrame", "FramesFile", "check_cameras", "load_frames", "save_frames"]

_RESERVED = ("q", "stamp")


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One depth image of one camera.

    Attributes:
        camera: Name of the camera that took it.
        depth: (H, W) float32 z-depth [m] (read-only).
        stamp: Acquisition time [s].
        seq: Frame counter, if the driver gives one (duplicate detection).
    """

    camera: str
    depth: ArrayF32
    stamp: float = 0.0
    seq: int | None = None

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth)
        if depth.ndim != 2 or depth.size == 0:
            raise FrameError(
                f"frame of camera '{self.camera}': depth must be a 2-D (H, W) array, "
                f"got shape {depth.shape}"
            )
        if depth.dtype == np.uint16:
            depth = depth.astype(np.float32) * np.float32(1e-3)  # 0 stays 0: unknown
        elif depth.dtype in (np.float32, np.float64):
            depth = depth.astype(np.float32, copy=depth.dtype != np.float32)
        else:
            raise FrameError(
                f"frame of camera '{self.camera}': depth dtype must be float32 metres or "
                f"uint16 millimetres, got {depth.dtype}"
            )
        if depth is self.depth:
            depth = depth.copy()
        depth.setflags(write=False)
        object.__setattr__(self, "depth", depth)
        if not np.isfinite(self.stamp):
            raise FrameError(f"frame of camera '{self.camera}': stamp must be finite, got {self.stamp!r}")
        object.__setattr__(self, "stamp", float(self.stamp))

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return self.depth.shape  # type: ignore[return-value]


@dataclass(frozen=True, eq=False)
class FramesFile:
    """The content of a frames file: depth per camera, joint positions and a stamp."""

    frames: dict[str, DepthFrame]
    q: ArrayF64
    stamp: float


def save_frames(path: str | Path, frames: Mapping[str, DepthFrame], q: ArrayF64, stamp: float) -> Path:
    """Write ``frames`` (camera name -> DepthFrame), ``q`` [rad] and ``stamp`` [s] to ``.npz``."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    for name, frame in frames.items():
        if name in _RESERVED:
            raise FrameError(f"{path}: camera name {name!r} is reserved in frames files")
        arrays[name] = np.asarray(frame.depth, dtype=np.float32)
    arrays["q"] = np.asarray(q, dtype=np.float64)
    arrays["stamp"] = np.asarray(float(stamp))
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
    return path


def open_npz(path: Path, error: type[Exception], what: str) -> np.lib.npyio.NpzFile:
    """``np.load`` of an .npz of named arrays (no pickles); any other content raises
    ``error`` with one line naming the file and ``what`` it should be. The first bytes are
    looked at before numpy opens the file: numpy takes anything else for a pickle, and its
    message invites an unsafe load."""
    try:
        with path.open("rb") as f:
            head = f.read(6)
    except OSError as exc:
        raise error(f"{path}: not a readable .npz {what} ({exc.strerror or exc})") from None
    if head.startswith(b"\x80"):  # pickle protocol 2 and later
        raise error(f"{path}: not an .npz {what} (it holds pickled objects, which polyhull never loads)")
    if not head.startswith((b"PK\x03\x04", b"PK\x05\x06", b"\x93NUMPY")):  # a zip (an empty one), an .npy
        raise error(f"{path}: not an .npz {what} (not a zip archive of named arrays)")
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"{path}: not a readable .npz {what} ({exc})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise error(f"{path}: not an .npz {what} (one array, not named fields)")
    return data


def check_cameras(path: str | Path, recorded: FramesFile, cameras: Iterable[str]) -> None:
    """Refuse a frames file with a camera the cell does not have: frames of another cell
    (a camera missing from the file is a fault of its cycle, a stop, not an input error).

    Raises:
        FrameError: Naming the file, its unknown cameras and the cell's.
    """
    known = set(cameras)
    unknown = sorted(set(recorded.frames) - known)
    if unknown:
        raise FrameError(
            f"{path}: frames of camera{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}, which the "
            f"cell does not have (its cameras: {', '.join(sorted(known))}): frames of another cell?"
        )


def load_frames(path: str | Path) -> FramesFile:
    """Read a frames file; raise :class:`FrameError` naming the file and field when invalid."""
    path = Path(path)
    if not path.is_file():
        raise FrameError(f"{path}: no such frames file")
    with open_npz(path, FrameError, "frames file") as data:
        keys = list(data.keys())
        arrays: dict[str, np.ndarray] = {}
        for key in keys:
            try:
                arrays[key] = data[key]
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                # a truncated archive, or an object array (never unpickled)
                raise FrameError(f"{path}: field {key!r} cannot be read ({exc})") from exc
        for key in _RESERVED:
            if key not in keys:
                raise FrameError(f"{path}: missing field {key!r} (frames files hold q and stamp)")
        if arrays["q"].dtype.kind not in "iuf":
            raise FrameError(f"{path}: field 'q' must be real numbers [rad], got dtype {arrays['q'].dtype}")
        try:
            q = np.asarray(arrays["q"], dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise FrameError(f"{path}: field 'q' must be real numbers [rad] ({exc})") from exc
        if not np.all(np.isfinite(q)):
            raise FrameError(f"{path}: field 'q' must be finite, got {q.tolist()}")
        stamp_arr = np.asarray(arrays["stamp"])
        # a real number only (a string or complex stamp is not a time)
        if stamp_arr.size != 1 or stamp_arr.dtype.kind not in "iuf" or not np.isfinite(float(stamp_arr.reshape(-1)[0])):
            raise FrameError(f"{path}: field 'stamp' must be one finite number [s]")
        stamp = float(stamp_arr.reshape(-1)[0])
        frames: dict[str, DepthFrame] = {}
        for key in keys:
            if key in _RESERVED:
                continue
            try:
                frames[key] = DepthFrame(camera=key, depth=arrays[key], stamp=stamp)
            except FrameError as exc:
                raise FrameError(f"{path}: field {key!r}: {exc}") from exc
    if not frames:
        raise FrameError(f"{path}: holds no depth arrays (one per camera name expected)")
    return FramesFile(frames=frames, q=q, stamp=stamp)
