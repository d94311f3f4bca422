"""Joint states of a recording: ``sensor_msgs/JointState`` messages and CSV files.

A joint-state CSV has a header row ``stamp,<joint>,<joint>,...`` naming every actuated
joint of the robot's URDF (in any order; extra columns are ignored), then one row per
sample: the stamp [s] and the positions [rad or m], rows in time order.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from ..errors import FrameError
from ..typed import ArrayF64
from .base import JointSample

__all__ = ["JointOrder", "read_joint_csv"]


class JointOrder:
    """Reorders named joint positions into the URDF order of the robot's actuated joints."""

    def __init__(self, joint_names: Sequence[str]) -> None:
        self.joint_names = tuple(joint_names)
        self._cache: tuple[tuple[str, ...], np.ndarray] | None = None

    def index(self, names: Sequence[str], where: str) -> np.ndarray:
        """Column of every URDF joint in ``names``; raise naming ``where`` when one is missing."""
        names = tuple(names)
        if self._cache is not None and self._cache[0] == names:
            return self._cache[1]
        position = {n: i for i, n in enumerate(names)}
        missing = [n for n in self.joint_names if n not in position]
        if missing:
            raise FrameError(
                f"{where}: joint state lacks joints {missing} of the robot "
                f"(expected names {list(self.joint_names)}, got {list(names)})"
            )
        idx = np.array([position[n] for n in self.joint_names], dtype=np.int64)
        self._cache = (names, idx)
        return idx

    def reorder(self, names: Sequence[str], positions: Sequence[float] | np.ndarray, where: str) -> ArrayF64:
        """(dof,) positions in URDF order from one named joint state."""
        values = np.asarray(positions, dtype=np.float64).reshape(-1)
        if len(values) != len(names):
            raise FrameError(f"{where}: joint state has {len(names)} names but {len(values)} positions")
        return values[self.index(names, where)]


def read_joint_csv(path: str | Path, order: JointOrder) -> Iterator[JointSample]:
    """Stream the samples of a joint-state CSV (see the module docstring).

    Raises:
        FrameError: naming the file, line and column of a missing joint, a value that is
            not a finite number or a stamp that goes back in time.
    """
    path = Path(path)
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise FrameError(f"{path}: cannot read the joint-state CSV ({exc})") from None
    with handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None or not header or header[0].strip() != "stamp":
            raise FrameError(f"{path}: line 1: expected a header 'stamp,<joint names>', got {header!r}")
        names = [h.strip() for h in header[1:]]
        idx = order.index(names, f"{path}: line 1")
        last = -math.inf
        for line, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != len(header):
                raise FrameError(f"{path}: line {line}: expected {len(header)} values, got {len(row)}")
            try:
                values = [float(x) for x in row]
            except ValueError:
                raise FrameError(f"{path}: line {line}: expected numbers, got {row!r}") from None
            if not all(math.isfinite(v) for v in values):
                raise FrameError(f"{path}: line {line}: expected finite numbers, got {row!r}")
            stamp = values[0]
            if stamp < last:
                raise FrameError(f"{path}: line {line}: stamp {stamp} goes back in time (previous {last})")
            last = stamp
            yield JointSample(stamp, np.asarray(values[1:], dtype=np.float64)[idx])
