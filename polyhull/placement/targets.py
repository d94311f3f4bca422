"""Target scenes for the placement simulation: people sampled over the walkable floor.

A placement is scored on a set of *target scenes*. Each scene holds a few people (one by
default) in standing or reaching poses at places sampled over the walkable floor: inside
Z (with a margin to the walls), not intersecting any obstacle and keeping a clearance to
the robot base. Reaching people face the robot, as over a work table.

The objectives are averaged over the scenes (see :mod:`polyhull.placement.objectives`).
Evaluating people one scene at a time, rather than all together, asks the question of
paper section 4 for each place a person may stand, without the people shadowing one
another, and the average is the expected quality over where a person stands.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import manifold3d as m3
import numpy as np
import trimesh

from ..cell import Cell, mesh_to_manifold
from ..errors import GeometryError
from ..person import PersonPose, make_person

__all__ = ["PersonPlacement", "TargetScene", "sample_target_scenes"]


@dataclass(frozen=True)
class PersonPlacement:
    """Where and how a sampled person stands.

    Attributes:
        pose: a :data:`polyhull.person.PersonPose` (``"standing"``, ``"walking"``, ``"reaching"`` or ``"crouching"``).
        position: Floor position (x, y) [m], world frame.
        yaw: Heading about world z [rad]; 0 faces world +x.
        height: Stature [m].
    """

    pose: PersonPose
    position: tuple[float, float]
    yaw: float
    height: float


@dataclass(frozen=True, eq=False)
class TargetScene:
    """One set of targets evaluated together.

    Attributes:
        meshes: Closed target meshes in the world frame [m].
        people: How each person was placed (empty for targets given as plain meshes).
    """

    meshes: tuple[trimesh.Trimesh, ...]
    people: tuple[PersonPlacement, ...] = ()

    def __post_init__(self) -> None:
        for n, mesh in enumerate(self.meshes):
            if not isinstance(mesh, trimesh.Trimesh):
                raise GeometryError(
                    f"target scene: meshes[{n}] must be a trimesh.Trimesh, got {type(mesh).__name__}"
                )
            if len(mesh.faces) == 0 or not np.all(np.isfinite(mesh.vertices)):
                raise GeometryError(f"target scene: meshes[{n}] is empty or not finite")


def sample_target_scenes(
    cell: Cell,
    n_scenes: int = 6,
    people_per_scene: int = 1,
    poses: Sequence[PersonPose] = ("standing", "reaching"),
    height: float = 1.75,
    seed: int = 0,
    wall_margin: float = 0.25,
    robot_clearance: float = 0.45,
    max_tries: int = 500,
) -> tuple[TargetScene, ...]:
    """People at places sampled uniformly over the walkable floor of ``cell``.

    Scene ``s`` uses pose ``poses[s % len(poses)]`` for all its people. A candidate is
    rejected when the person's mesh leaves Z shrunk by ``wall_margin`` horizontally,
    intersects an obstacle, comes within ``robot_clearance`` (horizontally) of the robot
    base, or within 0.6 m of another person of the same scene.

    Args:
        cell: The work cell.
        n_scenes: Number of target scenes.
        people_per_scene: People in each scene.
        poses: Pose cycle over the scenes.
        height: Stature of the people [m].
        seed: Seed of the sampler (the scenes are deterministic for a seed).
        wall_margin: Horizontal margin to the walls of Z [m].
        robot_clearance: Horizontal clearance of the body from the robot base position [m].
        max_tries: Candidates per person before giving up.

    Returns:
        ``n_scenes`` target scenes.

    Raises:
        GeometryError: No walkable place was found for a person within ``max_tries``.
    """
    if n_scenes < 1 or people_per_scene < 1:
        raise GeometryError(
            f"need n_scenes >= 1 and people_per_scene >= 1, got {n_scenes}, {people_per_scene}"
        )
    if not poses:
        raise GeometryError("poses must name at least one pose")
    rng = np.random.default_rng(seed)
    zone = cell.zone
    lo = np.asarray(zone.min)
    hi = np.asarray(zone.max)
    obstacles = [(o.manifold(), o.mesh.bounds) for o in cell.obstacles]
    robot_xy = None if cell.robot is None else np.asarray(cell.robot.base[:2])
    scenes: list[TargetScene] = []
    for s in range(n_scenes):
        pose = poses[s % len(poses)]
        meshes: list[trimesh.Trimesh] = []
        people: list[PersonPlacement] = []
        for _ in range(people_per_scene):
            for _attempt in range(max_tries):
                xy = rng.uniform(lo[:2] + wall_margin, hi[:2] - wall_margin)
                if pose == "reaching" and robot_xy is not None:
                    d = robot_xy - xy
                    yaw = float(np.arctan2(d[1], d[0])) + rng.normal(0.0, 0.2)
                else:
                    yaw = float(rng.uniform(-np.pi, np.pi))
                if any(np.hypot(*(xy - np.asarray(p.position))) < 0.6 for p in people):
                    continue
                mesh = make_person(
                    height=height,
                    pose=pose,
                    position=(float(xy[0]), float(xy[1])),
                    yaw=yaw,
                    floor_z=zone.floor_z,
                )
                if _walkable(mesh, lo, hi, wall_margin, obstacles, robot_xy, robot_clearance):
                    meshes.append(mesh)
                    people.append(
                        PersonPlacement(
                            pose=pose, position=(float(xy[0]), float(xy[1])), yaw=yaw, height=height
                        )
                    )
                    break
            else:
                raise GeometryError(
                    f"cell '{cell.name}': found no walkable place for a {pose} person in "
                    f"{max_tries} tries; reduce wall_margin ({wall_margin} m) or "
                    f"robot_clearance ({robot_clearance} m), or free some floor"
                )
        scenes.append(TargetScene(meshes=tuple(meshes), people=tuple(people)))
    return tuple(scenes)


def _walkable(
    mesh: trimesh.Trimesh,
    lo: np.ndarray,
    hi: np.ndarray,
    wall_margin: float,
    obstacles: list[tuple[m3.Manifold, np.ndarray]],
    robot_xy: np.ndarray | None,
    robot_clearance: float,
) -> bool:
    """True when the person ``mesh`` stands on free, walkable floor."""
    b_lo, b_hi = mesh.bounds
    if np.any(b_lo[:2] < lo[:2] + wall_margin) or np.any(b_hi[:2] > hi[:2] - wall_margin):
        return False
    if b_hi[2] > hi[2]:
        return False
    if robot_xy is not None:
        dist = np.hypot(*(np.asarray(mesh.vertices)[:, :2] - robot_xy).T)
        if float(dist.min()) < robot_clearance:
            return False
    person: m3.Manifold | None = None
    for solid, bounds in obstacles:
        if np.any(b_hi < bounds[0]) or np.any(b_lo > bounds[1]):
            continue
        if person is None:
            person = mesh_to_manifold(mesh, "sampled person")
        if (person ^ solid).volume() > 1e-9:
            return False
    return True
