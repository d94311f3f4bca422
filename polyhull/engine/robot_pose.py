"""The padded robot at this cycle's joint positions: what every later stage reads of it.

Built once (:class:`RobotPieces`): the robot's convex collision pieces grown by the
padding (:class:`polyhull.engine.robot_raster.PaddedPieces`), each piece's bounding sphere
and its noise-shell planes in its link frame, and which pieces belong to links that move.
Every cycle (:meth:`RobotPieces.pose`) moves them to the world at q (:class:`RobotPose`):
the link poses, the padded pieces' vertices (the robot raster, the occlusion M), their
spheres (the carving's robot test, the distance's frontier) and their shell planes (the
too_thin rule around the robot).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.spatial import ConvexHull

from ..plausibility import _ICOSPHERE
from ..robot import Robot
from ..typed import ArrayF64
from .robot_raster import PaddedPieces

__all__ = ["NO_ROBOT", "RobotPieces", "RobotPose", "moving_links"]


@dataclass(frozen=True, eq=False)
class RobotPose:
    """The padded robot at one q, in the world frame.

    Attributes:
        T_links: Link name -> (4, 4) world-from-link transform.
        padded_world: (K_i, 3) hull vertices of every padded piece [m].
        spheres: (P, 4) every padded piece's bounding sphere: centre [m], radius [m].
        shell_planes: (F_i, 4) planes ``n . x <= d`` of every padded piece grown by the
            noise shell (inside the true shell).
    """

    T_links: dict[str, ArrayF64]
    padded_world: list[ArrayF64]
    spheres: ArrayF64
    shell_planes: tuple[ArrayF64, ...]


NO_ROBOT = RobotPose({}, [], np.zeros((0, 4)), ())
"""The pose of a cell without a robot."""


class RobotPieces:
    """The padded robot's convex pieces and what each cycle moves with them (built once).

    Attributes:
        robot: The robot model.
        padded: The padded convex pieces (link frames).
        measured: (P,) whether each piece belongs to a link the distance is measured to
            (one that moves; a base fixed to the world is a static solid).
        moving: The links whose pose depends on an actuated joint.
    """

    def __init__(self, robot: Robot, padding: float, shell_thickness: float) -> None:
        self.robot = robot
        self.moving = moving_links(robot)
        self.padded = PaddedPieces.build(robot.link_convex_pieces(), padding)
        self._spheres = [_sphere(v) for v in self.padded.vertices]
        self._shells = _ShellPlanes(_shell_planes(self.padded, shell_thickness))
        self.measured = np.array([n in self.moving for n in self.padded.links], dtype=bool)

    def pose(self, q: ArrayF64) -> RobotPose:
        """The padded robot at joint positions ``q`` (checked before)."""
        T_links = self.robot.link_transforms(q)
        spheres = np.array(
            [[*(T_links[n][:3, :3] @ c + T_links[n][:3, 3]), r] for n, (c, r) in zip(self.padded.links, self._spheres, strict=True)]
        ).reshape(-1, 4)
        return RobotPose(T_links, self.padded.world(T_links), spheres, self._shells.world(T_links))


def moving_links(robot: Robot) -> frozenset[str]:
    """Links whose pose depends on an actuated joint (the others are fixed to the world).

    A link fixed to the world (the base) cannot move toward a person; it is a static solid
    like an obstacle, so speed and separation monitoring measures to the moving links only.
    """
    rng = np.random.default_rng(0)
    lo = np.where(np.isfinite(robot.lower), robot.lower, -np.pi)
    hi = np.where(np.isfinite(robot.upper), robot.upper, np.pi)
    ref = robot.link_transforms((lo + hi) / 2)
    moving: set[str] = set()
    for _ in range(3):
        T = robot.link_transforms(rng.uniform(lo, hi))
        moving |= {n for n in ref if not np.allclose(T[n], ref[n], atol=1e-9)}
    return frozenset(moving)


def _sphere(vertices: ArrayF64) -> tuple[ArrayF64, float]:
    c = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return c, float(np.linalg.norm(vertices - c, axis=1).max())


def _shell_planes(padded: PaddedPieces, thickness: float) -> list[tuple[str, ArrayF64]]:
    """Per padded piece, (F, 4) planes ``n . x <= d`` (link frame) of the piece grown by a
    polytope inscribed in the ball of radius ``thickness``: inside the true shell."""
    out = []
    for name, v in zip(padded.links, padded.vertices, strict=True):
        grown = (v[:, None, :] + thickness * _ICOSPHERE[None, :, :]).reshape(-1, 3)
        eq = ConvexHull(grown).equations  # n . x + c <= 0 inside
        out.append((name, np.column_stack([eq[:, :3], -eq[:, 3]])))
    return out


class _ShellPlanes:
    """Every padded piece's shell planes (link frame), moved to the world in one batch."""

    def __init__(self, planes: list[tuple[str, ArrayF64]]) -> None:
        self._links = [n for n, _ in planes]
        self._flat = np.concatenate([p for _, p in planes]).reshape(-1, 4) if planes else np.zeros((0, 4))
        self._piece = np.repeat(np.arange(len(planes)), [len(p) for _, p in planes]).astype(np.int64)
        self._splits = np.cumsum([len(p) for _, p in planes])[:-1]

    def world(self, T_links: Mapping[str, ArrayF64]) -> tuple[ArrayF64, ...]:
        """(F_i, 4) planes ``n . x <= d`` of every piece in the world frame."""
        if not self._links:
            return ()
        T = np.array([T_links[n] for n in self._links], dtype=np.float64)
        out = np.empty_like(self._flat)
        _move_planes(self._flat, self._piece, T, out)
        return tuple(np.split(out, self._splits))


@nb.njit(cache=True, nogil=True)
def _move_planes(planes, piece, T, out):  # pragma: no cover - compiled
    """Planes ``n . x <= d`` (F, 4) of piece ``piece[f]`` from its frame to the world
    (``T`` (P, 4, 4), world from piece): ``n' = R n``, ``d' = d + n' . t``."""
    for f in range(planes.shape[0]):
        p = piece[f]
        dot = 0.0
        for a in range(3):
            x = T[p, a, 0] * planes[f, 0] + T[p, a, 1] * planes[f, 1] + T[p, a, 2] * planes[f, 2]
            out[f, a] = x
            dot += x * T[p, a, 3]
        out[f, 3] = planes[f, 3] + dot
