"""Teaching the background from a recording of the empty cell (``polyhull teach``).

Per camera and per pixel, over the first ``seconds`` of the recording (streamed):

- the frames in which the pixel's background was in view: pixels the padded robot covers
  at the recorded joint state (:func:`polyhull.engine.robot_raster.rasterize_robot`) are
  left out of that frame, so the robot is never taught as background;
- the share of valid readings (finite, within the camera's range), and the least and
  greatest valid reading (the band), over every frame of the window;
- the median and the noise ``sigma = 1.4826 * MAD`` of the valid readings, over at most
  ``max_samples`` to ``2 * max_samples`` frames evenly spread over the window (the stream
  is decimated by two whenever the buffer fills, so memory stays bounded).

Checks of the result (:class:`CameraTeaching`):

- **motion**: the share of pixels whose valid readings spread (max - min) over more than
  the static band (``2 * CONSISTENT_BAND`` declared tolerances at the median depth) fails
  the teaching above ``max_moving_share``; pixels at depth edges of the taught median
  (where time-of-flight sensors give mixed pixels) are not counted;
- **disagreement with the CAD model**: the share of taught pixels whose median lies
  outside the CAD reference's static band, with a heat map (:func:`heat_map`).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .background import MIN_OBSERVED, MIN_VALID_SHARE, TaughtBackground, TaughtCamera
from .camera import Camera
from .cell import Cell
from .errors import FrameError, PolyhullError
from .frames import DepthFrame
from .recordings import JointSample, Recording
from .typed import ArrayF32

__all__ = [
    "TeachingError",
    "PixelStatistics",
    "CameraTeaching",
    "Teaching",
    "teach",
    "moving_pixels",
    "cad_disagreement",
    "heat_map",
]

MAD_TO_SIGMA = 1.4826
"""sigma of a normal distribution per median absolute deviation."""


class TeachingError(PolyhullError):
    """The recording cannot be taught (something moves, no frames, no joint state)."""


class PixelStatistics:
    """Streamed per-pixel statistics of one camera's frames.

    Args:
        camera: The camera (shape and valid range).
        max_samples: The median and MAD use between ``max_samples`` and ``2 * max_samples``
            frames, evenly spread over what was added.
    """

    def __init__(self, camera: Camera, max_samples: int = 50) -> None:
        if max_samples < 1:
            raise PolyhullError(f"max_samples must be >= 1, got {max_samples}")
        H, W = camera.shape
        self.camera = camera
        self.max_samples = int(max_samples)
        self.frames = 0
        self.observed = np.zeros((H, W), dtype=np.int32)
        self.valid = np.zeros((H, W), dtype=np.int32)
        self.low = np.full((H, W), np.inf, dtype=np.float32)
        self.high = np.full((H, W), -np.inf, dtype=np.float32)
        self._samples: list[ArrayF32] = []
        self._stride = 1

    def add(self, depth: ArrayF32, covered: np.ndarray | None = None) -> None:
        """Add one frame's (H, W) depth [m]; ``covered`` pixels (the robot) are left out."""
        cam = self.camera
        d = np.asarray(depth, dtype=np.float32)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d >= cam.near) & (d <= cam.far)
        seen = np.ones(d.shape, dtype=bool) if covered is None else ~covered
        valid &= seen
        self.observed += seen
        self.valid += valid
        np.minimum(self.low, np.where(valid, d, np.inf), out=self.low)
        np.maximum(self.high, np.where(valid, d, -np.inf), out=self.high)
        if self.frames % self._stride == 0:
            self._samples.append(np.where(valid, d, np.float32(np.nan)).astype(np.float32))
            if len(self._samples) >= 2 * self.max_samples:
                self._samples = self._samples[::2]
                self._stride *= 2
        self.frames += 1

    def result(self, min_valid_share: float = MIN_VALID_SHARE) -> TaughtCamera:
        """The taught statistics of what was added."""
        if self.frames == 0:
            raise TeachingError(f"camera '{self.camera.name}': no frames to teach from")
        stack = np.stack(self._samples)
        with np.errstate(invalid="ignore", divide="ignore"), _quiet():
            median = np.nanmedian(stack, axis=0)
            mad = np.nanmedian(np.abs(stack - median[None]), axis=0)
            share = np.where(self.observed > 0, self.valid / np.maximum(self.observed, 1), 0.0)
        has = self.valid > 0
        return TaughtCamera(
            observed=self.observed.astype(np.float32),
            valid_share=share.astype(np.float32),
            median=np.where(has, median, np.nan).astype(np.float32),
            sigma=np.where(has, MAD_TO_SIGMA * mad, np.nan).astype(np.float32),
            min=np.where(has, self.low, np.nan).astype(np.float32),
            max=np.where(has, self.high, np.nan).astype(np.float32),
            frames=self.frames,
            min_valid_share=float(min_valid_share),
        )


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence numpy's "All-NaN slice" warnings (pixels never valid are NaN on purpose)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _edges(camera: Camera, depth: np.ndarray, width: float) -> np.ndarray:
    """(H, W) pixels whose 3 x 3 neighbourhood spans a depth jump wider than the band."""
    d = np.where(np.isfinite(depth), depth, camera.far)
    jump = ndimage.maximum_filter(d, 3, mode="nearest") - ndimage.minimum_filter(d, 3, mode="nearest")
    return jump > 2 * width * camera.tau(np.minimum(d, camera.far))


