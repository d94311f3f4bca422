"""Drawing a cell, its frames, regions and a verdict into a meshcat scene tree.

The default scene tells the story at a glance: the robot in its colours, what moves near
it (the dynamic region) in a saturated colour, the distance as a thick segment with a
label; the rest is faint or hidden. Every item has its own path, so the meshcat UI can
toggle it ("Open Controls" > Scene); "hidden" items start with ``visible = false``::

    <prefix>/cell/zone                      wireframe of the work cell Z
    <prefix>/cell/obstacles/<name>          static objects (grey)
    <prefix>/robot/<link>                   robot links at q, URDF colours (orange if none)
    <prefix>/cameras/<name>/frustum         frustum V(i), clipped to Z, as thin lines
    <prefix>/cameras/<name>/body            a small box at the camera centre
    <prefix>/cameras/<name>/label           the camera's name (one size on screen)
    <prefix>/frames/<camera>                hidden: a depth frame as a point cloud,
                                            subsampled, clipped to Z (colour = depth)
    <prefix>/regions/dynamic                this cycle's part of R (people, new objects)
    <prefix>/regions/static/near            the static part of R near the robot, faint
    <prefix>/regions/static/far             hidden: the static part of R beyond that
    <prefix>/regions/robot_occlusion        hidden: the robot occlusion M (blue)
    <prefix>/regions/hull                   hidden: the depth hull C
    <prefix>/regions/camera/<name>          hidden: each camera's region C(i)
    <prefix>/regions/removed/<k>_<rule>     hidden: components removed by a rule
    <prefix>/distance/segment               closest pair region - robot, a tube coloured
                                            by the speed scale (red stop, green full)
    <prefix>/distance/closest_link          a shell around the closest link, same colour
    <prefix>/distance/label                 "0.84 m to link_3, speed 62 %"

A :class:`~polyhull_viewer.StaticVisualizer` also shows the distance line as HTML text over
the view (``#polyhull-status``). All geometry is drawn in the world frame of the cell. The
functions work on a ``meshcat.Visualizer`` (live) or a ``StaticVisualizer`` (HTML).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import manifold3d as m3
import meshcat.geometry as mg
import numpy as np
import numpy.typing as npt
import trimesh

from polyhull.cell import Cell
from polyhull.errors import FrameError, RobotError
from polyhull.frames import DepthFrame
from polyhull.typed import ArrayF64

from ._colors import STYLE, Style, camera_color, hex_to_rgb, speed_color_hex
from ._geometry import (
    VIEW_FOV_DEG,
    TextLabel,
    colored_mesh_object,
    frame_cloud,
    manifold_arrays,
    mesh_object,
    safe_name,
    trimesh_arrays,
    tube_object,
    wireframe_object,
)
from ._html import StaticVisualizer, VisualizerLike

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
    "draw_static_region",
    "split_static",
    "draw_scene",
    "distance_text",
    "robot_sphere",
    "set_view",
    "view_pose",
]

DEFAULT_PREFIX = "/polyhull"


class RobotLike(Protocol):
    """What the viewer needs of :class:`polyhull.robot.Robot`."""

    def visual_meshes(self, q: ArrayF64) -> Mapping[str, trimesh.Trimesh]: ...


class RemovedLike(Protocol):
    """A component removed by a plausibility rule (see :class:`polyhull.verdict.Verdict`)."""

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
    """The fields of :class:`polyhull.verdict.Verdict` the viewer draws."""

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


def draw_triangles(
    vis: VisualizerLike, vertices: ArrayF64, faces: npt.NDArray[np.integer[Any]], color: int, opacity: float = 1.0
) -> bool:
    """Draw triangles ((V, 3) vertices, (F, 3) vertex indices) at ``vis`` as a flat-shaded
    mesh, or delete ``vis`` when there are none.

    Returns:
        True when something was drawn.
    """
    faces = np.asarray(faces).reshape(-1, 3)
    if len(faces) == 0:
        vis.delete()
        return False
    v = np.ascontiguousarray(np.asarray(vertices, dtype=np.float32).reshape(-1, 3))
    vis.set_object(mesh_object(v, np.ascontiguousarray(faces, dtype=np.uint32), color, opacity))
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

    Links are opaque, in their URDF material colours; a link without one is orange
    (``style.robot``).

    Returns:
        The names of the links drawn.
    """
    vis.delete()
    names = []
    for link, mesh in robot.visual_meshes(np.asarray(q, dtype=np.float64)).items():
        if len(mesh.faces) == 0:
            continue
        vis[safe_name(link)].set_object(colored_mesh_object(mesh, style.robot))
        names.append(link)
    return names


