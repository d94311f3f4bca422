"""Writing recordings: ROS bags (``rosbags``' writers) and folders of depth images (``imageio``).

The inverse of the readers, for fixtures, tests and converting simulated or recorded
frames: per cycle, every camera's depth image (``16UC1`` millimetres or ``32FC1`` metres)
and its ``CameraInfo``, and the robot's ``JointState``.
"""

from __future__ import annotations

import contextlib
import csv
import math
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from ..camera import Camera
from ..cell import Cell
from ..errors import FrameError
from ..frames import DepthFrame
from ..typed import ArrayF64
from .rosbag import camera_topic, info_topic

__all__ = ["RecordedCycle", "write_bag", "write_folder", "depth_to_millimetres"]

Encoding = Literal["16UC1", "32FC1"]


class RecordedCycle(NamedTuple):
    """What one cycle writes: frames (their own stamps), and the joint state at ``stamp``."""

    stamp: float
    frames: Mapping[str, DepthFrame]
    q: ArrayF64 | None


def depth_to_millimetres(depth: np.ndarray) -> np.ndarray:
    """(H, W) uint16 millimetres of a depth image [m] (0 where unknown, REP 118)."""
    d = np.asarray(depth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(d) & (d > 0) & (d * 1000.0 < 65535.5)
    return np.where(ok, np.round(np.where(ok, d, 0.0) * 1000.0), 0.0).astype(np.uint16)


def _time(ts: Any, stamp: float) -> Any:
    sec = math.floor(stamp)
    nsec = int(round((stamp - sec) * 1e9))
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return ts.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=nsec)


def _header(ts: Any, stamp: float, frame_id: str, ros1: bool) -> Any:
    Header = ts.types["std_msgs/msg/Header"]
    if ros1:
        return Header(seq=0, stamp=_time(ts, stamp), frame_id=frame_id)
    return Header(stamp=_time(ts, stamp), frame_id=frame_id)


def _image(ts: Any, frame: DepthFrame, encoding: Encoding, ros1: bool) -> Any:
    if encoding == "16UC1":
        pixels = depth_to_millimetres(frame.depth).astype("<u2")
    elif encoding == "32FC1":
        pixels = np.asarray(frame.depth, dtype="<f4")
    else:
        raise FrameError(f"encoding must be '16UC1' or '32FC1', got {encoding!r}")
    H, W = pixels.shape
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, frame.stamp, f"{frame.camera}_depth_optical_frame", ros1),
        height=H,
        width=W,
        encoding=encoding,
        is_bigendian=0,
        step=W * pixels.dtype.itemsize,
        data=np.frombuffer(pixels.tobytes(), dtype=np.uint8),
    )


def _camera_info(ts: Any, camera: Camera, stamp: float, ros1: bool) -> Any:
    k = camera.intrinsics
    K = np.array([k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0])
    P = np.array([k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    fields = {"D": np.zeros(5), "K": K, "R": np.eye(3).ravel(), "P": P}
    if not ros1:
        fields = {key.lower(): v for key, v in fields.items()}
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, stamp, f"{camera.name}_depth_optical_frame", ros1),
        height=k.height,
        width=k.width,
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        roi=roi,
        **fields,
    )


def _joint_state(ts: Any, names: tuple[str, ...], q: ArrayF64, stamp: float, ros1: bool) -> Any:
    return ts.types["sensor_msgs/msg/JointState"](
        header=_header(ts, stamp, "", ros1),
        name=list(names),
        position=np.asarray(q, dtype=np.float64),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )


def _joint_names(cell: Cell) -> tuple[str, ...]:
    if cell.robot is None:
        return ()
    from ..robot import Robot

    return Robot.from_spec(cell.robot).joint_names


@contextlib.contextmanager
def _bag_writer(path: Path) -> Iterator[tuple[Any, Any, bool]]:
    """(writer, typestore, is_ros1) for a new bag at ``path`` (by suffix)."""
    from rosbags.typesys import Stores, get_typestore

    suffix = path.suffix.lower()
    if suffix == ".bag":
        from rosbags.rosbag1 import Writer as Writer1

        with Writer1(path) as w1:
            yield w1, get_typestore(Stores.ROS1_NOETIC), True
        return
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    plugin = {".db3": StoragePlugin.SQLITE3, "": StoragePlugin.MCAP, ".mcap": StoragePlugin.MCAP}.get(suffix)
    if plugin is None:
        raise FrameError(f"{path}: a bag is written as <dir> or <dir>.mcap (ROS 2 MCAP), <dir>.db3 or <file>.bag")
    w2 = Writer(path.with_suffix("") if suffix else path, version=9, storage_plugin=plugin)
    if plugin == StoragePlugin.MCAP:
        w2.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with w2:
        yield w2, get_typestore(Stores.ROS2_HUMBLE), False


