"""ROS bags through ``rosbags`` (pure Python, no ROS install): ROS 2 (``.mcap``, ``.db3``
or a bag directory with ``metadata.yaml``) and ROS 1 (``.bag``).

Per camera, the depth topic is the cell's ``topic`` key (default ``/<name>/depth/image_raw``)
with ``sensor_msgs/Image`` messages in ``16UC1`` (uint16 millimetres, 0 = unknown) or
``32FC1`` (float32 metres, REP 117 special values), as REP 118 fixes. Its
``sensor_msgs/CameraInfo`` (``camera_info`` in the same namespace), when recorded, must
agree with the cell's intrinsics. The stamp of a frame is its header stamp (the bag's
receive time when the header stamp is zero). The robot's joint state comes from the
``robot.joint_state_topic`` (``sensor_msgs/JointState``), reordered by joint name.
"""

from __future__ import annotations

import contextlib
import posixpath
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import FrameError
from .base import Event, JointSample, Recording
from .joints import JointOrder

__all__ = ["BagRecording", "camera_topic", "info_topic", "decode_depth_image", "check_camera_info", "BAG_SUFFIXES"]

#: File suffixes read as bags (a ROS 2 bag may also be its directory).
BAG_SUFFIXES = (".mcap", ".db3", ".bag")

_IMAGE = ("sensor_msgs/msg/Image", "sensor_msgs/Image")
_INFO = ("sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo")
_JOINTS = ("sensor_msgs/msg/JointState", "sensor_msgs/JointState")


def camera_topic(camera: Camera) -> str:
    """The depth topic of ``camera``: its ``topic`` key, else ``/<name>/depth/image_raw``."""
    return camera.topic if camera.topic else f"/{camera.name}/depth/image_raw"


def info_topic(topic: str) -> str:
    """The ``CameraInfo`` topic beside an image topic (same namespace, ``camera_info``)."""
    return posixpath.join(posixpath.dirname(topic) or "/", "camera_info")


def _stamp(msg: Any, fallback_ns: int) -> float:
    st = msg.header.stamp
    sec = getattr(st, "sec", None)
    if sec is None:  # ROS 1: secs / nsecs
        sec, nsec = st.secs, st.nsecs
    else:
        nsec = st.nanosec
    if sec == 0 and nsec == 0:
        return fallback_ns * 1e-9
    return float(sec) + float(nsec) * 1e-9


def decode_depth_image(msg: Any, camera: Camera, where: str) -> np.ndarray:
    """The (H, W) depth array of a ``sensor_msgs/Image`` (uint16 mm or float32 m).

    Raises:
        FrameError: ``where`` named with the encoding, shape or size at fault.
    """
    encoding = str(msg.encoding)
    dtype: np.dtype[Any]
    if encoding.lower() in ("16uc1", "mono16"):
        dtype = np.dtype(">u2" if msg.is_bigendian else "<u2")
    elif encoding.lower() == "32fc1":
        dtype = np.dtype(">f4" if msg.is_bigendian else "<f4")
    else:
        raise FrameError(
            f"{where}: encoding {encoding!r} is not a depth encoding "
            "(expected 16UC1 millimetres or 32FC1 metres, REP 118)"
        )
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if (h, w) != camera.shape:
        raise FrameError(
            f"{where}: image is {w} x {h} px, camera '{camera.name}' is "
            f"{camera.intrinsics.width} x {camera.intrinsics.height} px"
        )
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * dtype.itemsize or data.size < step * h:
        raise FrameError(
            f"{where}: {data.size} bytes with step {step} cannot hold {h} rows of {w} {encoding} pixels"
        )
    rows = data[: step * h].reshape(h, step)[:, : w * dtype.itemsize]
    return np.ascontiguousarray(rows).view(dtype).reshape(h, w).astype(dtype.newbyteorder("="))


def check_camera_info(msg: Any, camera: Camera, where: str) -> None:
    """Raise :class:`FrameError` when a ``CameraInfo`` disagrees with the cell's camera:
    another resolution, focal lengths off by more than 0.1 %, a principal point off by more
    than 0.5 px, or lens distortion (not supported)."""
    k = camera.intrinsics
    K = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, dtype=np.float64).reshape(-1)
    D = np.asarray(getattr(msg, "d", None) if hasattr(msg, "d") else msg.D, dtype=np.float64).reshape(-1)
    if (int(msg.width), int(msg.height)) != (k.width, k.height):
        raise FrameError(
            f"{where}: CameraInfo is {msg.width} x {msg.height} px, camera '{camera.name}' is "
            f"{k.width} x {k.height} px"
        )
    if K.size != 9 or not np.all(np.isfinite(K)):
        raise FrameError(f"{where}: CameraInfo K must be 9 finite numbers, got {K.tolist()}")
    fx, fy, cx, cy = K[0], K[4], K[2], K[5]
    if (
        abs(fx - k.fx) > 1e-3 * k.fx
        or abs(fy - k.fy) > 1e-3 * k.fy
        or abs(cx - k.cx) > 0.5
        or abs(cy - k.cy) > 0.5
    ):
        raise FrameError(
            f"{where}: CameraInfo K gives fx, fy, cx, cy = {[fx, fy, cx, cy]}, camera '{camera.name}' "
            f"has {[k.fx, k.fy, k.cx, k.cy]} [px]"
        )
    if D.size and np.any(np.abs(D) > 1e-9):
        raise FrameError(
            f"{where}: CameraInfo has lens distortion {D.tolist()}; polyhull needs rectified "
            "depth images (zero distortion)"
        )