def robot_sphere(robot: RobotLike, q: ArrayF64 | Sequence[float]) -> tuple[ArrayF64, float]:
    """A sphere around the robot's visual geometry at ``q``: centre (3,) [m] and radius [m].

    The centre is that of the geometry's bounding box; the radius reaches its farthest
    vertex.
    """
    meshes = robot.visual_meshes(np.asarray(q, dtype=np.float64))
    vertices = [np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in meshes.values()]
    points = np.concatenate(vertices + [np.zeros((0, 3))])
    if len(points) == 0:
        return np.zeros(3), 0.0
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    return centre, float(np.linalg.norm(points - centre, axis=1).max())


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
        labels: Draw the cameras' names (all of one size on screen).
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
            node["label"].set_object(TextLabel(camera.name, screen_size=style.camera_label_size))
            node["label"].set_transform(_translation(camera.center + np.array([0.0, 0.0, 0.2])))


def draw_frames(
    vis: VisualizerLike,
    cell: Cell,
    frames: Mapping[str, DepthFrame],
    *,
    prefix: str = DEFAULT_PREFIX,
    max_points: int = 5_000,
    visible: bool = False,
    style: Style = STYLE,
) -> list[str]:
    """Draw each depth frame as a point cloud under ``<prefix>/frames/<camera>``.

    Valid pixels (finite, within the camera's range) are unprojected to the world and
    clipped to the zone Z; at most ``max_points`` per camera are kept, spread evenly over
    the image, and coloured by depth.

    Args:
        visible: Initial visibility of the group ``<prefix>/frames`` (hidden by default:
            the points cover everything else; switch them on in the meshcat controls).

    Returns:
        The cameras drawn (a frame without a valid pixel in Z draws nothing).

    Raises:
        FrameError: A frame names a camera the cell does not have, or has the wrong shape.
    """
    names = {c.name for c in cell.cameras}
    unknown = sorted(set(frames) - names)
    if unknown:
        raise FrameError(f"frames of unknown cameras {unknown}; the cell has {sorted(names)}")
    root = vis[prefix]["frames"]
    root.delete()
    bounds = (np.asarray(cell.zone.min, dtype=np.float64), np.asarray(cell.zone.max, dtype=np.float64))
    drawn = []
    for name, frame in frames.items():
        cloud = frame_cloud(cell.camera(name), frame, max_points, style.point_size, bounds)
        if cloud is not None:
            root[safe_name(name)].set_object(cloud)
            drawn.append(name)
    if drawn:
        _set_visible(root, visible)
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


def split_static(
    static: m3.Manifold, near: tuple[ArrayF64, float] | None
) -> tuple[m3.Manifold, m3.Manifold]:
    """The static region inside and outside the ball ``near`` (centre (3,) [m], radius [m]).

    Without a ball, all of it is inside.
    """
    if near is None:
        return static, m3.Manifold()
    centre, radius = near
    ball = m3.Manifold.sphere(float(radius), 64).translate(tuple(float(x) for x in centre))
    return static ^ ball, static - ball


def draw_static_region(
    vis: VisualizerLike,
    static: m3.Manifold | None,
    *,
    near: tuple[ArrayF64, float] | None = None,
    style: Style = STYLE,
) -> tuple[bool, bool]:
    """Draw the static part of R (blind space, static shadows) as a faint tint.

    Args:
        vis: The path to draw at (``<prefix>/regions/static``).
        static: The static region (``Monitor.static.region``), or None.
        near: Centre (3,) [m] and radius [m] of a ball around the robot: the part inside
            is drawn at ``near`` (visible), the rest at ``far`` (hidden). Without it, all
            of it is drawn at ``near``.
        style: Colour and opacity.

    Returns:
        Whether ``near`` and ``far`` were drawn.
    """
    vis.delete()
    if static is None or static.is_empty():
        return False, False
    inside, outside = split_static(static, near)
    drew_near = draw_manifold(vis["near"], inside, style.static_region, style.static_region_opacity)
    drew_far = draw_manifold(vis["far"], outside, style.static_region, style.static_region_opacity)
    if drew_far:
        _set_visible(vis["far"], False)
    return drew_near, drew_far


