"""An animated, standalone HTML record of a monitored run: the person, the robot and R.

The page shares what does not change and sends only what does. The cell (zone, obstacles,
cameras) and the static part of the region (blind space, static shadows: the same every
cycle) are drawn once. The robot's links are rigid, so each link is drawn once and its
transform animated. meshcat animations can change only transforms and visibility, not
geometry, so what changes shape every cycle gets one small mesh per cycle, whose
``visible`` property is animated so only the current cycle's shows::

    <prefix>/anim/person/<k>          the simulated person of cycle k
    <prefix>/anim/region/<k>          the dynamic region of cycle k (saturated)
    <prefix>/anim/distance/<k>/...    the distance tube, the closest link's shell, the label
    <prefix>/regions/static/near|far  the static region, drawn once (far: hidden)

The page autoplays with meshcat's animation controls open, and a status line over the
view follows the animation: time, distance, closest link and speed.

To keep the file small, at most ``max_cycles`` cycles (evenly spread over the run) go into
the file, and meshes are decimated for display to a budget of triangles (the recorded
verdicts are not touched).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import manifold3d as m3
import meshcat.animation as ma
import numpy as np
import trimesh

from polyhull.cell import Cell
from polyhull.errors import PolyhullError
from polyhull.typed import ArrayF32, ArrayF64

from ._colors import STYLE, Style, speed_color_hex
from ._geometry import (
    ArrayU32,
    cluster_decimate,
    manifold_arrays,
    mesh_object,
    safe_name,
    trimesh_arrays,
)
from ._html import StaticVisualizer, write_html
from ._scene import (
    DEFAULT_PREFIX,
    RobotLike,
    VerdictLike,
    _resolve_robot,
    distance_text,
    draw_cell,
    draw_distance,
    robot_sphere,
    set_view,
    split_static,
)

__all__ = ["DemoRecorder", "rigid_transform"]


def rigid_transform(source: ArrayF64, target: ArrayF64) -> tuple[ArrayF64, float]:
    """The rigid transform that best maps points ``source`` (N, 3) onto ``target`` (N, 3).

    Least squares over corresponding points (Kabsch), without reflection.

    Returns:
        ``T_target_source`` (4, 4) and the largest residual distance [m].
    """
    a = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    if a.shape != b.shape or len(a) == 0:
        return np.eye(4), float("inf")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    H = (a - ca).T @ (b - cb)
    U, _, Vt = np.linalg.svd(H)
    d = 1.0 if np.linalg.det(Vt.T @ U.T) >= 0.0 else -1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cb - R @ ca
    residual = float(np.max(np.linalg.norm(a @ R.T + T[:3, 3] - b, axis=1)))
    return T, residual


@dataclass(frozen=True, eq=False)
class _Cycle:
    t: float
    q: ArrayF64
    person: tuple[ArrayF32, ArrayU32]
    region: tuple[ArrayF32, ArrayU32]  # the dynamic region (V, 3), (F, 3)
    closest_points: ArrayF64 | None
    min_distance: float
    speed_scale: float
    closest_link: str | None


class DemoRecorder:
    """Collect the cycles of a run and write them as an animated standalone HTML scene.

    Example::

        recorder = DemoRecorder(cell, static_region=monitor.static.region)
        for t, q, person in run:
            verdict = monitor.step(sim.render(q, targets=[person]), q, stamp=t)
            recorder.add_cycle(t, q, [person], verdict)
        recorder.write_html("demo.html")

    Args:
        cell: The cell of the run (drawn once: zone, obstacles, cameras).
        robot: The robot model; ``polyhull.robot.Robot.from_spec(cell.robot)`` when None.
        static_region: The static part of R (``Monitor.static.region``), drawn once; its
            part near the robot shows as a faint tint, the rest is hidden.
        max_cycles: Most cycles written to the file, evenly spread over the run.
        max_faces: Most triangles of one cycle's person or region mesh (decimated for
            display beyond).
        face_budget: Most triangles of all cycles' region meshes together; each kept
            cycle gets an equal share (at most ``max_faces``), which bounds the file size.
        static_faces: Most triangles of each of the static region's two parts.
        fps: Frame rate of the animation's key times (meshcat counts time in frames).
        prefix: Root path of the scene.
        style: Colours.
    """

    def __init__(
        self,
        cell: Cell,
        *,
        robot: RobotLike | None = None,
        static_region: m3.Manifold | None = None,
        max_cycles: int = 100,
        max_faces: int = 4000,
        face_budget: int = 60_000,
        static_faces: int = 30_000,
        fps: float = 30.0,
        prefix: str = DEFAULT_PREFIX,
        style: Style = STYLE,
    ) -> None:
        if max_cycles < 2:
            raise PolyhullError(f"DemoRecorder: max_cycles must be >= 2, got {max_cycles}")
        if max_faces < 12:
            raise PolyhullError(f"DemoRecorder: max_faces must be >= 12, got {max_faces}")
        if face_budget < 12 or static_faces < 12:
            raise PolyhullError(
                f"DemoRecorder: face_budget and static_faces must be >= 12, got "
                f"{face_budget} and {static_faces}"
            )
        if not (np.isfinite(fps) and fps > 0):
            raise PolyhullError(f"DemoRecorder: fps must be > 0, got {fps}")
        self.cell = cell
        self.robot = _resolve_robot(cell, robot)
        self.max_cycles = int(max_cycles)
        self.max_faces = int(max_faces)
        self.face_budget = int(face_budget)
        self.static_faces = int(static_faces)
        self.static_region = static_region
        self.fps = float(fps)
        self.prefix = prefix
        self.style = style
        self._cycles: list[_Cycle] = []

    @property
    def cycle_count(self) -> int:
        """Number of cycles added so far."""
        return len(self._cycles)

    def add_cycle(
        self,
        t: float,
        q: ArrayF64 | Sequence[float],
        person_meshes: Sequence[trimesh.Trimesh],
        verdict: VerdictLike,
    ) -> None:
        """Record one cycle.

        Args:
            t: Time of the cycle [s]; strictly increasing from cycle to cycle.
            q: Joint positions [rad] of the robot in this cycle.
            person_meshes: The people (or other targets) in the world frame.
            verdict: The monitor's verdict of this cycle; what it adds to the static
                region is drawn: ``region_dynamic_drawing()`` (and
                ``region_unseen_drawing()``) when it has one (the
                monitor's :class:`polyhull.verdict.Verdict`: its kept pieces as they are,
                not united, in milliseconds where the union of thousands of pieces near the
                robot takes seconds), else ``region_dynamic`` minus ``static_region``, else
                its whole ``region``. Only that region is read.
        """
        t = float(t)
        if not np.isfinite(t):
            raise PolyhullError(f"DemoRecorder.add_cycle: t must be finite [s], got {t}")
        if self._cycles and t <= self._cycles[-1].t:
            raise PolyhullError(
                f"DemoRecorder.add_cycle: t = {t} s must exceed the previous cycle's "
                f"t = {self._cycles[-1].t} s"
            )
        q_arr = np.array(q, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(q_arr)):
            raise PolyhullError(f"DemoRecorder.add_cycle: q must be finite [rad], got {q_arr.tolist()}")
        parts = [trimesh_arrays(m) for m in person_meshes]
        offsets = np.cumsum([0] + [len(v) for v, _ in parts])
        person = (
            np.concatenate([v for v, _ in parts] + [np.zeros((0, 3), np.float32)]),
            np.concatenate(
                [f + np.uint32(o) for (_, f), o in zip(parts, offsets, strict=False)]
                + [np.zeros((0, 3), np.uint32)]
            ),
        )
        points = verdict.closest_points
        closest = None if points is None else np.array(points, dtype=np.float64).reshape(2, 3)
        drawing = getattr(verdict, "region_dynamic_drawing", None)
        if callable(drawing):
            v, f = drawing()
            unseen = getattr(verdict, "region_unseen_drawing", None)
            if callable(unseen):  # drawn with it here: one region a cycle in the animation
                uv, uf = unseen()
                v, f = np.concatenate([v, uv]), np.concatenate([f, np.asarray(uf) + len(v)])
            region_arrays = (
                np.ascontiguousarray(np.asarray(v, dtype=np.float32).reshape(-1, 3)),
                np.ascontiguousarray(np.asarray(f, dtype=np.uint32).reshape(-1, 3)),
            )
        else:
            dynamic = getattr(verdict, "region_dynamic", None)
            if dynamic is None:
                region = verdict.region
            elif self.static_region is not None:
                region = dynamic - self.static_region  # what this cycle adds to the static region
            else:
                region = dynamic
            region_arrays = manifold_arrays(region)
        self._cycles.append(
            _Cycle(
                t=t,
                q=q_arr,
                person=person,
                region=region_arrays,
                closest_points=closest,
                min_distance=float(verdict.min_distance),
                speed_scale=float(verdict.speed_scale),
                closest_link=verdict.closest_link,
            )
        )

    def kept_cycles(self) -> list[int]:
        """Indices of the cycles that go into the file (at most ``max_cycles``, evenly spread)."""
        n = len(self._cycles)
        if n <= self.max_cycles:
            return list(range(n))
        return sorted({int(round(x)) for x in np.linspace(0, n - 1, self.max_cycles)})

    def build(self, *, repetitions: int = 1000) -> StaticVisualizer:
        """The animated scene (the static cell plus one animation of the run).

        Args:
            repetitions: How many times the animation loops when the page opens.
        """
        if not self._cycles:
            raise PolyhullError("DemoRecorder: no cycle recorded; call add_cycle first")
        kept = [self._cycles[i] for i in self.kept_cycles()]
        times = np.array([c.t for c in kept])
        step = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
        frames = (times - times[0]) * self.fps
        end = float((times[-1] - times[0] + step) * self.fps)
        region_faces = max(12, min(self.max_faces, self.face_budget // len(kept)))

        vis = StaticVisualizer()
        root = vis[self.prefix]
        draw_cell(vis, self.cell, kept[0].q, robot=self.robot, prefix=self.prefix, style=self.style)
        self._draw_static(root, kept)
        animation = ma.Animation(default_framerate=self.fps)

        groups: list[list[str]] = []
        for k, cycle in enumerate(kept):
            groups.append(self._draw_cycle(root, k, cycle, region_faces))
        if self.robot is not None:
            self._animate_robot(root, kept, frames, end, animation, groups)
        for k, paths in enumerate(groups):
            for path in paths:
                root[path].set_property("visible", k == 0)
                with animation.at_frame(root, 0.0) as frame:
                    frame[path].set_property("visible", "boolean", k == 0)
                if k > 0:
                    with animation.at_frame(root, float(frames[k])) as frame:
                        frame[path].set_property("visible", "boolean", True)
                if k + 1 < len(kept):
                    with animation.at_frame(root, float(frames[k + 1])) as frame:
                        frame[path].set_property("visible", "boolean", False)
                with animation.at_frame(root, end) as frame:
                    frame[path].set_property("visible", "boolean", k + 1 == len(kept))
        vis.set_animation(animation, play=True, repetitions=int(repetitions))
        vis.set_timeline(
            frames / self.fps,
            [f"t = {c.t:.1f} s: {distance_text(c)}" for c in kept],
            [speed_color_hex(c.speed_scale) for c in kept],
            end / self.fps,
        )
        set_view(vis, self.cell, prefix=self.prefix, style=self.style)
        return vis

    def write_html(self, path: str | Path, *, title: str | None = None) -> Path:
        """Write the animated scene as standalone HTML to ``path``; return the path."""
        vis = self.build()
        return write_html(vis, path, title=title or f"polyhull demo: {self.cell.name}")

    # -- internals ----------------------------------------------------------------------------
    def _draw_static(self, root: StaticVisualizer, kept: list[_Cycle]) -> None:
        """The static region once: near the robot (over the run) faint, the rest hidden."""
        node = root["regions/static"]
        node.delete()
        static = self.static_region
        if static is None or static.is_empty():
            return
        near = None
        if self.robot is not None:
            spheres = [robot_sphere(self.robot, c.q) for c in kept]
            centres = np.array([c for c, _ in spheres])
            centre = centres.mean(axis=0)
            radius = max(float(np.linalg.norm(c - centre)) + r for c, r in spheres)
            near = (centre, radius + self.style.static_margin)
        for name, part in zip(("near", "far"), split_static(static, near), strict=True):
            if part.is_empty():
                continue
            v, f = cluster_decimate(*manifold_arrays(part), self.static_faces)
            if len(f):
                node[name].set_object(
                    mesh_object(v, f, self.style.static_region, self.style.static_region_opacity)
                )
                if name == "far":
                    node[name].set_property("visible", False)

    def _draw_cycle(
        self, root: StaticVisualizer, k: int, cycle: _Cycle, region_faces: int
    ) -> list[str]:
        style = self.style
        paths = []
        vertices, faces = cycle.person
        if len(faces):
            v, f = cluster_decimate(vertices, faces, self.max_faces)
            root[f"anim/person/{k}"].set_object(mesh_object(v, f, style.person))
            paths.append(f"anim/person/{k}")
        vertices, faces = cycle.region
        if len(faces):
            v, f = cluster_decimate(vertices, faces, region_faces)
            if len(f):
                root[f"anim/region/{k}"].set_object(
                    mesh_object(v, f, style.region, style.region_opacity)
                )
                paths.append(f"anim/region/{k}")
        # a cycle reads like a verdict
        if draw_distance(root[f"anim/distance/{k}"], cycle, robot=self.robot, q=cycle.q, style=style):
            paths.append(f"anim/distance/{k}")
        return paths

    def _animate_robot(
        self,
        root: StaticVisualizer,
        kept: list[_Cycle],
        frames: ArrayF64,
        end: float,
        animation: Any,
        groups: list[list[str]],
    ) -> None:
        """Animate the links' transforms, or show one robot mesh per cycle if not rigid."""
        assert self.robot is not None
        meshes = [self.robot.visual_meshes(c.q) for c in kept]
        first = meshes[0]
        poses: dict[str, list[ArrayF64]] = {link: [] for link in first}
        rigid = True
        for per_link in meshes:
            if set(per_link) != set(first):
                rigid = False
                break
            for link, mesh in per_link.items():
                T, residual = rigid_transform(first[link].vertices, mesh.vertices)
                if residual > 1e-4:
                    rigid = False
                    break
                poses[link].append(T)
            if not rigid:
                break
        if rigid:
            for link, transforms in poses.items():
                path = f"robot/{safe_name(link)}"
                for k, T in enumerate(transforms):
                    with animation.at_frame(root, float(frames[k])) as frame:
                        frame[path].set_transform(T)
                with animation.at_frame(root, end) as frame:
                    frame[path].set_transform(transforms[-1])
            return
        # Not rigid (the model re-meshes per q): one robot per cycle, switched by visibility.
        root["robot"].delete()
        for k, per_link in enumerate(meshes):
            for link, mesh in per_link.items():
                vertices, faces = trimesh_arrays(mesh)
                root[f"anim/robot/{k}/{safe_name(link)}"].set_object(
                    mesh_object(vertices, faces, self.style.robot)
                )
            groups[k].append(f"anim/robot/{k}")