def moving_pixels(camera: Camera, taught: TaughtCamera) -> tuple[np.ndarray, np.ndarray]:
    """(moving, considered): (H, W) pixels whose valid readings spread beyond the static band
    (``2 * CONSISTENT_BAND * tau(median)``), among the taught pixels with a valid reading
    that are not at a depth edge of the taught median."""
    from .engine.static_model import CONSISTENT_BAND

    with np.errstate(invalid="ignore"):
        has = taught.taught & np.isfinite(taught.median)
        m = np.where(has, taught.median, 1.0).astype(np.float64)
        spread = np.where(has, taught.max.astype(np.float64) - taught.min.astype(np.float64), 0.0)
        considered = has & ~_edges(camera, np.where(has, m, np.nan), CONSISTENT_BAND)
        moving = considered & (spread > 2 * CONSISTENT_BAND * camera.tau(m))
    return moving, considered


def cad_disagreement(camera: Camera, taught: TaughtCamera, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ratio, compared): ``|median - B|`` in units of the CAD band's half-width
    (``CONSISTENT_BAND * tau(B)``) where both are known (ratio > 1: disagreement), and
    the (H, W) mask of those pixels (taught valid, CAD reference within range)."""
    from .engine.static_model import CONSISTENT_BAND

    B = np.asarray(reference, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        compared = taught.taught_valid & np.isfinite(B) & (B <= camera.far)
        Bc = np.where(compared, B, 1.0)
        ratio = np.where(
            compared, np.abs(taught.median.astype(np.float64) - Bc) / (CONSISTENT_BAND * camera.tau(Bc)), 0.0
        )
    return ratio, compared


def heat_map(ratio: np.ndarray, compared: np.ndarray, static_invalid: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of :func:`cad_disagreement`: agreement in green (darker the
    closer), disagreement from yellow (just outside the band) to red (3 bands or more),
    static-invalid pixels blue, pixels not compared grey."""
    H, W = ratio.shape
    img = np.full((H, W, 3), 96, dtype=np.uint8)
    r = np.clip(ratio, 0.0, 3.0)
    agree = compared & (r <= 1.0)
    g = (60 + 120 * r).astype(np.uint8)
    img[agree] = np.stack([np.zeros_like(g), g, np.zeros_like(g)], axis=-1)[agree]
    dis = compared & (r > 1.0)
    t = (r - 1.0) / 2.0  # 0 at the band's edge, 1 at three bands
    dis_rgb = np.stack([np.full_like(t, 255.0), 255.0 * (1.0 - t), np.zeros_like(t)], axis=-1).astype(np.uint8)
    img[dis] = dis_rgb[dis]
    img[static_invalid] = (40, 80, 255)
    return img