def draw_verdict(
    vis: VisualizerLike,
    verdict: VerdictLike,
    *,
    prefix: str = DEFAULT_PREFIX,
    robot: RobotLike | None = None,
    static_region: m3.Manifold | None = None,
    hull: bool = True,
    occlusion: bool = True,
    style: Style = STYLE,
) -> None:
    """Draw one verdict of the monitor: the region (dynamic, static), M, C, removed, distance.

    The dynamic region (people, new objects) is drawn in a saturated colour: given
    ``static_region``, a verdict with ``region_dynamic_drawing()`` (the monitor's) is drawn
    from those triangles, its kept pieces as they are (milliseconds; the union of thousands
    of pieces as ``region_dynamic`` takes seconds), with its pieces that hold no reading
    (``region_unseen_drawing()``: the far part of a dropout patch's rays) paler, under
    ``regions/unseen``; else ``region_dynamic`` minus
    ``static_region``, else ``region_dynamic``; the static region
    (``static_region``, or ``region`` minus ``region_dynamic``) as a faint tint near the
    robot and hidden beyond; together they are all of ``region``. M, C and the
    removed components are drawn hidden (a component with ``drawing()``, the monitor's,
    from those triangles: its pieces, not their union). A verdict without ``region_dynamic`` has its
    whole ``region`` drawn as dynamic. The closest-distance segment joins the point of R
    and the point of the robot, coloured by the speed scale (red = stop, yellow, green =
    full speed), with the closest link outlined and a label giving the distance, the link
    and the speed.

    Args:
        vis: A meshcat visualizer (e.g. your controller's), or a :class:`StaticVisualizer`.
        verdict: A ``polyhull.verdict.Verdict`` (or anything with its fields).
        prefix: Root path; use the prefix of :func:`draw_cell` so both share the frame.
        robot: The robot model: the static region is split at ``style.static_margin``
            around it, and the closest link is outlined. Without it, the static region is
            drawn whole and no link is outlined.
        static_region: The static part of R (``Monitor.static.region``); computed as
            ``region - region_dynamic`` when None.
        hull: Draw C (``verdict.hull``; building it costs a mesh boolean).
        occlusion: Draw M (``verdict.robot_occlusion``; building it costs several).
        style: Colours.
    """
    regions = vis[prefix]["regions"]
    drawing = getattr(verdict, "region_dynamic_drawing", None)
    if callable(drawing) and static_region is not None:
        # The monitor's verdict: what this cycle adds, as its pieces' triangles (no union
        # of thousands of pieces: milliseconds where the manifold takes seconds).
        vertices, faces = drawing()
        draw_triangles(regions["dynamic"], vertices, faces, style.region, style.region_opacity)
        unseen = getattr(verdict, "region_unseen_drawing", None)
        if callable(unseen):  # the pieces no camera read: a dropout's rays, paler
            vertices, faces = unseen()
            draw_triangles(regions["unseen"], vertices, faces, style.region_unseen, style.region_unseen_opacity)
        static = static_region
    else:
        dynamic = getattr(verdict, "region_dynamic", None)  # a property: built when read
        if dynamic is None:
            dynamic, static = verdict.region, None
        elif static_region is not None:
            # What this cycle adds to the static region: the noise sheets restored under a
            # kept piece partly lie in the static region already, and are drawn with it.
            dynamic, static = dynamic - static_region, static_region
        else:
            static = verdict.region - dynamic
        draw_manifold(regions["dynamic"], dynamic, style.region, style.region_opacity)
    q = getattr(verdict, "q", None)
    has_q = q is not None and len(q) > 0
    near = None
    if robot is not None and q is not None and has_q:
        centre, radius = robot_sphere(robot, q)
        near = (centre, radius + style.static_margin)
    draw_static_region(regions["static"], static, near=near, style=style)
    for name, wanted, color, opacity, getter in (
        ("hull", hull, style.hull, style.hull_opacity, lambda: verdict.hull),
        (
            "robot_occlusion",
            occlusion,
            style.robot_occlusion,
            style.robot_occlusion_opacity,
            lambda: verdict.robot_occlusion,
        ),
    ):
        if wanted and draw_manifold(regions[name], getter(), color, opacity):
            _set_visible(regions[name], False)
        elif not wanted:
            regions[name].delete()
    removed = regions["removed"]
    removed.delete()
    for k, component in enumerate(verdict.removed):
        path = removed[f"{k}_{safe_name(component.rule)}"]
        drawing = getattr(component, "drawing", None)
        if callable(drawing):  # the monitor's: its pieces as they are, not their union
            vertices, faces = drawing()
            draw_triangles(path, vertices, faces, style.removed, style.removed_opacity)
        else:
            draw_manifold(path, component.mesh, style.removed, style.removed_opacity)
    if len(verdict.removed):
        _set_visible(removed, False)
    draw_distance(
        vis[prefix]["distance"], verdict, robot=robot if has_q else None, q=q, style=style
    )


