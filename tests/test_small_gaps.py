"""The small_gaps rule frees only reading-less clusters walled in by the static scene and
narrower than the detection capability (synthetic images, exact expectations)."""

from __future__ import annotations

import numpy as np
import pytest

from polyhull.engine.pixels import small_gaps

H, W = 60, 80
F = 600.0  # focal length [px]
NEAR = 0.1
SIZE = 0.07  # detection capability [m]


def _scene(depth: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A static wall at ``depth``: every pixel free to its static free depth."""
    fs = np.full((H, W), depth - 0.1, dtype=np.float32)
    return fs.copy(), fs.copy(), np.zeros((H, W), dtype=bool), fs


def _drop(free, invalid, v0, v1, u0, u1):  # noqa: ANN001, ANN202
    free[v0:v1, u0:u1] = NEAR
    invalid[v0:v1, u0:u1] = True


def _gaps(free, end, invalid, fs, size=SIZE):  # noqa: ANN001, ANN202
    return small_gaps(free, end, invalid, fs, NEAR, F, F, size)


def test_a_dropout_patch_in_the_static_scene_is_a_small_gap() -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 24, 30, 34)  # 4 x 4 px: (4 + 2) * 3.9 / 600 = 0.039 m
    gap = _gaps(free, end, invalid, fs)
    assert gap.sum() == 16 and gap[20:24, 30:34].all()


def test_a_patch_wider_than_the_detection_capability_stays() -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 24, 30, 41)  # 11 px: (11 + 2) * 3.9 / 600 = 0.085 m > 0.07
    assert not _gaps(free, end, invalid, fs).any()
    # the same patch is small for a coarser declared capability
    assert _gaps(free, end, invalid, fs, size=0.1).sum() == 44


def test_valid_readings_are_never_filled() -> None:
    """A hand seen through a gap: valid readings in front of the wall."""
    free, end, invalid, fs = _scene()
    free[20:22, 30:32] = 1.5
    assert not _gaps(free, end, invalid, fs).any()


@pytest.mark.parametrize("where", ["person", "robot", "blind", "border"])
def test_a_patch_next_to_anything_but_the_static_scene_stays(where: str) -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 23, 30, 33)
    if where == "person":
        free[23, 31] = 1.5  # a valid changed reading touching the patch
    elif where == "robot":
        end[19, 29] = free[19, 29] = 2.0  # explained by the robot: free to its shadow start only
    elif where == "blind":
        fs[20, 33] = free[20, 33] = end[20, 33] = 0.5 * NEAR  # sees nothing even in the empty cell
    else:
        _drop(free, invalid, 0, 3, 30, 33)
        free[20:23, 30:33] = fs[20:23, 30:33]
        invalid[20:23, 30:33] = False
    assert not _gaps(free, end, invalid, fs).any()
