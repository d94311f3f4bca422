"""Pinhole cameras: intrinsics, pose, projection and the frustum.

Conventions: the camera frame is the OpenCV / ROS optical frame (x right,
y down, z forward); the centre of pixel (u, v) is at integer coordinates (u, v) and the
pixel covers [u - 0.5, u + 0.5) x [v - 0.5, v + 0.5); depth is z-depth in [m].

Besides world and camera coordinates, polyhull uses the camera's *inverse-depth image
space* ``(u, v, w)`` with ``w = -1 / z``. The map from camera space to it is a projective
transformation, so it sends lines to lines and planes to planes: a prism over an image
polygon between two depths is a box-like solid in ``(u, v, w)`` and maps back to a solid
with planar faces in the world, exactly. ``w`` grows with depth and the map preserves
orientation (its Jacobian determinant is ``fx * fy / z**4 > 0``), so a manifold built in
image space stays a valid, outward-oriented manifold after :meth:`Camera.image_to_world`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import manifold3d as m3
import numpy as np

from .errors import CameraError
from .typed import ArrayF64, Transform

__all__ = [
    "Intrinsics",
    "Camera",
    "CameraKind",
    "look_at_rotation",
    "quaternion_to_rotation",
    "check_rigid_transform",
]

CameraKind = Literal["depth", "color"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention, no distortion).

    Attributes:
        width: Image width in [px].
        height: Image height in [px].
        fx: Focal length along x in [px].
        fy: Focal length along y in [px].
        cx: Principal point x in [px] (pixel centres at integers).
        cy: Principal point y in [px].
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int | np.integer) and self.width > 0):
            raise CameraError(f"intrinsics.width must be a positive integer, got {self.width!r}")
        if not (isinstance(self.height, int | np.integer) and self.height > 0):
            raise CameraError(f"intrinsics.height must be a positive integer, got {self.height!r}")
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise CameraError(f"intrinsics.{name} must be finite, got {value!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise CameraError(
                f"intrinsics.fx and fy must be > 0 [px], got fx={self.fx!r}, fy={self.fy!r}"
            )

    @property
    def K(self) -> ArrayF64:  # noqa: N802 - the conventional name of the matrix
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape as (height, width), the shape of a depth array."""
        return (self.height, self.width)

    def scaled(self, factor: int) -> Intrinsics:
        """Intrinsics of the image downsampled by an integer ``factor`` (blocks of pixels).

        Block (bu, bv) covers pixels [bu * factor, (bu + 1) * factor); its centre sits at
        ``bu * factor + (factor - 1) / 2`` in full-resolution pixel coordinates.
        """
        if factor < 1:
            raise CameraError(f"downsampling factor must be >= 1, got {factor}")
        return Intrinsics(
            width=-(-self.width // factor),
            height=-(-self.height // factor),
            fx=self.fx / factor,
            fy=self.fy / factor,
            cx=(self.cx + 0.5) / factor - 0.5,
            cy=(self.cy + 0.5) / factor - 0.5,
        )


def check_rigid_transform(T: ArrayF64, what: str = "transform", atol: float = 1e-6) -> Transform:
    """Return ``T`` as a float64 (4, 4) array, or raise if it is not a rigid transform.

    Args:
        T: Candidate homogeneous transform.
        what: Name used in the error message (e.g. ``cameras[1].T_world_camera``).
        atol: Tolerance on orthonormality and on the last row.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise CameraError(f"{what} must be a (4, 4) matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise CameraError(f"{what} must be finite, got {T.tolist()}")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=atol) or np.linalg.det(R) < 0.0:
        raise CameraError(f"{what} rotation is not orthonormal with det +1: {R.tolist()}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=atol):
        raise CameraError(f"{what} last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    return T


def look_at_rotation(position: ArrayF64, target: ArrayF64) -> ArrayF64:
    """Rotation of ``T_world_camera`` for a camera at ``position`` looking at ``target``.

    The optical axis (camera +z) points at ``target``; image up (camera -y) is world +z
    projected onto the image plane. An optical axis parallel to world z has no defined
    image up and is rejected.

    Returns:
        (3, 3) rotation whose columns are the camera axes expressed in the world frame.
    """
    position = np.asarray(position, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    forward = target - position
    norm = float(np.linalg.norm(forward))
    if not np.isfinite(norm) or norm < 1e-9:
        raise CameraError(
            f"look_at {target.tolist()} must differ from position {position.tolist()}"
        )
    z_axis = forward / norm
    up_world = np.array([0.0, 0.0, 1.0])
    up_in_image = up_world - z_axis * float(up_world @ z_axis)
    up_norm = float(np.linalg.norm(up_in_image))
    if up_norm < 1e-6:
        raise CameraError(
            "look_at: the optical axis is parallel to world z, so image up is undefined; "
            "give a quaternion instead or tilt the camera"
        )
    y_axis = -up_in_image / up_norm
    x_axis = np.cross(y_axis, z_axis)
    return np.column_stack([x_axis, y_axis, z_axis])


def quaternion_to_rotation(quaternion: ArrayF64) -> ArrayF64:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]`` (normalised here)."""
    q = np.asarray(quaternion, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise CameraError(f"quaternion must be 4 finite numbers [w, x, y, z], got {q.tolist()}")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise CameraError(f"quaternion must have unit norm (within 1e-3), got norm {n:.6g}")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated depth (or colour) camera.

    Attributes:
        name: Unique camera name.
        kind: ``"depth"``, or ``"color"`` for a camera with binary (change / no change) depth.
        intrinsics: Pinhole intrinsics.
        T_world_camera: (4, 4) rigid transform from camera to world coordinates.
        near: Minimum valid depth in [m].
        far: Maximum valid depth (rated range) in [m].
        noise: Depth noise standard deviation in [m] at 1 m; it grows with depth squared.
        tolerance_sigmas: The depth tolerance tau is this many standard deviations.
        tolerance_min: Floor of the depth tolerance in [m] (quantisation, calibration).
        topic: The ``sensor_msgs/Image`` depth topic of this camera in ROS bags
            (``/cam_ne/depth/image_raw``); its ``CameraInfo`` is read from ``camera_info``
            in the same namespace. None: the camera name, as ``/<name>/depth/image_raw``.
    """

    name: str
    kind: CameraKind
    intrinsics: Intrinsics
    T_world_camera: Transform
    near: float = 0.3
    far: float = 8.0
    noise: float = 0.003
    tolerance_sigmas: float = 3.0
    tolerance_min: float = 0.01
    topic: str | None = None
    _T_camera_world: Transform = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in ("depth", "color"):
            raise CameraError(
                f"camera '{self.name}': type must be 'depth' or 'color', got {self.kind!r}"
            )
        T = check_rigid_transform(self.T_world_camera, f"camera '{self.name}' T_world_camera")
        T.setflags(write=False)
        object.__setattr__(self, "T_world_camera", T)
        if not (np.isfinite(self.near) and np.isfinite(self.far) and 0 < self.near < self.far):
            raise CameraError(
                f"camera '{self.name}': range must satisfy 0 < near < far (finite) [m], "
                f"got near={self.near!r}, far={self.far!r}"
            )
        if not (np.isfinite(self.noise) and self.noise >= 0):
            raise CameraError(f"camera '{self.name}': noise must be >= 0 [m], got {self.noise!r}")
        if not (np.isfinite(self.tolerance_sigmas) and self.tolerance_sigmas >= 0):
            raise CameraError(
                f"camera '{self.name}': tolerance_sigmas must be >= 0, got {self.tolerance_sigmas!r}"
            )
        T_cw = np.eye(4)
        T_cw[:3, :3] = T[:3, :3].T
        T_cw[:3, 3] = -T[:3, :3].T @ T[:3, 3]
        T_cw.setflags(write=False)
        object.__setattr__(self, "_T_camera_world", T_cw)

    # -- pose -------------------------------------------------------------------------
    @property
    def T_camera_world(self) -> Transform:
        """(4, 4) transform from world to camera coordinates."""
        return self._T_camera_world

    @property
    def center(self) -> ArrayF64:
        """Camera centre in the world frame [m], shape (3,)."""
        return self.T_world_camera[:3, 3]

    @property
    def shape(self) -> tuple[int, int]:
        """Depth image shape (height, width)."""
        return self.intrinsics.shape

    # -- noise model ------------------------------------------------------------------
    def sigma(self, depth: ArrayF64 | float) -> ArrayF64:
        """Depth noise standard deviation in [m] at z-depth ``depth`` [m]."""
        d = np.asarray(depth, dtype=np.float64)
        return self.noise * d * d

    def tau(self, depth: ArrayF64 | float) -> ArrayF64:
        """Depth tolerance tau(z) in [m]: ``max(tolerance_sigmas * sigma(z), tolerance_min)``."""
        return np.maximum(self.tolerance_sigmas * self.sigma(depth), self.tolerance_min)

    # -- projection -------------------------------------------------------------------
    def world_to_camera(self, points_world: ArrayF64) -> ArrayF64:
        """Points (N, 3) from world to camera coordinates."""
        p = np.asarray(points_world, dtype=np.float64)
        T = self.T_camera_world
        return p @ T[:3, :3].T + T[:3, 3]

    def camera_to_world(self, points_camera: ArrayF64) -> ArrayF64:
        """Points (N, 3) from camera to world coordinates."""
        p = np.asarray(points_camera, dtype=np.float64)
        T = self.T_world_camera
        return p @ T[:3, :3].T + T[:3, 3]

    def project(self, points_world: ArrayF64) -> tuple[ArrayF64, ArrayF64]:
        """Project world points (N, 3) to pixel coordinates (N, 2) and z-depths (N,) [m].

        Points behind the camera get z <= 0 and meaningless pixel coordinates; callers
        mask them with ``z > 0``.
        """
        pc = self.world_to_camera(points_world)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.intrinsics.fx * pc[:, 0] / z + self.intrinsics.cx
            v = self.intrinsics.fy * pc[:, 1] / z + self.intrinsics.cy
        return np.column_stack([u, v]), z

    def unproject(self, uv: ArrayF64, depth: ArrayF64) -> ArrayF64:
        """World points (N, 3) at pixel coordinates ``uv`` (N, 2) and z-depth (N,) [m]."""
        uv = np.asarray(uv, dtype=np.float64)
        z = np.asarray(depth, dtype=np.float64)
        k = self.intrinsics
        pc = np.column_stack([(uv[:, 0] - k.cx) * z / k.fx, (uv[:, 1] - k.cy) * z / k.fy, z])
        return self.camera_to_world(pc)

    def pixel_rays(self, step: int = 1) -> ArrayF64:
        """Camera-frame ray directions with unit z for the pixel centres, (H', W', 3).

        A point at z-depth d along the ray of pixel (u, v) is ``d * rays[v, u]``.
        """
        k = self.intrinsics
        u = np.arange(0, k.width, step, dtype=np.float64)
        v = np.arange(0, k.height, step, dtype=np.float64)
        uu, vv = np.meshgrid(u, v)
        return np.stack([(uu - k.cx) / k.fx, (vv - k.cy) / k.fy, np.ones_like(uu)], axis=-1)

    # -- inverse-depth image space ----------------------------------------------------
    def world_to_image(self, points_world: ArrayF64) -> ArrayF64:
        """World points (N, 3) to inverse-depth image space (u, v, w = -1/z), (N, 3)."""
        uv, z = self.project(points_world)
        with np.errstate(divide="ignore"):
            return np.column_stack([uv, -1.0 / z])

    def image_to_world(self, points_image: ArrayF64) -> ArrayF64:
        """Inverse-depth image space (u, v, w = -1/z), (N, 3), to world points (N, 3)."""
        p = np.asarray(points_image, dtype=np.float64)
        z = -1.0 / p[:, 2]
        return self.unproject(p[:, :2], z)

    def image_box(self) -> tuple[ArrayF64, ArrayF64]:
        """Corners (lo, hi) of the frustum in image space: the image rectangle x [near, far]."""
        k = self.intrinsics
        lo = np.array([-0.5, -0.5, -1.0 / self.near])
        hi = np.array([k.width - 0.5, k.height - 0.5, -1.0 / self.far])
        return lo, hi

    def frustum(self) -> m3.Manifold:
        """The frustum V(i) (image rectangle between near and far) as a manifold in the world."""
        lo, hi = self.image_box()
        box = m3.Manifold.cube(tuple(hi - lo)).translate(tuple(lo))
        return box.warp_batch(self.image_to_world)
