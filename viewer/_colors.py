"""Colours of the viewer: one fixed colour per kind of object, the speed cue and depth maps.

Colours are ``0xRRGGBB`` integers as meshcat and three.js take them, or float RGB in [0, 1]
for per-vertex colours. The robot is orange on purpose: no other object uses a hue near it,
so a screenshot can be searched for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from polyhull.typed import ArrayF32, ArrayF64

__all__ = [
    "Style",
    "STYLE",
    "CAMERA_PALETTE",
    "camera_color",
    "speed_color",
    "speed_color_hex",
    "rgb_to_hex",
    "hex_to_rgb",
    "depth_colors",
]


@dataclass(frozen=True)
class Style:
    """Colour and opacity of every drawn item (``0xRRGGBB``, opacity in (0, 1]).

    Attributes:
        zone: Lines of the work cell box Z.
        obstacle_solid: Static solids O(j) (a person cannot enter them), grey.
        obstacle_open: Static objects a person can enter (drawn see-through).
        obstacle_open_opacity: Opacity of those.
        enclosure_opacity: Opacity of solids outside the zone (walls, fences), drawn as
            faint glass with their edges so they never hide the cell from the view.
        robot: Robot links without a URDF colour; orange, a hue nothing else uses.
        closest_link_opacity: Opacity of the shell drawn around the closest link, in the
            colour of the speed scale.
        camera_body: The small box marking a camera.
        camera_label_size: Height of a camera label on screen, as a share of the view's
            height (one size for every label, whatever its distance).
        distance_label_size: Height of the distance label on screen, likewise.
        hull: The depth hull C (possibly occupied by some camera's verdict).
        hull_opacity: Opacity of C (hidden by default).
        robot_occlusion: The robot occlusion M, a blue tint (hidden by default).
        robot_occlusion_opacity: Opacity of M.
        region: The dynamic region (this cycle's part of R: people, new objects), saturated.
        region_opacity: Opacity of the dynamic region.
        region_unseen: The dynamic region's pieces that hold no reading (the far part of a
            dropout patch's rays, where a small object may hide), a paler red.
        region_unseen_opacity: Opacity of those pieces.
        static_region: The static region (blind space, static shadows), a faint tint.
        static_region_opacity: Opacity of the static region.
        static_margin: The static region is shown (by default) within this distance [m]
            of the sphere around the robot, and hidden beyond.
        removed: Components removed by a plausibility rule (hidden by default).
        removed_opacity: Opacity of removed components.
        camera_region_opacity: Opacity of each camera's region C(i) (hidden by default).
        person: The person of the demo.
        segment_radius: Radius of the closest-distance segment's tube [m].
        point_size: Side of a point of a frame's point cloud [m].
        background_top: Background colour at the top of the view.
        background_bottom: Background colour at the bottom of the view.
    """

    zone: int = 0x30343A
    obstacle_solid: int = 0x8A8F98
    obstacle_open: int = 0xB8C8DC
    obstacle_open_opacity: float = 0.45
    enclosure_opacity: float = 0.08
    robot: int = 0xFF8C00
    closest_link_opacity: float = 0.45
    camera_body: int = 0x202428
    camera_label_size: float = 0.09
    distance_label_size: float = 0.22
    hull: int = 0x3C78D8
    hull_opacity: float = 0.12
    robot_occlusion: int = 0x2F6FD0
    robot_occlusion_opacity: float = 0.3
    region: int = 0xE0102F
    region_opacity: float = 0.8
    region_unseen: int = 0xF09AA6
    region_unseen_opacity: float = 0.55
    static_region: int = 0xB06070
    static_region_opacity: float = 0.12
    static_margin: float = 1.0
    removed: int = 0x707070
    removed_opacity: float = 0.3
    camera_region_opacity: float = 0.15
    person: int = 0xE8C8A0
    segment_radius: float = 0.02
    point_size: float = 0.02
    background_top: int = 0xF4F6F8
    background_bottom: int = 0xB8C2CC


STYLE = Style()

# Categorical colours of cameras (frustum lines, camera regions); no orange, red or green,
# which mean robot, region and speed.
CAMERA_PALETTE: tuple[int, ...] = (
    0x17BECF,
    0x9467BD,
    0xE377C2,
    0xBCBD22,
    0x1F77B4,
    0x8C564B,
    0x7F7F7F,
    0x00CED1,
)


def camera_color(index: int) -> int:
    """Colour ``0xRRGGBB`` of the camera at position ``index`` of the cell's camera list."""
    return CAMERA_PALETTE[index % len(CAMERA_PALETTE)]


def rgb_to_hex(rgb: ArrayF64 | tuple[float, float, float]) -> int:
    """Float RGB (3,) in [0, 1] to ``0xRRGGBB`` (values are clipped to [0, 1])."""
    c = np.clip(np.asarray(rgb, dtype=np.float64).reshape(3), 0.0, 1.0)
    r, g, b = (int(round(float(x) * 255.0)) for x in c)
    return (r << 16) | (g << 8) | b


def hex_to_rgb(color: int) -> tuple[float, float, float]:
    """``0xRRGGBB`` to float RGB in [0, 1]."""
    return (((color >> 16) & 0xFF) / 255.0, ((color >> 8) & 0xFF) / 255.0, (color & 0xFF) / 255.0)


# The speed cue: red at speed_scale 0 (stop), yellow at 0.5, green at 1 (full speed).
# Red only falls and green only rises with the scale, so the cue is monotone.
_SPEED_KNOTS = np.array([0.0, 0.5, 1.0])
_SPEED_RGB = np.array(
    [
        [0.90, 0.00, 0.00],  # red
        [0.90, 0.80, 0.00],  # yellow
        [0.00, 0.80, 0.00],  # green
    ]
)


def speed_color(speed_scale: float) -> tuple[float, float, float]:
    """Colour cue of a speed scale: red at 0 (stop), yellow at 0.5, green at 1.

    Args:
        speed_scale: Speed scale in [0, 1]; values outside are clipped, and NaN counts as
            0 (a verdict that cannot be read is drawn as a stop).

    Returns:
        Float RGB in [0, 1].
    """
    s = float(speed_scale)
    s = 0.0 if np.isnan(s) else min(max(s, 0.0), 1.0)
    rgb = [float(np.interp(s, _SPEED_KNOTS, _SPEED_RGB[:, k])) for k in range(3)]
    return (rgb[0], rgb[1], rgb[2])


def speed_color_hex(speed_scale: float) -> int:
    """:func:`speed_color` as ``0xRRGGBB``."""
    return rgb_to_hex(speed_color(speed_scale))


# Viridis sampled at 9 points: dark purple (near) to yellow (far); perceptually ordered.
_VIRIDIS = np.array(
    [
        [0.267, 0.005, 0.329],
        [0.283, 0.141, 0.458],
        [0.254, 0.265, 0.530],
        [0.207, 0.372, 0.553],
        [0.164, 0.471, 0.558],
        [0.128, 0.567, 0.551],
        [0.135, 0.659, 0.518],
        [0.267, 0.749, 0.441],
        [0.478, 0.821, 0.318],
        [0.741, 0.873, 0.150],
        [0.993, 0.906, 0.144],
    ]
)


def depth_colors(depth: ArrayF64 | ArrayF32, near: float, far: float) -> ArrayF32:
    """Per-point colours (N, 3) float32 in [0, 1] for depths (N,) [m] on a viridis map.

    ``near`` maps to dark purple and ``far`` to yellow; depths outside are clipped. When
    ``far <= near`` every point gets the middle colour.
    """
    d = np.asarray(depth, dtype=np.float64).reshape(-1)
    if not far > near:
        t = np.full(d.shape, 0.5)
    else:
        t = np.clip((d - near) / (far - near), 0.0, 1.0)
    knots = np.linspace(0.0, 1.0, len(_VIRIDIS))
    rgb = np.column_stack([np.interp(t, knots, _VIRIDIS[:, k]) for k in range(3)])
    return rgb.astype(np.float32)
