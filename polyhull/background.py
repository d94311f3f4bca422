"""The taught background: per camera and per pixel, what the empty cell measured.

``polyhull teach`` learns it from a recording of the empty cell (:mod:`polyhull.teaching`)
and writes it to one ``.npz`` beside the cell file, which names it with the top-level key
``background = "<file>.npz"``. Per camera ``c`` the file holds six (H, W) float32 arrays:

- ``c.observed``: how many taught frames saw the pixel's background (the padded robot, at
  the recorded joint state, did not cover it);
- ``c.valid_share``: share in [0, 1] of those frames with a valid reading (finite,
  within the camera's range);
- ``c.median``: the median of the valid readings [m] (NaN where there were none);
- ``c.sigma``: the noise, ``1.4826 * MAD`` of the valid readings [m];
- ``c.min``, ``c.max``: the least and greatest valid reading [m] (the taught band);

and the scalars ``c.frames`` (frames taught) and ``c.min_valid_share``. A pixel observed in
at least ``MIN_OBSERVED`` frames is *taught*; a taught pixel with a smaller valid share is
**static-invalid** (the sensor loses it in the empty cell: a dark or shiny surface, an
edge, multipath), so it frees nothing and is never a change. A pixel that is not taught
(the robot hid it throughout) keeps the CAD reference.

The static model (:mod:`polyhull.engine.static_model`) replaces a camera's CAD reference
and band by the taught ones (:meth:`TaughtCamera.band`) wherever the pixel is taught valid.
"""

from __future__ import annotations

import hashlib
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import CellError
from .frames import open_npz
from .typed import ArrayF32, ArrayF64

if TYPE_CHECKING:
    from .camera import Camera

__all__ = ["TaughtCamera", "TaughtBackground", "load_background", "save_background", "STAT_NAMES"]

#: The per-pixel arrays of every camera, in file order.
STAT_NAMES = ("observed", "valid_share", "median", "sigma", "min", "max")

MIN_VALID_SHARE = 0.8
"""Default: a pixel valid in fewer of the taught frames is static-invalid."""

MIN_OBSERVED = 5
"""A pixel's background seen in fewer taught frames than this is not taught (CAD reference)."""


@dataclass(frozen=True, eq=False)
class TaughtCamera:
    """One camera's taught statistics (read-only (H, W) float32 arrays).

    Attributes:
        observed: Frames in which the pixel's background was in view (not behind the robot).
        valid_share: Share of those frames with a valid reading.
        median: Median valid reading [m] (NaN where none).
        sigma: MAD-based noise [m] (NaN where none).
        min: Least valid reading [m] (NaN where none).
        max: Greatest valid reading [m] (NaN where none).
        frames: Number of frames taught.
        min_valid_share: Below this valid share a pixel is static-invalid.
    """

    observed: ArrayF32
    valid_share: ArrayF32
    median: ArrayF32
    sigma: ArrayF32
    min: ArrayF32
    max: ArrayF32
    frames: int
    min_valid_share: float = MIN_VALID_SHARE

    def __post_init__(self) -> None:
        shape = np.asarray(self.observed).shape
        for name in STAT_NAMES:
            a = np.asarray(getattr(self, name), dtype=np.float32)
            if a.ndim != 2 or a.shape != shape:
                raise CellError(f"taught {name}: expected an (H, W) array of shape {shape}, got {a.shape}")
            a = a.copy()
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return self.observed.shape  # type: ignore[return-value]

    @property
    def taught(self) -> np.ndarray:
        """(H, W) pixels whose background was observed in at least ``MIN_OBSERVED`` frames."""
        return self.observed >= MIN_OBSERVED

    @property
    def taught_valid(self) -> np.ndarray:
        """(H, W) taught pixels with enough valid readings and a finite taught depth."""
        with np.errstate(invalid="ignore"):
            return (
                self.taught
                & (self.valid_share >= self.min_valid_share)
                & np.isfinite(self.median)
                & (self.median > 0)
            )

    @property
    def static_invalid(self) -> np.ndarray:
        """(H, W) taught pixels without enough valid readings: they free nothing."""
        return self.taught & ~self.taught_valid

    def band(
        self, camera: Camera, reference: ArrayF64, lower: ArrayF64, upper: ArrayF64, width: float
    ) -> tuple[ArrayF64, ArrayF64, ArrayF64, np.ndarray]:
        """The reference and band of ``camera`` with the taught ones where taught valid.

        Where a pixel is taught valid its reference is the taught median ``m`` and its band
        ``[min(lo, m - width tau), max(hi, m + width tau)]``: the taught min/max band, at
        least ``width`` tolerances wide, with ``tau = max(tolerance_sigmas * sigma, tau(m))``
        (the taught noise or the declared one, whichever is larger).

        Args:
            camera: The camera (its noise model and tolerance).
            reference: (H, W) CAD reference depth B [m].
            lower: (H, W) CAD band lower bound [m].
            upper: (H, W) CAD band upper bound [m].
            width: Band half-width in tolerances.

        Returns:
            (reference, lower, upper, static_invalid): float64 (H, W) arrays and the (H, W)
            mask of static-invalid pixels (they free nothing). Pixels that are not taught
            keep the CAD values.
        """
        if self.shape != camera.shape:
            raise CellError(
                f"taught background of camera '{camera.name}': shape {self.shape} != image shape {camera.shape}"
            )
        ok = self.taught_valid
        m = np.where(ok, self.median, 1.0).astype(np.float64)
        tau = np.maximum(camera.tolerance_sigmas * np.nan_to_num(self.sigma.astype(np.float64)), camera.tau(m))
        lo = np.minimum(np.where(ok, self.min, m), m - width * tau)
        hi = np.maximum(np.where(ok, self.max, m), m + width * tau)
        B = np.where(ok, m, reference)
        T = np.where(ok, lo, lower)
        U = np.where(ok, hi, upper)
        return B, T, U, self.static_invalid


