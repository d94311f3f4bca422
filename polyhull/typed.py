"""Array aliases used across polyhull (shapes are given in docstrings or comments)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["ArrayF32", "ArrayF64", "ArrayBool", "ArrayI64", "Transform"]

ArrayF32 = npt.NDArray[np.float32]
ArrayF64 = npt.NDArray[np.float64]
ArrayBool = npt.NDArray[np.bool_]
ArrayI64 = npt.NDArray[np.int64]
Transform = npt.NDArray[np.float64]  # (4, 4) rigid transform, e.g. T_world_camera
