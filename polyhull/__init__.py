"""polyhull: polyhedral safety surveillance of human/robot work cells.

Every cycle, from the depth frames of a camera network, polyhull computes where an unknown
object (a person) could be as a watertight mesh, subtracts the robot occlusion and static
solids, measures the distance to the robot and derives a safe robot speed (ISO/TS 15066).
"""

import atexit
import gc
import importlib
from typing import TYPE_CHECKING, Any

from .cachedir import use_numba_cache

use_numba_cache()  # before any module of the package imports numba

if TYPE_CHECKING:
    from .camera import Camera as Camera
    from .camera import Intrinsics as Intrinsics
    from .cell import Cell as Cell
    from .cell import Obstacle as Obstacle
    from .cell import PlausibilityParams as PlausibilityParams
    from .cell import ReconstructionParams as ReconstructionParams
    from .cell import RobotSpec as RobotSpec
    from .cell import SafetyParams as SafetyParams
    from .cell import Zone as Zone
    from .cellfile import default_cell_path as default_cell_path
    from .cellfile import load_cell as load_cell
    from .errors import CameraError as CameraError
    from .errors import CellError as CellError
    from .errors import FrameError as FrameError
    from .errors import GeometryError as GeometryError
    from .errors import MissingExtraError as MissingExtraError
    from .errors import PolyhullError as PolyhullError
    from .errors import RobotError as RobotError
    from .frames import DepthFrame as DepthFrame
    from .frames import load_frames as load_frames
    from .frames import save_frames as save_frames
    from .intrinsics_io import read_intrinsics_file as read_intrinsics_file
    from .monitor import Monitor as Monitor
    from .person import PersonTrack as PersonTrack
    from .person import make_person as make_person
    from .person import sample_points_inside as sample_points_inside
    from .plausibility import RemovedComponent as RemovedComponent
    from .raycast import render_depth as render_depth
    from .raycast import render_reference as render_reference
    from .robot import Robot as Robot
    from .simulator import SensorEffects as SensorEffects
    from .simulator import Simulator as Simulator
    from .speed import SpeedDecision as SpeedDecision
    from .speed import decide_speed as decide_speed
    from .verdict import Verdict as Verdict

# The public names are imported when first used (PEP 562), so ``polyhull --help`` and the
# error paths of the command line do not pay for trimesh, manifold3d and numba.
_LAZY = {
    "Camera": ".camera",
    "Intrinsics": ".camera",
    "Cell": ".cell",
    "Obstacle": ".cell",
    "PlausibilityParams": ".cell",
    "ReconstructionParams": ".cell",
    "RobotSpec": ".cell",
    "SafetyParams": ".cell",
    "Zone": ".cell",
    "default_cell_path": ".cellfile",
    "load_cell": ".cellfile",
    "CameraError": ".errors",
    "CellError": ".errors",
    "FrameError": ".errors",
    "GeometryError": ".errors",
    "MissingExtraError": ".errors",
    "PolyhullError": ".errors",
    "RobotError": ".errors",
    "DepthFrame": ".frames",
    "load_frames": ".frames",
    "save_frames": ".frames",
    "read_intrinsics_file": ".intrinsics_io",
    "Monitor": ".monitor",
    "Verdict": ".verdict",
    "PersonTrack": ".person",
    "make_person": ".person",
    "sample_points_inside": ".person",
    "RemovedComponent": ".plausibility",
    "render_depth": ".raycast",
    "render_reference": ".raycast",
    "Robot": ".robot",
    "SensorEffects": ".simulator",
    "Simulator": ".simulator",
    "SpeedDecision": ".speed",
    "decide_speed": ".speed",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'polyhull' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


__version__ = "0.1.0"

# Collect reference cycles holding manifold3d objects before interpreter shutdown; nanobind
# would otherwise report them as leaks on stderr when the process exits.
atexit.register(gc.collect)

__all__ = [
    "Camera",
    "Monitor",
    "PersonTrack",
    "RemovedComponent",
    "Robot",
    "SensorEffects",
    "Simulator",
    "SpeedDecision",
    "Verdict",
    "decide_speed",
    "default_cell_path",
    "load_cell",
    "make_person",
    "read_intrinsics_file",
    "render_depth",
    "render_reference",
    "sample_points_inside",
    "Cell",
    "CameraError",
    "CellError",
    "DepthFrame",
    "FrameError",
    "GeometryError",
    "Intrinsics",
    "MissingExtraError",
    "Obstacle",
    "PlausibilityParams",
    "PolyhullError",
    "ReconstructionParams",
    "RobotError",
    "RobotSpec",
    "SafetyParams",
    "Zone",
    "load_frames",
    "save_frames",
]