@dataclass(frozen=True, eq=False)
class CameraTeaching:
    """What teaching found for one camera.

    Attributes:
        camera: Camera name.
        taught: The taught statistics.
        taught_share: Share of the pixels taught (background in view in enough frames).
        static_invalid_share: Share of the pixels that are static-invalid.
        moving_share: Share of the considered pixels whose depth varied beyond the noise.
        disagree_share: Share of the compared pixels outside the CAD reference's band
            (None when no pixel could be compared).
        noise_at_1m: Median taught noise scaled to 1 m (``sigma / z^2``) [m], to compare
            with the camera's declared ``noise``.
        ratio: (H, W) disagreement ratio (see :func:`cad_disagreement`).
        compared: (H, W) pixels compared with the CAD reference.
    """

    camera: str
    taught: TaughtCamera
    taught_share: float
    static_invalid_share: float
    moving_share: float
    disagree_share: float | None
    noise_at_1m: float
    ratio: np.ndarray
    compared: np.ndarray

    def heat_map(self) -> np.ndarray:
        """The disagreement heat map (:func:`heat_map`)."""
        return heat_map(self.ratio, self.compared, self.taught.static_invalid)

    def summary(self) -> dict[str, object]:
        """The JSON-ready numbers of this camera."""
        return {
            "frames": self.taught.frames,
            "taught_share": self.taught_share,
            "static_invalid_share": self.static_invalid_share,
            "moving_share": self.moving_share,
            "cad_disagree_share": self.disagree_share,
            "noise_at_1m": self.noise_at_1m if math.isfinite(self.noise_at_1m) else None,
        }


@dataclass(frozen=True, eq=False)
class Teaching:
    """The result of :func:`teach`: the background and the per-camera findings."""

    background: TaughtBackground
    cameras: tuple[CameraTeaching, ...]
    start: float
    seconds: float


def _robot_masker(cell: Cell) -> Callable[[Camera, np.ndarray], np.ndarray] | None:
    """A function (camera, q) -> (H, W) pixels covered by the padded robot, or None."""
    if cell.robot is None:
        return None
    from .engine.robot_raster import PaddedPieces, rasterize_robot
    from .robot import Robot

    robot = Robot.from_spec(cell.robot)
    padded = PaddedPieces.build(robot.link_convex_pieces(), cell.robot.padding)
    cache: dict[tuple[str, bytes], np.ndarray] = {}

    def covered(camera: Camera, q: np.ndarray) -> np.ndarray:
        key = (camera.name, np.asarray(q, dtype=np.float64).tobytes())
        if key not in cache:
            if len(cache) > 64:
                cache.clear()
            world = padded.world(robot.link_transforms(q))
            cache[key] = rasterize_robot(camera, world, padded).covered
        return cache[key]

    return covered


def _window(
    recording: Recording, name: str, start: float | None, seconds: float, joints: bool
) -> Iterator[tuple[DepthFrame, JointSample | None]]:
    """The frames of camera ``name`` from ``start`` (its first frame when None) for
    ``seconds``, each with the joint sample nearest to it in time (the last one before it
    or the first one after it)."""
    last: JointSample | None = None
    waiting: list[DepthFrame] = []  # frames in the window, waiting for the next joint sample
    t0 = start
    events = recording.events((name,), joints=joints)

    def nearest(frame: DepthFrame, after: JointSample | None) -> JointSample | None:
        if last is None or (after is not None and after.stamp - frame.stamp < frame.stamp - last.stamp):
            return after
        return last

    try:
        for e in events:
            if isinstance(e, JointSample):
                for f in waiting:
                    yield f, nearest(f, e)
                waiting.clear()
                last = e
                continue
            if t0 is None:
                t0 = e.stamp
            if e.stamp < t0:
                continue
            if e.stamp > t0 + seconds:
                break
            if joints:
                waiting.append(e)
            else:
                yield e, None
        for f in waiting:
            yield f, nearest(f, None)
    finally:
        close = getattr(events, "close", None)
        if close is not None:
            close()


