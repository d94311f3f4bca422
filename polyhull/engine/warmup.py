"""Synthetic frames that take a new monitor through every stage once, before its first cycle.

A monitor's first cycles cost what no later cycle does: numba loads each compiled kernel
from its on-disk cache on the kernel's first call (about 0.12 s for all of them), the image
and raster buffers are allocated, the pool threads start and python-fcl builds its first
models. Measured on the reference workload: 149 ms for the first cycle and 51 ms for the
second (the shadow memory's first use), against 15 ms for the third. A controller would see
two cycles over the 50 ms deadline, and their latency would enter the reaction time.

:func:`warmup_frames` renders, per camera, the cell's references with a person-sized box
standing next to the robot (the box moves between the two frames, so that the second cycle
has a previous region for the shadow memory) and a few dropout patches. The monitor runs
them and then forgets them (:meth:`polyhull.monitor.Monitor.reset`): they change no state a
later cycle reads, only what is cached.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import trimesh

from ..cell import Cell
from ..frames import DepthFrame
from ..raycast import MeshCaster

__all__ = ["WARMUP_BOX", "warmup_frames"]

WARMUP_BOX = (0.25, 0.25, 1.2)
"""Size [m] of the box standing beside the robot: about 20,000 unexplained pixels in the
default cell's four cameras, as many as a person's, so that every stage has work."""

WARMUP_GAP = 1.0
"""Horizontal distance [m] between the robot's base and the box's near face in the first
frame (0.1 m less in the second): the box is at the distance frontier, so that the pieces
near the robot are refined."""

DROPOUT = 4
"""Side [px] of the dropout patches (a sensor's usual ones, as the simulator's)."""


def _box_at(cell: Cell, k: int, robot_points: np.ndarray) -> trimesh.Trimesh:
    """The standing box of frame ``k``: ``WARMUP_GAP`` beside the robot's base (the zone's
    centre without a robot), moved 0.1 m closer each frame, inside the zone; of eight
    compass directions, the one whose box centre lies farthest (horizontally) from the
    nearest of ``robot_points`` (the robot's link origins at q: away from the arm)."""
    zmin, zmax = np.asarray(cell.zone.min, dtype=np.float64), np.asarray(cell.zone.max, dtype=np.float64)
    size = np.minimum(np.asarray(WARMUP_BOX), 0.5 * (zmax - zmin))
    lo, hi = zmin[:2] + 0.5 * size[:2], zmax[:2] - 0.5 * size[:2]
    if cell.robot is None:
        xy = 0.5 * (zmin[:2] + zmax[:2])
    else:
        base = np.asarray(cell.robot.base[:2], dtype=np.float64)
        angles = np.arange(8) * (np.pi / 4)
        directions = np.column_stack([np.cos(angles), np.sin(angles)])
        offset = WARMUP_GAP + 0.5 * size[0] - 0.1 * k
        centres = np.clip(base + offset * directions, lo, hi)
        pts = np.asarray(robot_points, dtype=np.float64).reshape(-1, 3)[:, :2]
        if len(pts):
            clearance = np.linalg.norm(centres[:, None, :] - pts[None, :, :], axis=2).min(axis=1)
            xy = centres[int(np.argmax(clearance))]
        else:
            xy = centres[0]
    box = trimesh.creation.box(extents=size)
    box.apply_translation([xy[0], xy[1], cell.zone.floor_z + 0.5 * size[2]])
    return box


def warmup_frames(
    cell: Cell, references: Mapping[str, np.ndarray], stamps: Sequence[float], robot_points: np.ndarray
) -> list[dict[str, DepthFrame]]:
    """One frame set per stamp: each camera's reference depth [m] with the standing box
    (:func:`_box_at`, away from ``robot_points`` (P, 3) [m]) in front of it, eight
    ``DROPOUT`` px patches with no reading (0) near the image's corners, and one patch a
    sixteenth of the image wide near its bottom edge (too wide to free whole beyond about
    0.9 m, whatever the resolution: the small gaps' residue, which far patches leave, and
    its test run too); the cameras' range is not applied (the monitor's pixel classes do)."""
    out = []
    for k, stamp in enumerate(stamps):
        caster = MeshCaster([_box_at(cell, k, robot_points)])
        frames = {}
        for cam in cell.cameras:
            depth = np.minimum(np.asarray(references[cam.name], dtype=np.float32), caster.depth(cam))
            H, W = depth.shape
            # near the image's corners, away from the robot (which a camera looks at)
            for v in (H // 16, H - H // 16 - DROPOUT):
                for u in (W // 16, W // 8, W - W // 8 - DROPOUT, W - W // 16 - DROPOUT):
                    depth[v : v + DROPOUT, u : u + DROPOUT] = 0.0
            wide = max(DROPOUT, W // 16)
            v, u = H - H // 16 - wide, W // 4
            depth[max(v, 0) : v + wide, u : u + wide] = 0.0
            frames[cam.name] = DepthFrame(cam.name, depth, stamp=float(stamp))
        out.append(frames)
    return out