class BagRecording(Recording):
    """A ROS 1 or ROS 2 bag (see the module docstring).

    Args:
        path: A ``.mcap``, ``.db3`` or ``.bag`` file, or a ROS 2 bag directory.
        cameras: The cell's cameras; those whose topic the bag holds are read.
        joint_order: The robot's joint order (None: no robot, joint states are not read).
        joint_topic: The ``sensor_msgs/JointState`` topic.

    Raises:
        FrameError: The bag cannot be opened, or holds none of the cameras' topics, or a
            topic has the wrong message type; the message names the bag and the topic.
    """

    def __init__(
        self,
        path: str | Path,
        cameras: tuple[Camera, ...],
        joint_order: JointOrder | None = None,
        joint_topic: str = "/joint_states",
    ) -> None:
        self.path = Path(path)
        self._cameras = {c.name: c for c in cameras}
        self._topics = {c.name: camera_topic(c) for c in cameras}
        self._joint_order = joint_order
        self._joint_topic = joint_topic
        with self._open() as reader:
            by_topic: dict[str, list[Any]] = {}
            for conn in reader.connections:
                by_topic.setdefault(conn.topic, []).append(conn)
            self._counts: dict[str, int] = {}
            present = []
            for name, topic in self._topics.items():
                conns = by_topic.get(topic, [])
                if not conns:
                    continue
                for conn in conns:
                    if conn.msgtype not in _IMAGE:
                        raise FrameError(
                            f"{self.path}: topic {topic} (camera '{name}') holds {conn.msgtype}, "
                            "expected sensor_msgs/msg/Image"
                        )
                self._counts[name] = sum(int(c.msgcount) for c in conns)
                present.append(name)
            if not present:
                wanted = ", ".join(f"{t} ({n})" for n, t in self._topics.items())
                raise FrameError(
                    f"{self.path}: holds none of the cameras' depth topics {wanted}; topics in the "
                    f"bag: {sorted(by_topic)} (set each camera's topic in the cell file)"
                )
            self.cameras = tuple(present)
            jconns = by_topic.get(joint_topic, []) if joint_order is not None else []
            for conn in jconns:
                if conn.msgtype not in _JOINTS:
                    raise FrameError(
                        f"{self.path}: topic {joint_topic} holds {conn.msgtype}, expected "
                        "sensor_msgs/msg/JointState (robot.joint_state_topic)"
                    )
            self._has_joints = bool(jconns)

    @contextlib.contextmanager
    def _open(self) -> Iterator[Any]:
        """The bag's open ``AnyReader`` (closed on exit); a bag that cannot be opened is a
        :class:`FrameError` naming it."""
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore

        if not self.path.exists():
            raise FrameError(f"{self.path}: no such bag (a .mcap, .db3 or .bag file, or a ROS 2 bag directory)")
        try:
            reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError) as exc:
            raise FrameError(f"{self.path}: not a readable ROS bag ({exc})") from None
        try:
            yield reader
        finally:
            reader.close()

    def frame_count(self, camera: str) -> int:
        return self._counts.get(camera, 0)

    @property
    def has_joints(self) -> bool:
        return self._has_joints

    def events(self, cameras: tuple[str, ...] | None = None, joints: bool = True) -> Iterator[Event]:
        names = self.cameras if cameras is None else tuple(c for c in cameras if c in self.cameras)
        wanted_images = {self._topics[n]: n for n in names}
        wanted_info = {info_topic(self._topics[n]): n for n in names}
        read_joints = joints and self._has_joints and self._joint_order is not None
        with self._open() as reader:
            conns = [
                c
                for c in reader.connections
                if c.topic in wanted_images
                or (c.topic in wanted_info and c.msgtype in _INFO)
                or (read_joints and c.topic == self._joint_topic)
            ]
            seq = dict.fromkeys(names, 0)
            info_checked: set[str] = set()
            for conn, t_ns, raw in reader.messages(connections=conns):
                where = f"{self.path}: topic {conn.topic}"
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as exc:  # noqa: BLE001 - rosbags raises many types; wrap them
                    raise FrameError(f"{where}: message at {t_ns} ns cannot be decoded ({exc})") from None
                if conn.topic in wanted_images:
                    name = wanted_images[conn.topic]
                    depth = decode_depth_image(msg, self._cameras[name], where)
                    try:
                        yield _frame(name, depth, _stamp(msg, t_ns), seq[name])
                    except FrameError as exc:
                        raise FrameError(f"{where}: {exc}") from None
                    seq[name] += 1
                elif conn.topic in wanted_info:
                    name = wanted_info[conn.topic]
                    if name not in info_checked:
                        check_camera_info(msg, self._cameras[name], where)
                        info_checked.add(name)
                else:
                    assert self._joint_order is not None
                    q = self._joint_order.reorder(list(msg.name), np.asarray(msg.position), where)
                    yield JointSample(_stamp(msg, t_ns), q)


def _frame(name: str, depth: np.ndarray, stamp: float, seq: int) -> Event:
    from ..frames import DepthFrame

    return DepthFrame(camera=name, depth=depth, stamp=stamp, seq=seq)
