"""Voxel labels of the placement simulation (paper section 4).

Every voxel of a regular grid over the work cell Z is tagged *target-free*, *changed* or
*undetectable* for a set of cameras, the static scene and a set of targets (people):

For each voxel centre ``p`` and camera ``i``, ``p`` is projected into the camera; outside
the image or outside ``[near, far]`` the camera says *undetectable*. Otherwise, with ``B``
the reference depth (floor and static obstacles) and ``D`` the depth with the targets
present (noise free) at the nearest pixel, the camera says

- *target-free* when ``z(p) < f`` with the free depth ``f = min(D, B) - tau(D)``
  (a colour camera frees nothing along a changed pixel);
- *changed* when the pixel is changed, ``D < B - tau(D)`` (``p`` lies behind it);
- *undetectable* otherwise (``p`` lies behind the static background).

The fused label is target-free when at least ``k`` cameras say so (``k = 1`` is the plain
rule, ``k > 1`` the k-of-n rule of paper section 4, item 4), otherwise changed when some
camera says changed, otherwise undetectable. Following paper section 4 ("the inside of
static objects [...] is always undetectable", "the inside of targets [...] is always
changed or undetectable") voxels whose centre lies inside a static obstacle are always
undetectable and voxels inside a target are never target-free. This keeps the optimal
values f_opt true lower bounds of the objectives, whatever the pixel rounding does at
object boundaries.

Everything is vectorised with numpy: the grid is projected into a camera slab by slab
(one x index at a time, so every temporary stays in cache), and the pixel lookup is one
gather per camera.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import trimesh

from ..camera import Camera
from ..cell import Zone
from ..errors import GeometryError
from ..regions import free_depth
from ..typed import ArrayBool, ArrayF32, ArrayF64

__all__ = [
    "PAPER_GRID",
    "Label",
    "VoxelGrid",
    "GridProjection",
    "project_grid",
    "free_depth_image",
    "camera_votes",
    "fuse_labels",
    "mesh_mask",
    "label_voxels",
    "label_from_free_depth",
    "boundary_mask",
]

#: The voxel grid of the paper's setup (section 3.1): 126 x 90 x 66 voxels over Z.
PAPER_GRID: tuple[int, int, int] = (126, 90, 66)

ArrayI32 = npt.NDArray[np.int32]
ArrayI8 = npt.NDArray[np.int8]


class Label(IntEnum):
    """The three sections of paper section 4 (values of a label array, dtype int8)."""

    FREE = 0
    CHANGED = 1
    UNDETECTABLE = 2


@dataclass(frozen=True)
class VoxelGrid:
    """A regular grid of voxels partitioning an axis-aligned box (the zone Z).

    Voxel ``(i, j, k)`` covers ``lo + [i, i + 1) * spacing`` (per axis); its centre is at
    ``lo + (i + 0.5) * spacing``. Flat voxel indices are in C order (``i`` slowest).

    Attributes:
        lo: Minimum corner of the box [m], world frame.
        hi: Maximum corner of the box [m], world frame.
        shape: Voxel counts ``(nx, ny, nz)``.
    """

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=np.float64)
        hi = np.asarray(self.hi, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)):
            raise GeometryError(
                f"voxel grid: lo and hi must be 3 finite numbers [m], got {self.lo!r}, {self.hi!r}"
            )
        if not np.all(hi > lo):
            raise GeometryError(f"voxel grid: hi {hi.tolist()} must exceed lo {lo.tolist()}")
        shape = tuple(int(n) for n in np.asarray(self.shape).ravel())
        if len(shape) != 3 or min(shape) < 1:
            raise GeometryError(
                f"voxel grid: shape must be 3 positive voxel counts (nx, ny, nz), got {self.shape!r}"
            )
        object.__setattr__(self, "lo", tuple(float(x) for x in lo))
        object.__setattr__(self, "hi", tuple(float(x) for x in hi))
        object.__setattr__(self, "shape", shape)

    @classmethod
    def from_zone(cls, zone: Zone, shape: Sequence[int] = PAPER_GRID) -> VoxelGrid:
        """The grid of ``shape`` voxels over the zone box (default: the paper's grid)."""
        return cls(lo=zone.min, hi=zone.max, shape=(int(shape[0]), int(shape[1]), int(shape[2])))

    @property
    def size(self) -> int:
        """Number of voxels N."""
        return int(np.prod(self.shape))

    @property
    def spacing(self) -> ArrayF64:
        """Voxel edge lengths (3,) [m]."""
        return (np.asarray(self.hi) - np.asarray(self.lo)) / np.asarray(self.shape)

    @property
    def voxel_volume(self) -> float:
        """Volume of one voxel [m^3]."""
        return float(np.prod(self.spacing))

    @property
    def volume(self) -> float:
        """Volume of the whole box [m^3]."""
        return float(np.prod(np.asarray(self.hi) - np.asarray(self.lo)))

    def axes(self) -> tuple[ArrayF64, ArrayF64, ArrayF64]:
        """Voxel centre coordinates along x (nx,), y (ny,) and z (nz,) [m]."""
        lo, h = np.asarray(self.lo), self.spacing
        return tuple(  # type: ignore[return-value]
            lo[a] + (np.arange(self.shape[a], dtype=np.float64) + 0.5) * h[a] for a in range(3)
        )

    def centers(self) -> ArrayF64:
        """Voxel centres (N, 3) [m] in flat (C) order."""
        xs, ys, zs = self.axes()
        grid = np.meshgrid(xs, ys, zs, indexing="ij")
        return np.stack([g.ravel() for g in grid], axis=1)

    def flat_indices_in_box(self, lo: ArrayF64, hi: ArrayF64) -> npt.NDArray[np.int64]:
        """Flat indices of the voxels whose centre lies in the closed box [lo, hi] [m]."""
        xs, ys, zs = self.axes()
        sel = [
            np.flatnonzero((ax >= lo[a]) & (ax <= hi[a])) for a, ax in enumerate((xs, ys, zs))
        ]
        if any(len(s) == 0 for s in sel):
            return np.zeros(0, dtype=np.int64)
        ii, jj, kk = np.meshgrid(*sel, indexing="ij")
        return np.ravel_multi_index((ii.ravel(), jj.ravel(), kk.ravel()), self.shape).astype(
            np.int64
        )


class GridProjection(NamedTuple):
    """The voxel centres of a grid seen by one camera.

    Attributes:
        pixel: (N,) int32 flat index ``v' * W' + u'`` of the nearest pixel in the depth
            image rendered with pixel stride ``step``, or -1 where the voxel centre is
            outside the image or outside the camera's ``[near, far]`` (undetectable).
        depth: (N,) float32 z-depth of the voxel centre in the camera [m].
    """

    pixel: ArrayI32
    depth: ArrayF32


def project_grid(camera: Camera, grid: VoxelGrid, step: int = 1) -> GridProjection:
    """Project every voxel centre of ``grid`` into ``camera`` (nearest pixel).

    Visibility is decided at full resolution: a centre at pixel coordinates ``(u, v)`` is
    in the image when ``-0.5 <= u < W - 0.5`` and ``-0.5 <= v < H - 0.5`` (:mod:`polyhull.camera`)
    and in range when ``near <= z <= far``. Its pixel is the nearest rendered pixel centre
    (``round(u / step)``, clamped to the rendered image).

    Args:
        camera: The camera.
        grid: The voxel grid.
        step: Pixel stride of the depth images the indices refer to (1: full resolution).

    Returns:
        The pixel index and depth of each voxel centre.
    """
    if not (isinstance(step, int | np.integer) and step >= 1):
        raise GeometryError(f"pixel step must be a positive integer [px], got {step!r}")
    k = camera.intrinsics
    width, height = k.width, k.height
    sub_w = -(-width // step)
    sub_h = -(-height // step)
    # Homogeneous pixel coordinates (u z, v z, z) are affine in the voxel centre and the
    # grid is a tensor product of axes, so each row is a sum of per-axis terms.
    P = k.K @ camera.T_camera_world[:3, :]  # (3, 4)
    xs, ys, zs = grid.axes()
    ax = (P[:, 0:1] * xs[None, :]).astype(np.float32)  # (3, nx)
    by = (P[:, 1:2] * ys[None, :]).astype(np.float32)  # (3, ny)
    cz = (P[:, 2:3] * zs[None, :] + P[:, 3:4]).astype(np.float32)  # (3, nz)
    yz = [by[r][:, None] + cz[r][None, :] for r in range(3)]  # 3 x (ny, nz)
    nx = grid.shape[0]
    pixel = np.empty((nx, grid.shape[1], grid.shape[2]), dtype=np.int32)
    depth = np.empty((nx, grid.shape[1], grid.shape[2]), dtype=np.float32)
    near, far = np.float32(camera.near), np.float32(camera.far)
    half = np.float32(0.5)
    inv_step = np.float32(1.0 / step)
    for i in range(nx):
        z = ax[2, i] + yz[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (ax[0, i] + yz[0]) / z
            v = (ax[1, i] + yz[1]) / z
            ok = (z >= near) & (z <= far)
            ok &= (u >= -half) & (u < width - half) & (v >= -half) & (v < height - half)
            # Truncation is the floor for u + 0.5 >= 0; other voxels are masked below.
            if step == 1:
                iu = (u + half).astype(np.int32)
                iv = (v + half).astype(np.int32)
            else:
                iu = np.minimum((u * inv_step + half).astype(np.int32), sub_w - 1)
                iv = np.minimum((v * inv_step + half).astype(np.int32), sub_h - 1)
        idx = iv * np.int32(sub_w) + iu
        idx[~ok] = -1
        pixel[i] = idx
        depth[i] = z
    return GridProjection(pixel=pixel.ravel(), depth=depth.ravel())


def free_depth_image(
    camera: Camera, reference: ArrayF32 | ArrayF64, measured: ArrayF32 | ArrayF64
) -> tuple[ArrayF32, ArrayBool]:
    """Per-pixel free depth and change mask of one camera.

    The free depth is the engine's (:func:`polyhull.regions.free_depth`), so that the
    evaluation uses the same definition of F as the reconstruction (paper section 4, item
    4): ``min(D, B) - tau(D)`` for a depth camera, and for a colour camera nothing along a
    changed pixel and ``B - tau(B)`` along an unchanged one, clipped to ``[near, far]``.
    A pixel is changed when ``D < B - tau(D)`` (the engine's test). ``D`` is what the
    simulated sensor reports: a depth beyond ``far`` becomes +inf, "no return" (REP 117),
    which frees the ray up to the rated range and changes nothing.

    Args:
        camera: The camera (its ``kind``, range and noise model).
        reference: (H', W') reference z-depth ``B`` [m], +inf where nothing is hit.
        measured: (H', W') z-depth ``D`` with the targets present [m] (noise free, as
            ray cast), +inf where nothing is hit.

    Returns:
        ``(free_depth, changed)``: (H', W') float32 free depth ``f`` [m] (a voxel centre
        in range at z-depth ``z < f`` is target-free for this camera; ``near`` frees
        nothing) and the (H', W') bool mask of changed pixels.
    """
    B = np.asarray(reference, dtype=np.float64)
    D = np.asarray(measured, dtype=np.float64)
    if B.shape != D.shape:
        raise GeometryError(
            f"camera '{camera.name}': reference shape {B.shape} differs from measured {D.shape}"
        )
    # The simulated sensor: nothing within range returns +inf, "no return" (REP 117).
    D = np.where(D > camera.far, np.inf, D)
    finite_d = np.isfinite(D)
    with np.errstate(invalid="ignore"):
        changed = finite_d & (D < B - camera.tau(np.where(finite_d, D, 0.0)))
    free = free_depth(camera, D, B)
    return free.astype(np.float32), changed


def camera_votes(
    projection: GridProjection, free_depth: ArrayF32, changed: ArrayBool
) -> tuple[ArrayBool, ArrayBool]:
    """What one camera says about every voxel.

    Args:
        projection: The grid seen by the camera (:func:`project_grid`).
        free_depth: (H', W') free depth [m] (:func:`free_depth_image`).
        changed: (H', W') changed-pixel mask.

    Returns:
        ``(free, behind_changed)``: (N,) bool masks of the voxels the camera calls
        target-free, and of those it calls changed (not free, behind a changed pixel).
    """
    visible = projection.pixel >= 0
    pix = np.where(visible, projection.pixel, 0)
    free = visible & (projection.depth < free_depth.ravel()[pix])
    behind = visible & ~free & changed.ravel()[pix]
    return free, behind


def fuse_labels(
    free_count: npt.NDArray[np.integer],
    changed_any: ArrayBool,
    k: int = 1,
    static_mask: ArrayBool | None = None,
    target_mask: ArrayBool | None = None,
) -> ArrayI8:
    """Fuse per-camera votes into labels (k-of-n rule).

    Args:
        free_count: (N,) number of cameras that call each voxel target-free.
        changed_any: (N,) True where some camera calls the voxel changed.
        k: A voxel is target-free when at least ``k`` cameras say so.
        static_mask: (N,) voxels inside static obstacles: always undetectable.
        target_mask: (N,) voxels inside targets: never target-free.

    Returns:
        (N,) int8 labels (:class:`Label` values).
    """
    if not (isinstance(k, int | np.integer) and k >= 1):
        raise GeometryError(f"k of the k-of-n rule must be an integer >= 1, got {k!r}")
    free = np.asarray(free_count) >= k
    changed = np.asarray(changed_any, dtype=bool)
    if target_mask is not None:
        free &= ~target_mask
    if static_mask is not None:
        free &= ~static_mask
        changed = changed & ~static_mask
    labels = np.full(free.shape, Label.UNDETECTABLE, dtype=np.int8)
    labels[changed & ~free] = Label.CHANGED
    labels[free] = Label.FREE
    return labels


def mesh_mask(grid: VoxelGrid, meshes: Sequence[trimesh.Trimesh]) -> ArrayBool:
    """Voxels whose centre lies inside any of the closed ``meshes`` (the indicators delta).

    Only the centres within each mesh's bounding box are tested (trimesh containment,
    ray parity with Embree); an axis-aligned box mesh is decided exactly from its bounds.

    Args:
        grid: The voxel grid.
        meshes: Closed (watertight) meshes in the world frame [m].

    Returns:
        (N,) bool mask.
    """
    mask = np.zeros(grid.size, dtype=bool)
    centers: ArrayF64 | None = None
    for n, mesh in enumerate(meshes):
        if len(mesh.faces) == 0:
            continue
        if not mesh.is_watertight:
            raise GeometryError(
                f"mesh {n} of {len(mesh.faces)} faces is not watertight: its inside (the "
                "static or target indicator) is undefined; repair it or give a box"
            )
        lo, hi = mesh.bounds
        idx = grid.flat_indices_in_box(lo, hi)
        if len(idx) == 0:
            continue
        if _is_axis_aligned_box(mesh):
            mask[idx] = True
            continue
        if centers is None:
            centers = grid.centers()
        inside = np.asarray(mesh.contains(centers[idx]), dtype=bool)
        mask[idx[inside]] = True
    return mask


def _is_axis_aligned_box(mesh: trimesh.Trimesh) -> bool:
    """True when the mesh is exactly its axis-aligned bounding box."""
    if len(mesh.vertices) != 8:
        return False
    lo, hi = mesh.bounds
    v = np.asarray(mesh.vertices)
    on_bounds = np.isclose(v, lo, atol=1e-12) | np.isclose(v, hi, atol=1e-12)
    return bool(np.all(on_bounds)) and np.isclose(mesh.volume, np.prod(hi - lo), rtol=1e-9)


def label_voxels(
    cameras: Sequence[Camera],
    grid: VoxelGrid,
    references: Sequence[ArrayF32],
    measured: Sequence[ArrayF32],
    k: int = 1,
    static_mask: ArrayBool | None = None,
    target_mask: ArrayBool | None = None,
    step: int = 1,
) -> ArrayI8:
    """Labels of every voxel for given rendered depth images (one target scene).

    Args:
        cameras: The cameras.
        grid: The voxel grid.
        references: Per camera (H', W') reference depth ``B`` [m] (static scene, floor).
        measured: Per camera (H', W') depth ``D`` with the targets [m], noise free.
        k: k of the k-of-n rule.
        static_mask: (N,) voxels inside static obstacles (:func:`mesh_mask`).
        target_mask: (N,) voxels inside targets.
        step: Pixel stride the images were rendered with.

    Returns:
        (N,) int8 labels (:class:`Label` values).
    """
    if not (len(cameras) == len(references) == len(measured)):
        raise GeometryError(
            f"need one reference and one measured image per camera, got {len(cameras)} "
            f"cameras, {len(references)} references, {len(measured)} measured"
        )
    images = [free_depth_image(c, B, D) for c, B, D in zip(cameras, references, measured, strict=True)]
    return label_from_free_depth(
        cameras,
        grid,
        [f for f, _ in images],
        [ch for _, ch in images],
        k=k,
        static_mask=static_mask,
        target_mask=target_mask,
        step=step,
    )


def label_from_free_depth(
    cameras: Sequence[Camera],
    grid: VoxelGrid,
    free_depths: Sequence[ArrayF32 | ArrayF64],
    changed: Sequence[ArrayBool],
    k: int = 1,
    static_mask: ArrayBool | None = None,
    target_mask: ArrayBool | None = None,
    step: int = 1,
) -> ArrayI8:
    """Labels of every voxel from per-camera free depth images and change masks.

    Args:
        cameras: The cameras.
        grid: The voxel grid.
        free_depths: Per camera (H', W') free depth [m] (:func:`free_depth_image`).
        changed: Per camera (H', W') changed-pixel mask.
        k: k of the k-of-n rule.
        static_mask: (N,) voxels inside static obstacles (always undetectable).
        target_mask: (N,) voxels inside targets (never target-free).
        step: Pixel stride of the images.

    Returns:
        (N,) int8 labels (:class:`Label` values).
    """
    if not (len(cameras) == len(free_depths) == len(changed)):
        raise GeometryError(
            f"need one free depth image and one change mask per camera, got {len(cameras)} "
            f"cameras, {len(free_depths)} free depth images, {len(changed)} masks"
        )
    free_count = np.zeros(grid.size, dtype=np.int16)
    changed_any = np.zeros(grid.size, dtype=bool)
    for camera, f, ch in zip(cameras, free_depths, changed, strict=True):
        free, behind = camera_votes(project_grid(camera, grid, step), np.asarray(f), ch)
        free_count += free
        changed_any |= behind
    return fuse_labels(free_count, changed_any, k, static_mask, target_mask)


def boundary_mask(labels: npt.NDArray[np.integer], shape: Sequence[int]) -> ArrayBool:
    """Voxels with a 26-neighbour of a different label: where the voxel volumes err.

    A voxel whose cell is cut by the boundary between two labels is counted whole for the
    label of its centre. When the boundary is planar at the scale of a voxel, some
    26-neighbour of such a voxel has its centre across the boundary, so
    ``count(boundary_mask) * voxel_volume`` bounds the error of each label's volume.
    (The faces of Z are voxel faces, so they add no error.)

    Args:
        labels: (N,) labels in flat (C) order.
        shape: Grid shape ``(nx, ny, nz)``.

    Returns:
        (N,) bool mask.
    """
    lab = np.asarray(labels).reshape(tuple(int(n) for n in shape))
    out = np.zeros(lab.shape, dtype=bool)
    nx, ny, nz = lab.shape
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if dx == dy == dz == 0:
                    continue
                a = tuple(
                    slice(max(0, -d), n - max(0, d)) for d, n in zip((dx, dy, dz), (nx, ny, nz), strict=True)
                )
                b = tuple(
                    slice(max(0, d), n - max(0, -d)) for d, n in zip((dx, dy, dz), (nx, ny, nz), strict=True)
                )
                out[a] |= lab[a] != lab[b]
    return out.ravel()
