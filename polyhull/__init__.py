"""polyhull: polyhedral safety surveillance of human/robot work cells.

Every cycle, from the depth frames of a camera network, polyhull computes where an unknown
object (a person) could be as a watertight mesh, subtracts the robot occlusion and static
solids, measures the distance to the robot and derives a safe robot speed (ISO/TS 15066).
"""

from .camera import Camera as Camera
from .camera import Intrinsics as Intrinsics
from .cell import Cell as Cell
from .cell import Obstacle as Obstacle
from .cell import PlausibilityParams as PlausibilityParams
from .cell import ReconstructionParams as ReconstructionParams
from .cell import RobotSpec as RobotSpec
from .cell import SafetyParams as SafetyParams
from .cell import Zone as Zone
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

__version__ = "0.1.0"

__all__ = [
    "Camera",
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
