"""Drawing a cell, its frames, regions and a verdict into a meshcat scene tree.

Every item has its own path, so the meshcat UI can toggle it ("Open Controls" > Scene)::

    <prefix>/cell/zone                      wireframe of the work cell Z
    <prefix>/cell/obstacles/<name>          static objects
    <prefix>/robot/<link>                   robot links at q (orange)
    <prefix>/cameras/<name>/frustum         frustum V(i), clipped to Z, as lines
    <prefix>/cameras/<name>/body            a small box at the camera centre
    <prefix>/cameras/<name>/label           the camera's name
    <prefix>/frames/<camera>                a depth frame as a point cloud (colour = depth)
    <prefix>/regions/camera/<name>          each camera's possibly occupied region C(i)
    <prefix>/regions/hull                   the depth hull C
    <prefix>/regions/robot_occlusion        the robot occlusion M
    <prefix>/regions/region                 the region R given to the controller
    <prefix>/regions/removed/<k>_<rule>     components removed by a plausibility rule
    <prefix>/distance/segment               closest pair region - robot (colour = speed)

All geometry is drawn in the world frame of the cell. The functions work on a
``meshcat.Visualizer`` (live) or a :class:`~polyhull_viewer.StaticVisualizer` (HTML).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import manifold3d as m3
import meshcat.geometry as mg
import numpy as np
import trimesh

from polyhull.cell import Cell
from polyhull.errors import FrameError, RobotError
from polyhull.frames import DepthFrame
from polyhull.typed import ArrayF64

from ._colors import STYLE, Style, camera_color, hex_to_rgb, speed_color_hex
from ._geometry import (
    TextLabel,
    frame_cloud,
    manifold_arrays,
    mesh_object,
    safe_name,
    segments_object,
    trimesh_arrays,
    wireframe_object,
)
from ._html import VisualizerLike

__all__ = [
    "DEFAULT_PREFIX",
    "RobotLike",
    "RemovedLike",
    "VerdictLike",
    "draw_cell",
    "draw_robot",
    "draw_frames",
    "draw_camera_regions",
    "draw_verdict",
    "draw_distance",
    "draw_manifold",
    "draw_scene",
    "set_view",
    "view_pose",
]

DEFAULT_PREFIX = "/polyhull"


class RobotLike(Protocol):
    """What the viewer needs of :class:`polyhull.robot.Robot`."""

    def visual_meshes(self, q: ArrayF64) -> Mapping[str, trimesh.Trimesh]: ...


class RemovedLike(Protocol):
    """A component removed by a plausibility rule (see :class:`polyhull.monitor.Verdict`)."""

    @property
    def rule(self) -> str: ...

    @property
    def mesh(self) -> m3.Manifold: ...


class DistanceLike(Protocol):
    """The distance fields of a verdict (also of a recorded demo cycle)."""

    @property
    def min_distance(self) -> float: ...

    @property
    def closest_points(self) -> Any: ...

    @property
    def closest_link(self) -> str | None: ...

    @property
    def speed_scale(self) -> float: ...


class VerdictLike(DistanceLike, Protocol):
    """The fields of :class:`polyhull.monitor.Verdict` the viewer draws."""

    @property
    def hull(self) -> m3.Manifold: ...

    @property
    def robot_occlusion(self) -> m3.Manifold: ...

    @property
    def region(self) -> m3.Manifold: ...

    @property
    def removed(self) -> Sequence[RemovedLike]: ...

    @property
    def q(self) -> Any: ...


def _translation(p: ArrayF64) -> ArrayF64:
    T = np.eye(4)
    T[:3, 3] = np.asarray(p, dtype=np.float64).reshape(3)
    return T


def draw_manifold(
    vis: VisualizerLike, manifold: m3.Manifold | None, color: int, opacity: float = 1.0
) -> bool:
    """Draw a manifold at ``vis`` as a flat-shaded mesh, or delete ``vis`` when it is empty.

    Returns:
        True when something was drawn.
    """
    if manifold is None or manifold.is_empty():
        vis.delete()
        return False
    vertices, faces = manifold_arrays(manifold)
    if len(faces) == 0:
        vis.delete()
        return False
    vis.set_object(mesh_object(vertices, faces, color, opacity))
    return True


def _set_visible(vis: VisualizerLike, visible: bool) -> None:
    vis.set_property("visible", bool(visible))


# -- the cell -------------------------------------------------------------------------------
def draw_robot(
    vis: VisualizerLike,
    robot: RobotLike,
    q: ArrayF64,
    *,
    style: Style = STYLE,
) -> list[str]:
    """Draw each link of ``robot`` at joint positions ``q`` [rad] under ``vis``/<link>.

    Returns:
        The names of the links drawn.
    """
    vis.delete()
    names = []
    for link, mesh in robot.visual_meshes(np.asarray(q, dtype=np.float64)).items():
        vertices, faces = trimesh_arrays(mesh)
        if len(faces) == 0:
            continue
        vis[safe_name(link)].set_object(mesh_object(vertices, faces, style.robot))
        names.append(link)
    return names


def _resolve_robot(cell: Cell, robot: RobotLike | None) -> RobotLike | None:
    if robot is not None or cell.robot is None:
        return robot
    from polyhull.robot import Robot  # the robot model is part of the core

    return Robot.from_spec(cell.robot)


def draw_cell(
    vis: VisualizerLike,
    cell: Cell,
    q: ArrayF64 | Sequence[float] | None = None,
    *,
    robot: RobotLike | None = None,
    prefix: str = DEFAULT_PREFIX,
    clip_frustums: bool = True,
    labels: bool = True,
    style: Style = STYLE,
) -> None:
    """Draw the zone, the static objects, the robot at ``q`` and the cameras.

    Args:
        vis: A meshcat visualizer (or :class:`StaticVisualizer`).
        cell: The work cell.
        q: Joint positions [rad] (URDF order); the cell's default ``robot.q`` when None.
        robot: The robot model; built from ``cell.robot`` with
            ``polyhull.robot.Robot.from_spec`` when None.
        prefix: Root path of everything drawn.
        clip_frustums: Draw each frustum V(i) intersected with Z (what the camera covers
            in the cell) rather than out to its far plane.
        labels: Draw the cameras' names.
        style: Colours.
    """
    root = vis[prefix]
    root["cell"].delete()
    zone = cell.zone.manifold()
    root["cell/zone"].set_object(wireframe_object(*manifold_arrays(zone), style.zone))
    zone_lo, zone_hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    for obstacle in cell.obstacles:
        vertices, faces = trimesh_arrays(obstacle.mesh)
        node = root["cell/obstacles"][safe_name(obstacle.name)]
        lo, hi = obstacle.mesh.bounds
        if np.any(lo >= zone_hi - 1e-9) or np.any(hi <= zone_lo + 1e-9):
            # An enclosure (wall, fence) outside Z: faint glass and edges, so the view
            # into the cell stays open.
            node.set_object(mesh_object(vertices, faces, style.obstacle_solid, style.enclosure_opacity))
            node["edges"].set_object(wireframe_object(vertices, faces, style.obstacle_solid))
        elif obstacle.solid:
            node.set_object(mesh_object(vertices, faces, style.obstacle_solid))
        else:
            node.set_object(mesh_object(vertices, faces, style.obstacle_open, style.obstacle_open_opacity))

    resolved = _resolve_robot(cell, robot)
    if resolved is None:
        root["robot"].delete()
    else:
        if q is not None:
            q_robot = np.asarray(q, dtype=np.float64)
        elif cell.robot is not None:
            q_robot = np.asarray(cell.robot.q, dtype=np.float64)
        else:
            raise RobotError("draw_cell: the cell has no [robot] entry, so give q [rad]")
        draw_robot(root["robot"], resolved, q_robot, style=style)

    root["cameras"].delete()
    for index, camera in enumerate(cell.cameras):
        node = root["cameras"][safe_name(camera.name)]
        frustum = camera.frustum()
        if clip_frustums:
            frustum = frustum ^ zone
        if not frustum.is_empty():
            node["frustum"].set_object(wireframe_object(*manifold_arrays(frustum), camera_color(index)))
        body = trimesh.creation.box(extents=(0.16, 0.10, 0.08))
        body.apply_transform(camera.T_world_camera)
        node["body"].set_object(mesh_object(*trimesh_arrays(body), style.camera_body))
        if labels:
            node["label"].set_object(TextLabel(camera.name, height=0.8))
            node["label"].set_transform(_translation(camera.center + np.array([0.0, 0.0, 0.25])))


def draw_frames(
    vis: VisualizerLike,
    cell: Cell,
    frames: Mapping[str, DepthFrame],
    *,
    prefix: str = DEFAULT_PREFIX,
    max_points: int = 20_000,
    style: Style = STYLE,
) -> list[str]:
    """Draw each depth frame as a point cloud under ``<prefix>/frames/<camera>``.

    Valid pixels (finite, within the camera's range) are unprojected to the world, at most
    ``max_points`` per camera spread evenly over the image, and coloured by depth.

    Returns:
        The cameras drawn (a frame without a valid pixel draws nothing).

    Raises:
        FrameError: A frame names a camera the cell does not have, or has the wrong shape.
    """
    names = {c.name for c in cell.cameras}
    unknown = sorted(set(frames) - names)
    if unknown:
        raise FrameError(f"frames of unknown cameras {unknown}; the cell has {sorted(names)}")
    root = vis[prefix]["frames"]
    root.delete()
    drawn = []
    for name, frame in frames.items():
        cloud = frame_cloud(cell.camera(name), frame, max_points, style.point_size)
        if cloud is not None:
            root[safe_name(name)].set_object(cloud)
            drawn.append(name)
    return drawn


def draw_camera_regions(
    vis: VisualizerLike,
    regions: Mapping[str, m3.Manifold],
    *,
    prefix: str = DEFAULT_PREFIX,
    colors: Mapping[str, int] | None = None,
    visible: bool = False,
    style: Style = STYLE,
) -> None:
    """Draw each camera's possibly occupied region C(i) under ``<prefix>/regions/camera``.

    Args:
        vis: A meshcat visualizer.
        regions: Camera name to C(i) (as ``Monitor.camera_regions`` returns).
        prefix: Root path.
        colors: Colour per camera; by default the palette in the order of ``regions``
            (the cell's camera order, which matches the frustum colours).
        visible: Initial visibility; each C(i) covers most of the cell, so they start
            hidden and are switched on one at a time in the meshcat controls.
        style: Opacity.
    """
    root = vis[prefix]["regions/camera"]
    root.delete()
    for index, (name, region) in enumerate(regions.items()):
        color = colors[name] if colors is not None and name in colors else camera_color(index)
        node = root[safe_name(name)]
        if draw_manifold(node, region, color, style.camera_region_opacity):
            _set_visible(node, visible)


def draw_verdict(
    vis: VisualizerLike,
    verdict: VerdictLike,
    *,
    prefix: str = DEFAULT_PREFIX,
    style: Style = STYLE,
) -> None:
    """Draw one verdict of the monitor: C, M, R, the removed components and the distance.

    C (blue), M (purple) and R (red) are see-through so nested regions stay visible; an
    empty region deletes its path. The closest-distance segment joins the point of R and
    the point of the robot, coloured by the speed scale (red = stop, yellow, green = full
    speed), with a label giving the distance, the link and the speed.

    Args:
        vis: A meshcat visualizer (e.g. your controller's), or a :class:`StaticVisualizer`.
        verdict: A ``polyhull.monitor.Verdict`` (or anything with its fields).
        prefix: Root path; use the prefix of :func:`draw_cell` so both share the frame.
        style: Colours.
    """
    regions = vis[prefix]["regions"]
    draw_manifold(regions["hull"], verdict.hull, style.hull, style.hull_opacity)
    draw_manifold(
        regions["robot_occlusion"],
        verdict.robot_occlusion,
        style.robot_occlusion,
        style.robot_occlusion_opacity,
    )
    draw_manifold(regions["region"], verdict.region, style.region, style.region_opacity)
    removed = regions["removed"]
    removed.delete()
    for k, component in enumerate(verdict.removed):
        draw_manifold(
            removed[f"{k}_{safe_name(component.rule)}"],
            component.mesh,
            style.removed,
            style.removed_opacity,
        )
    draw_distance(vis[prefix]["distance"], verdict)


def draw_distance(vis: VisualizerLike, verdict: DistanceLike) -> bool:
    """Draw the closest-distance segment of ``verdict`` at ``vis``, or delete it.

    Returns:
        True when a segment was drawn (there are closest points and the distance is finite).
    """
    vis.delete()
    points = verdict.closest_points
    if points is None or not np.isfinite(verdict.min_distance):
        return False
    p = np.asarray(points, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(p)):
        return False
    color = speed_color_hex(verdict.speed_scale)
    vis["segment"].set_object(segments_object(p, color))
    for name, point in (("region_point", p[0]), ("robot_point", p[1])):
        vis[name].set_object(mg.Sphere(0.04), mg.MeshLambertMaterial(color=color))
        vis[name].set_transform(_translation(point))
    link = f" to {verdict.closest_link}" if verdict.closest_link else ""
    text = f"{verdict.min_distance:.2f} m{link}, speed {100.0 * verdict.speed_scale:.0f} %"
    vis["label"].set_object(TextLabel(text, height=2.0))
    vis["label"].set_transform(_translation(p.mean(axis=0) + np.array([0.0, 0.0, 0.15])))
    return True


# -- the view -------------------------------------------------------------------------------
def view_pose(cell: Cell) -> tuple[ArrayF64, ArrayF64]:
    """Where the default view puts the scene and the viewer's camera.

    meshcat 0.3's orbit controls always orbit the scene origin, so the view moves the cell
    instead of the camera: the floor centre of Z goes to the origin.

    Returns:
        ``T_scene_world`` (4, 4), the transform applied to the prefix, and the viewer
        camera's position in the scene frame (3,) [m], looking at the origin from the
        front-right, above.
    """
    lo, hi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    floor_centre = np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]])
    T_scene_world = _translation(-floor_centre)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    direction = np.array([0.55, -1.0, 0.8])
    eye = direction / np.linalg.norm(direction) * (1.85 * radius)
    return T_scene_world, eye


def set_view(
    vis: VisualizerLike, cell: Cell, *, prefix: str = DEFAULT_PREFIX, style: Style = STYLE
) -> None:
    """Centre the cell on the meshcat origin, look at it from above, front-right.

    The transform of ``prefix``, the default camera and the background colours change;
    the geometry under ``prefix`` stays in world coordinates.
    """
    T_scene_world, eye = view_pose(cell)
    vis[prefix].set_transform(T_scene_world)
    # The camera lives in meshcat's y-up frame: scene (x, y, z) is (x, z, -y) there.
    position = [float(eye[0]), float(eye[2]), float(-eye[1])]
    vis["/Cameras/default/rotated/<object>"].set_property("position", position)
    # A light background: black labels and dark lines read well on it.
    vis["/Background"].set_property("top_color", list(hex_to_rgb(style.background_top)))
    vis["/Background"].set_property("bottom_color", list(hex_to_rgb(style.background_bottom)))


def draw_scene(
    vis: VisualizerLike,
    cell: Cell,
    *,
    q: ArrayF64 | Sequence[float] | None = None,
    frames: Mapping[str, DepthFrame] | None = None,
    verdict: VerdictLike | None = None,
    camera_regions: Mapping[str, m3.Manifold] | None = None,
    robot: RobotLike | None = None,
    prefix: str = DEFAULT_PREFIX,
    max_points: int = 20_000,
    style: Style = STYLE,
) -> None:
    """Draw everything known about one moment of a cell and set the default view.

    The robot is drawn at ``q``, else at the verdict's ``q``, else at the cell's default.
    Each part is drawn by the function of the same name: :func:`draw_cell`,
    :func:`draw_frames`, :func:`draw_camera_regions`, :func:`draw_verdict`.
    """
    if q is None and verdict is not None and verdict.q is not None and len(verdict.q) > 0:
        q = np.asarray(verdict.q, dtype=np.float64)
    draw_cell(vis, cell, q, robot=robot, prefix=prefix, style=style)
    if frames is not None:
        draw_frames(vis, cell, frames, prefix=prefix, max_points=max_points, style=style)
    if camera_regions is not None:
        order = {c.name: i for i, c in enumerate(cell.cameras)}
        colors = {name: camera_color(order.get(name, i)) for i, name in enumerate(camera_regions)}
        draw_camera_regions(vis, camera_regions, prefix=prefix, colors=colors, style=style)
    if verdict is not None:
        draw_verdict(vis, verdict, prefix=prefix, style=style)
    set_view(vis, cell, prefix=prefix, style=style)