def teach(
    cell: Cell,
    recording: Recording,
    seconds: float = 10.0,
    *,
    references: dict[str, np.ndarray] | None = None,
    min_valid_share: float = MIN_VALID_SHARE,
    max_moving_share: float = 0.01,
    max_samples: int = 50,
    progress: bool = False,
) -> Teaching:
    """Teach the background of ``cell``'s depth cameras from ``recording`` (module docstring).

    Args:
        cell: The cell.
        recording: A recording of the empty cell (the robot may move: it is left out).
        seconds: Length of the teaching window [s], from the recording's first frame.
        references: The CAD references (rendered from the cell when None).
        min_valid_share: Below this valid share a pixel is static-invalid.
        max_moving_share: Fail when a camera's share of moving pixels exceeds this.
        max_samples: Frames (at least; at most twice) behind the median and MAD.
        progress: Show a tqdm progress bar per camera on stderr.

    Raises:
        TeachingError: Something moves in a camera's view (naming the camera and the
            share), a camera has no frames, or the robot's joint state is missing.
    """
    from tqdm import tqdm

    if not (math.isfinite(seconds) and seconds > 0):
        raise TeachingError(f"--seconds must be a time > 0 s, got {seconds!r}")
    if not 0.0 < min_valid_share <= 1.0:
        raise TeachingError(f"--min-valid-share must be a share in (0, 1], got {min_valid_share!r}")
    if not 0.0 <= max_moving_share <= 1.0:
        raise TeachingError(f"--max-moving-share must be a share in [0, 1], got {max_moving_share!r}")
    masker = _robot_masker(cell)
    if masker is not None and not recording.has_joints:
        raise TeachingError(
            f"{recording.path}: no joint state, needed to leave the robot out of the background "
            f"(record robot.joint_state_topic {cell.robot.joint_state_topic if cell.robot else ''} "
            "or give a joint-state CSV)"
        )
    if references is None:
        from .raycast import render_reference

        references = render_reference(cell)
    depth_cams = [c for c in cell.cameras if c.kind == "depth" and c.name in recording.cameras]
    if not depth_cams:
        raise TeachingError(f"{recording.path}: holds no frames of the cell's depth cameras")
    start: float | None = None
    found: list[CameraTeaching] = []
    for cam in depth_cams:
        stats = PixelStatistics(cam, max_samples)
        bar = tqdm(desc=f"teach {cam.name}", unit="frame", disable=None if progress else True, leave=False)
        try:
            for frame, sample in _window(recording, cam.name, start, seconds, masker is not None):
                if start is None:
                    start = frame.stamp
                covered = None
                if masker is not None:
                    if sample is None:
                        continue  # no joint state yet: the robot's place is unknown
                    covered = masker(cam, sample.q)
                stats.add(frame.depth, covered)
                bar.update()
        except FrameError:
            raise
        finally:
            bar.close()
        if stats.frames < MIN_OBSERVED:
            raise TeachingError(
                f"camera '{cam.name}': {stats.frames} frames in the teaching window"
                f"{' with a joint state' if masker is not None else ''}, at least {MIN_OBSERVED} needed "
                "(a longer --seconds?)"
            )
        taught = stats.result(min_valid_share)
        found.append(_findings(cam, taught, references[cam.name]))
    for f in found:
        if f.moving_share > max_moving_share:
            raise TeachingError(
                f"camera '{f.camera}': {100 * f.moving_share:.1f} % of its pixels varied beyond the "
                f"noise (limit {100 * max_moving_share:.1f} %): something moves in the teaching "
                "recording, or the camera's noise is larger than declared"
            )
    background = TaughtBackground(cameras={f.camera: f.taught for f in found})
    assert start is not None
    return Teaching(background=background, cameras=tuple(found), start=start, seconds=float(seconds))


def _findings(cam: Camera, taught: TaughtCamera, reference: np.ndarray) -> CameraTeaching:
    n = taught.observed.size
    moving, considered = moving_pixels(cam, taught)
    ratio, compared = cad_disagreement(cam, taught, reference)
    ok = taught.taught_valid
    with np.errstate(invalid="ignore", divide="ignore"), _quiet():
        noise = float(np.nanmedian(np.where(ok, taught.sigma / (taught.median.astype(np.float64) ** 2), np.nan)))
    return CameraTeaching(
        camera=cam.name,
        taught=taught,
        taught_share=float(taught.taught.sum()) / n,
        static_invalid_share=float(taught.static_invalid.sum()) / n,
        moving_share=float(moving.sum()) / max(int(considered.sum()), 1),
        disagree_share=float((ratio[compared] > 1.0).sum()) / int(compared.sum()) if compared.any() else None,
        noise_at_1m=noise,
        ratio=ratio,
        compared=compared,
    )