def distance_text(verdict: DistanceLike) -> str:
    """The distance line: ``0.84 m to link_3, speed 62 %`` (or what holds instead)."""
    speed = f"speed {100.0 * _clipped(verdict.speed_scale):.0f} %"
    if not np.isfinite(verdict.min_distance):
        return f"no possibly occupied region near the robot, {speed}"
    link = f" to {verdict.closest_link}" if verdict.closest_link else ""
    return f"{verdict.min_distance:.2f} m{link}, {speed}"


def _clipped(speed_scale: float) -> float:
    s = float(speed_scale)
    return 0.0 if np.isnan(s) else min(max(s, 0.0), 1.0)


def draw_distance(
    vis: VisualizerLike,
    verdict: DistanceLike,
    *,
    robot: RobotLike | None = None,
    q: ArrayF64 | Sequence[float] | None = None,
    style: Style = STYLE,
) -> bool:
    """Draw the closest-distance segment of ``verdict`` at ``vis``, or delete it.

    The segment is a tube in the colour of the speed scale with a ball at each end, the
    closest link (given ``robot`` and ``q``) gets a shell of the same colour, and a label
    of fixed screen size says :func:`distance_text`. On a :class:`StaticVisualizer` the
    same text is the page's status line (``#polyhull-status``).

    Returns:
        True when a segment was drawn (there are closest points and the distance is finite).
    """
    vis.delete()
    color = speed_color_hex(verdict.speed_scale)
    text = distance_text(verdict)
    if isinstance(vis, StaticVisualizer):
        vis.set_status(text, color)
    points = verdict.closest_points
    if points is None or not np.isfinite(verdict.min_distance):
        return False
    p = np.asarray(points, dtype=np.float64).reshape(2, 3)
    if not np.all(np.isfinite(p)):
        return False
    tube = tube_object(p[0], p[1], style.segment_radius, color)
    if tube is not None:
        vis["segment"].set_object(tube)
    for name, point in (("region_point", p[0]), ("robot_point", p[1])):
        vis[name].set_object(mg.Sphere(2.0 * style.segment_radius), mg.MeshLambertMaterial(color=color))
        vis[name].set_transform(_translation(point))
    if robot is not None and q is not None and verdict.closest_link:
        mesh = robot.visual_meshes(np.asarray(q, dtype=np.float64)).get(verdict.closest_link)
        if mesh is not None and len(mesh.faces):
            shell = np.asarray(mesh.vertices) + 0.015 * np.asarray(mesh.vertex_normals)
            vis["closest_link"].set_object(
                mesh_object(shell, np.asarray(mesh.faces), color, style.closest_link_opacity)
            )
    vis["label"].set_object(TextLabel(text, screen_size=style.distance_label_size))
    vis["label"].set_transform(_translation(p.mean(axis=0) + np.array([0.0, 0.0, 0.25])))
    return True


# -- the view -------------------------------------------------------------------------------
def _view_target(cell: Cell) -> ArrayF64:
    """What the default view looks at: the robot at working height, else the zone's floor centre."""
    lo, hi = np.asarray(cell.zone.min, dtype=np.float64), np.asarray(cell.zone.max, dtype=np.float64)
    if cell.robot is not None:
        base = np.asarray(cell.robot.base, dtype=np.float64).reshape(-1)[:3]
        height = min(0.6, 0.5 * float(hi[2] - lo[2]))
        return np.array([base[0], base[1], lo[2] + height])
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]])