def write_bag(
    path: str | Path,
    cell: Cell,
    cycles: Iterable[RecordedCycle],
    *,
    encoding: Encoding = "16UC1",
    camera_info: bool = True,
) -> Path:
    """Write ``cycles`` of ``cell``'s cameras to a new ROS bag.

    Args:
        path: ``name.bag`` (ROS 1), ``name.db3`` (ROS 2 SQLite) or ``name`` / ``name.mcap``
            (ROS 2 MCAP, zstd chunks); a ROS 2 bag is the directory ``name`` holding
            ``metadata.yaml`` and the storage file.
        cell: The cell: camera topics (``topic``, or ``/<name>/depth/image_raw``),
            intrinsics, and the robot's joint names and ``robot.joint_state_topic``.
        cycles: The cycles to write, in time order.
        encoding: ``16UC1`` (uint16 millimetres) or ``32FC1`` (float32 metres).
        camera_info: Also write each camera's ``CameraInfo`` with each image.

    Returns:
        The path the readers open (the ROS 2 bag directory, or the ``.bag`` file).
    """
    path = Path(path)
    names = _joint_names(cell)
    cams = {c.name: c for c in cell.cameras}
    with _bag_writer(path) as (writer, ts, ros1):
        serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
        conns: dict[str, Any] = {}

        def conn(topic: str, msgtype: str) -> Any:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            return conns[topic]

        for cycle in cycles:
            for name, frame in cycle.frames.items():
                cam = cams[name]
                topic = camera_topic(cam)
                t_ns = int(round(frame.stamp * 1e9))
                msg = _image(ts, frame, encoding, ros1)
                writer.write(conn(topic, msg.__msgtype__), t_ns, serialize(msg, msg.__msgtype__))
                if camera_info:
                    info = _camera_info(ts, cam, frame.stamp, ros1)
                    writer.write(conn(info_topic(topic), info.__msgtype__), t_ns, serialize(info, info.__msgtype__))
            if cycle.q is not None and names and cell.robot is not None:
                js = _joint_state(ts, names, cycle.q, cycle.stamp, ros1)
                writer.write(
                    conn(cell.robot.joint_state_topic, js.__msgtype__),
                    int(round(cycle.stamp * 1e9)),
                    serialize(js, js.__msgtype__),
                )
    return path if ros1 else (path.with_suffix("") if path.suffix else path)


def write_folder(
    path: str | Path, cell: Cell, cycles: Iterable[RecordedCycle], *, encoding: Encoding = "16UC1"
) -> Path:
    """Write ``cycles`` as a folder of depth images (:mod:`polyhull.recordings.folder`):
    ``<camera>/<stamp>.png`` (16-bit PNG millimetres) or ``.tiff`` (float32 metres), stamps
    in seconds with six decimals, and ``joint_states.csv``."""
    import imageio.v3 as iio

    path = Path(path)
    names = _joint_names(cell)
    path.mkdir(parents=True, exist_ok=True)
    joints_path = path / "joint_states.csv"
    with joints_path.open("w", newline="", encoding="utf-8") as handle:
        out = csv.writer(handle)
        out.writerow(["stamp", *names])
        for cycle in cycles:
            for name, frame in cycle.frames.items():
                directory = path / name
                directory.mkdir(exist_ok=True)
                if encoding == "16UC1":
                    iio.imwrite(directory / f"{frame.stamp:.6f}.png", depth_to_millimetres(frame.depth))
                else:
                    iio.imwrite(directory / f"{frame.stamp:.6f}.tiff", np.asarray(frame.depth, dtype=np.float32))
            if cycle.q is not None and names:
                out.writerow([f"{cycle.stamp:.6f}", *(repr(float(x)) for x in cycle.q)])
    return path
