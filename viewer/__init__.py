"""polyhull_viewer: look at cells, depth frames and verdicts in meshcat, live or as HTML.

Draw into your own meshcat visualizer from your controller code::

    import meshcat
    import polyhull_viewer as pv

    vis = meshcat.Visualizer()
    pv.draw_cell(vis, cell, q)              # zone, obstacles, robot, camera frustums
    verdict = monitor.step(frames, q, stamp=t)
    pv.draw_verdict(vis, verdict, robot=robot, static_region=monitor.static.region)
                                            # R (dynamic saturated, a dropout's rays pale,
                                            # static faint), M, C,
                                            # removed parts (hidden), distance and label;
                                            # every cycle: hull=False, occlusion=False
                                            # (C and M are manifold booleans: seconds)

or write a standalone HTML file that opens with no server::

    vis = pv.StaticVisualizer()
    pv.draw_scene(vis, cell, frames=frames, verdict=verdict, static_region=monitor.static.region)
    pv.write_html(vis, "cell.html")

The core package ``polyhull`` never imports this one. It needs the ``viewer`` extra
(``pip install 'polyhull[viewer]'``).
"""

from __future__ import annotations

import warnings as _warnings

from polyhull.errors import MissingExtraError

try:
    with _warnings.catch_warnings():
        # meshcat 0.3 imports the deprecated zmq.eventloop.ioloop; nothing to act on here.
        _warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat as _meshcat  # noqa: F401
    import umsgpack as _umsgpack  # noqa: F401
except ImportError as _exc:  # pragma: no cover - exercised by a subprocess test
    raise MissingExtraError("the viewer", "viewer") from _exc

from ._colors import STYLE as STYLE
from ._colors import Style as Style
from ._colors import depth_colors as depth_colors
from ._colors import hex_to_rgb as hex_to_rgb
from ._colors import rgb_to_hex as rgb_to_hex
from ._colors import speed_color as speed_color
from ._colors import speed_color_hex as speed_color_hex
from ._demo import DemoRecorder as DemoRecorder
from ._geometry import TextLabel as TextLabel
from ._geometry import feature_edges as feature_edges
from ._geometry import frame_points as frame_points
from ._html import StaticVisualizer as StaticVisualizer
from ._html import VisualizerLike as VisualizerLike
from ._html import write_html as write_html
from ._scene import DEFAULT_PREFIX as DEFAULT_PREFIX
from ._scene import RobotLike as RobotLike
from ._scene import VerdictLike as VerdictLike
from ._scene import distance_text as distance_text
from ._scene import draw_camera_regions as draw_camera_regions
from ._scene import draw_cell as draw_cell
from ._scene import draw_frames as draw_frames
from ._scene import draw_robot as draw_robot
from ._scene import draw_scene as draw_scene
from ._scene import draw_static_region as draw_static_region
from ._scene import draw_verdict as draw_verdict
from ._scene import robot_sphere as robot_sphere
from ._scene import set_view as set_view
from ._server import LiveViewer as LiveViewer

__all__ = [
    "DEFAULT_PREFIX",
    "STYLE",
    "DemoRecorder",
    "LiveViewer",
    "RobotLike",
    "StaticVisualizer",
    "Style",
    "TextLabel",
    "VerdictLike",
    "VisualizerLike",
    "depth_colors",
    "distance_text",
    "draw_camera_regions",
    "draw_cell",
    "draw_frames",
    "draw_robot",
    "draw_scene",
    "draw_static_region",
    "draw_verdict",
    "feature_edges",
    "frame_points",
    "hex_to_rgb",
    "rgb_to_hex",
    "robot_sphere",
    "set_view",
    "speed_color",
    "speed_color_hex",
    "write_html",
]