def view_pose(cell: Cell, aspect: float = 4.0 / 3.0) -> tuple[ArrayF64, ArrayF64]:
    """Where the default view puts the scene and the viewer's camera.

    meshcat 0.3's orbit controls always orbit the scene origin, so the view moves the cell
    instead of the camera: the view's target (the robot at working height, or the floor
    centre of Z without a robot) goes to the origin. The eye looks at it from beyond the
    zone's upper front-right corner (+x, -y, top), as far back as it takes for all of Z to
    fit in a view of meshcat's 75 degree vertical field of view and ``aspect``
    (width / height), with a margin.

    Returns:
        ``T_scene_world`` (4, 4), the transform applied to the prefix, and the viewer
        camera's position in the scene frame (3,) [m], looking at the origin.
    """
    lo, hi = np.asarray(cell.zone.min, dtype=np.float64), np.asarray(cell.zone.max, dtype=np.float64)
    target = _view_target(cell)
    T_scene_world = _translation(-target)
    corner = np.array([hi[0], lo[1], hi[2]])
    direction = corner - target
    # Not straight down a diagonal: lift the eye a little above the corner.
    direction = direction / np.linalg.norm(direction) + np.array([0.0, 0.0, 0.25])
    direction /= np.linalg.norm(direction)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    corners = corners - target
    forward = -direction
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_v = np.tan(np.deg2rad(VIEW_FOV_DEG) / 2.0) * 0.92  # margin: 8 % of the half-view
    tan_h = tan_v * aspect
    distance = 0.25 * float(np.linalg.norm(corner - target))  # from close in, back off
    for _ in range(200):
        eye = direction * distance
        d = corners - eye
        z = d @ forward
        if np.all(z > 0) and np.all(np.abs(d @ right) <= z * tan_h) and np.all(np.abs(d @ up) <= z * tan_v):
            break
        distance *= 1.03
    return T_scene_world, direction * distance


def set_view(
    vis: VisualizerLike, cell: Cell, *, prefix: str = DEFAULT_PREFIX, style: Style = STYLE
) -> None:
    """Centre the view's target on the meshcat origin; look at it from a corner of the zone.

    The transform of ``prefix``, meshcat's grid (moved to the zone's floor), the default
    camera and the background colours change; the geometry under ``prefix`` stays in
    world coordinates.
    """
    T_scene_world, eye = view_pose(cell)
    vis[prefix].set_transform(T_scene_world)
    floor = _translation(np.array([0.0, 0.0, float(cell.zone.min[2]) + T_scene_world[2, 3]]))
    vis["/Grid"].set_transform(floor)
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
    static_region: m3.Manifold | None = None,
    robot: RobotLike | None = None,
    prefix: str = DEFAULT_PREFIX,
    max_points: int = 5_000,
    style: Style = STYLE,
) -> None:
    """Draw everything known about one moment of a cell and set the default view.

    The robot is drawn at ``q``, else at the verdict's ``q``, else at the cell's default.
    Each part is drawn by the function of the same name: :func:`draw_cell`,
    :func:`draw_frames`, :func:`draw_camera_regions`, :func:`draw_verdict` (with
    ``static_region``, e.g. ``Monitor.static.region``).
    """
    if q is None and verdict is not None and verdict.q is not None and len(verdict.q) > 0:
        q = np.asarray(verdict.q, dtype=np.float64)
    resolved = _resolve_robot(cell, robot)
    draw_cell(vis, cell, q, robot=resolved, prefix=prefix, style=style)
    if frames is not None:
        draw_frames(vis, cell, frames, prefix=prefix, max_points=max_points, style=style)
    if camera_regions is not None:
        order = {c.name: i for i, c in enumerate(cell.cameras)}
        colors = {name: camera_color(order.get(name, i)) for i, name in enumerate(camera_regions)}
        draw_camera_regions(vis, camera_regions, prefix=prefix, colors=colors, style=style)
    if verdict is not None:
        draw_verdict(
            vis, verdict, prefix=prefix, robot=resolved, static_region=static_region, style=style
        )
    set_view(vis, cell, prefix=prefix, style=style)
