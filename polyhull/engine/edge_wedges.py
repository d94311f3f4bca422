"""Edge wedges: where a static edge's widened band meets another camera's robot shadow.

At a depth camera's static edge the band is the pixel's 3 x 3 neighbourhood's (flying
pixels, :mod:`polyhull.engine.static_model`), so a reading anywhere between the nearer and
the farther surface is static, and the static free depth ``f_s`` is the nearer surface's.
Behind it lies the pixel's **wedge**: its ray from ``f_s`` to ``own_free``, the least free
depth of a reading of the pixel's own background. The static model counts the wedge as
hidden from the camera, which is conservative for ``C_static``. But a segment's end is the
depth the static scene (and the robot) lets the camera see free, and the robot occlusion
``M = F_static \\ F_static+robot`` is defined from the empty cell, where the pixel reads its
own background and sees its wedge free. Ending the pixel's segment at ``f_s`` would count a
wedge point that another camera sees only in the empty cell (now behind the robot) as M,
and a person standing there, read by this pixel in front of its own background (within
the widened band, so static), would be lost.

So the segment of an edge pixel runs to ``own_free`` wherever its wedge may meet another
camera's robot shadow, and a reading in front of its own band then has a segment (the
other cameras carve it like any other). Elsewhere the wedge changes nothing: a wedge point
the other cameras see free with the robot is free, and one they do not see even in the
empty cell lies in ``C_static``. The test is conservative, per cycle and per camera pair:
the image rectangle of the wedge's eight corners (its pixel's corners at both depths,
projected once) against the rectangle of the padded robot's vertices, and the wedge's
farthest depth against the robot's nearest, in the other camera (a colour camera's robot
hides its whole ray). About 1,000 edge pixels a camera, a few comparisons each.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..camera import Camera

__all__ = ["EdgeWedges", "RobotBox", "robot_boxes"]


class RobotBox(NamedTuple):
    """The padded robot in one camera's image: the pixel rectangle (u0, u1, v0, v1) of its
    vertices (the whole image when a vertex is not in front of the camera) and its nearest
    depth [m] (0 for a colour camera, whose robot hides the whole ray)."""

    u0: float
    u1: float
    v0: float
    v1: float
    zmin: float


def robot_boxes(cameras: Sequence[Camera], vertices: np.ndarray) -> list[RobotBox | None]:
    """Per camera, the :class:`RobotBox` of the padded robot's world ``vertices`` (N, 3), or
    None where the robot is wholly outside the image (it shadows nothing there)."""
    out: list[RobotBox | None] = []
    vt = np.asarray(vertices, dtype=np.float64).T
    for cam in cameras:
        H, W = cam.shape
        if len(vertices) == 0:
            out.append(None)
            continue
        T = cam.T_camera_world
        pc = T[:3, :3] @ vt + T[:3, 3:4]  # (3, N): rows reduce fast
        z = pc[2]
        if z.min() <= 1e-9:
            out.append(RobotBox(-np.inf, np.inf, -np.inf, np.inf, 0.0))
            continue
        x, y = pc[0] / z, pc[1] / z
        k = cam.intrinsics
        x0, x1, y0, y1 = x.min(), x.max(), y.min(), y.max()
        u0, u1 = k.fx * x0 + k.cx - 1.0, k.fx * x1 + k.cx + 1.0
        v0, v1 = k.fy * y0 + k.cy - 1.0, k.fy * y1 + k.cy + 1.0
        if u1 < -0.5 or v1 < -0.5 or u0 > W - 0.5 or v0 > H - 0.5:
            out.append(None)
            continue
        out.append(RobotBox(float(u0), float(u1), float(v0), float(v1), 0.0 if cam.kind == "color" else float(np.min(z))))
    return out


class _Wedges(NamedTuple):
    """One camera's wedges: pixels (n, 2) as (v, u), their ``own_free`` (n,) [m], the other
    cameras' indices (J,), and in each other camera's image the wedges' rectangle and
    farthest depth [m], (5, J, n): u0, u1, v0, v1, zmax."""

    vu: np.ndarray
    end: np.ndarray
    others: np.ndarray
    boxes: np.ndarray


class EdgeWedges:
    """Every camera's edge wedges, projected into the other cameras once."""

    def __init__(self, wedges: list[_Wedges]) -> None:
        self._wedges = wedges

    @classmethod
    def build(cls, statics: Sequence[object]) -> EdgeWedges:
        """From the static cameras (:class:`polyhull.engine.static_model.StaticCamera`: their
        ``camera``, ``edge``, ``free_static`` and ``own_free``)."""
        cams = [s.camera for s in statics]  # type: ignore[attr-defined]
        wedges = []
        for i, s in enumerate(statics):
            cam: Camera = s.camera  # type: ignore[attr-defined]
            fs = np.asarray(s.free_static, dtype=np.float64)  # type: ignore[attr-defined]
            own = np.asarray(s.own_free, dtype=np.float64)  # type: ignore[attr-defined]
            v, u = np.nonzero(np.asarray(s.edge) & (own > fs))  # type: ignore[attr-defined]
            corners = _corners(cam, u, v, fs[v, u], own[v, u])  # (n, 8, 3) world
            others = np.array([j for j in range(len(cams)) if j != i], dtype=np.int64)
            boxes = np.empty((5, len(others), len(v)))
            for n, j in enumerate(others):
                uv, z = cams[j].project(corners.reshape(-1, 3))
                uv = uv.reshape(-1, 8, 2)
                z = z.reshape(-1, 8)
                behind = np.any(z <= 1e-9, axis=1)
                with np.errstate(invalid="ignore"):
                    b = np.stack(
                        [uv[:, :, 0].min(axis=1), uv[:, :, 0].max(axis=1), uv[:, :, 1].min(axis=1), uv[:, :, 1].max(axis=1), z.max(axis=1)]
                    )
                b[:, behind] = np.array([-np.inf, np.inf, -np.inf, np.inf, np.inf])[:, None]
                boxes[:, n] = b
            wedges.append(_Wedges(np.column_stack([v, u]).astype(np.int64), own[v, u].astype(np.float32), others, boxes))
        return cls(wedges)

    def count(self, i: int) -> int:
        """Camera ``i``'s number of edge wedges."""
        return len(self._wedges[i].end)

    def ends(self, i: int, robots: Sequence[RobotBox | None]) -> tuple[np.ndarray, np.ndarray]:
        """Camera ``i``'s edge pixels (m, 2) as (v, u) whose wedge may meet another camera's
        robot shadow this cycle (``robots``: :func:`robot_boxes`), and their segment end
        ``own_free`` (m,) [m]."""
        w = self._wedges[i]
        seen = [n for n, j in enumerate(w.others) if robots[j] is not None]
        if not seen or not len(w.end):
            return w.vu[:0], w.end[:0]
        r = np.array([robots[w.others[n]] for n in seen]).T[:, :, None]  # (5, J', 1)
        b = w.boxes[:, seen] if len(seen) < len(w.others) else w.boxes
        hit = ((b[1] >= r[0]) & (b[0] <= r[1]) & (b[3] >= r[2]) & (b[2] <= r[3]) & (b[4] >= r[4])).any(axis=0)
        return w.vu[hit], w.end[hit]


def _corners(cam: Camera, u: np.ndarray, v: np.ndarray, z0: np.ndarray, z1: np.ndarray) -> np.ndarray:
    """(n, 8, 3) world points: the corners of pixels (u, v) at z-depths ``z0`` and ``z1``."""
    k = cam.intrinsics
    du = np.array([-0.5, 0.5, 0.5, -0.5, -0.5, 0.5, 0.5, -0.5])
    dv = np.array([-0.5, -0.5, 0.5, 0.5, -0.5, -0.5, 0.5, 0.5])
    z = np.column_stack([z0, z0, z0, z0, z1, z1, z1, z1])
    x = (u[:, None] + du - k.cx) / k.fx * z
    y = (v[:, None] + dv - k.cy) / k.fy * z
    pts = np.stack([x, y, z], axis=2)
    return cam.camera_to_world(pts.reshape(-1, 3)).reshape(-1, 8, 3)