@dataclass(frozen=True, eq=False)
class TaughtBackground:
    """Every taught camera of a cell, and the file it came from.

    Attributes:
        cameras: Camera name -> its taught statistics.
        path: The ``.npz`` file (None when built in memory).
    """

    cameras: dict[str, TaughtCamera]
    path: Path | None = None

    def get(self, name: str) -> TaughtCamera | None:
        """The taught statistics of camera ``name`` (None when not taught)."""
        return self.cameras.get(name)

    def digest(self) -> bytes:
        """A digest of every array and threshold (the static model's cache key includes it)."""
        h = hashlib.blake2b(digest_size=16)
        for name in sorted(self.cameras):
            t = self.cameras[name]
            h.update(repr((name, t.frames, t.min_valid_share, t.shape)).encode())
            for stat in STAT_NAMES:
                h.update(np.ascontiguousarray(getattr(t, stat)).tobytes())
        return h.digest()


def save_background(path: str | Path, background: TaughtBackground) -> Path:
    """Write ``background`` to ``path`` (``.npz``)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    for name, t in background.cameras.items():
        for stat in STAT_NAMES:
            arrays[f"{name}.{stat}"] = np.asarray(getattr(t, stat), dtype=np.float32)
        arrays[f"{name}.frames"] = np.asarray(t.frames, dtype=np.int64)
        arrays[f"{name}.min_valid_share"] = np.asarray(t.min_valid_share, dtype=np.float64)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]
    return path


def load_background(path: str | Path, cameras: tuple[Camera, ...]) -> TaughtBackground:
    """Read a taught background and check it against the cell's cameras.

    Every camera in the file must be a camera of the cell with the same image shape; a
    camera of the cell missing from the file is not taught (it keeps its CAD reference).

    Raises:
        CellError: ``"<file>: ..."`` naming the camera and field at fault.
    """
    path = Path(path)
    shapes = {c.name: c.shape for c in cameras}
    data = open_npz(path, CellError, "taught background")
    taught: dict[str, TaughtCamera] = {}
    with data:
        keys = set(data.keys())
        names = sorted({k.rsplit(".", 1)[0] for k in keys if "." in k})
        if not names:
            raise CellError(f"{path}: holds no camera statistics (<camera>.median, ...)")
        for name in names:
            if name not in shapes:
                raise CellError(
                    f"{path}: camera {name!r} is not in the cell (cameras: {sorted(shapes)})"
                )
            fields: dict[str, np.ndarray] = {}
            for stat in (*STAT_NAMES, "frames", "min_valid_share"):
                key = f"{name}.{stat}"
                if key not in keys:
                    raise CellError(f"{path}: missing field {key!r}")
                try:
                    fields[stat] = np.asarray(data[key])
                except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                    raise CellError(f"{path}: field {key!r} cannot be read ({exc})") from None
            for stat in STAT_NAMES:
                a = fields[stat]
                if a.shape != shapes[name] or a.dtype.kind != "f":
                    raise CellError(
                        f"{path}: field '{name}.{stat}': expected a float (H, W) = "
                        f"{shapes[name]} array, got {a.dtype} {a.shape}"
                    )
            share = fields["valid_share"]
            if np.any(~np.isfinite(share)) or np.any((share < 0) | (share > 1)):
                raise CellError(f"{path}: field '{name}.valid_share': expected shares in [0, 1]")
            with np.errstate(invalid="ignore"):
                bad_depth = np.isfinite(fields["median"]) & (fields["median"] <= 0)
            if np.any(bad_depth):
                raise CellError(f"{path}: field '{name}.median': expected depths > 0 m or NaN")
            mvs = float(fields["min_valid_share"].reshape(-1)[0]) if fields["min_valid_share"].size else np.nan
            if not 0.0 < mvs <= 1.0:
                raise CellError(f"{path}: field '{name}.min_valid_share': expected a share in (0, 1], got {mvs}")
            if np.any(~np.isfinite(fields["observed"])) or np.any(fields["observed"] < 0):
                raise CellError(f"{path}: field '{name}.observed': expected frame counts >= 0")
            taught[name] = TaughtCamera(
                observed=fields["observed"],
                valid_share=share,
                median=fields["median"],
                sigma=fields["sigma"],
                min=fields["min"],
                max=fields["max"],
                frames=int(fields["frames"].reshape(-1)[0]),
                min_valid_share=mvs,
            )
    return TaughtBackground(cameras=taught, path=path.resolve())
