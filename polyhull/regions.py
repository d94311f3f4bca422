"""Per-camera regions: free depth, and the target-free region F(i) as a manifold.

The free depth of pixel p (SPEC section 2) is ``f(p) = min(D(p), B(p)) - tau(D(p))`` for a
valid depth camera pixel, ``near`` (nothing free) for an invalid one; for a colour camera a
changed pixel frees nothing and an unchanged one frees up to ``B(p) - tau(B(p))``.

F(i) is built in the camera's inverse-depth image space ``(u, v, w = -1/z)`` as the solid
between the plane ``w = -1/near`` and a piecewise-linear surface over a grid of pixel
blocks, then mapped to the world by the projective map of :class:`~polyhull.camera.Camera`,
which keeps faces planar. Conservativeness (the region may only shrink, never grow):

- a block's free depth is the **minimum** free depth of its pixels;
- a grid corner takes the minimum over the (up to four) blocks around it, so the linear
  interpolation inside a block never exceeds the block's minimum;
- depth beyond ``far`` is cut at ``far`` (the frustum ends there).

Static / dynamic split: :class:`CameraStatic` precomputes, from the reference depth B, the
per-pixel band ``[T, U]`` of depths consistent with the background (``T`` solves
``T + tau(T) = B``, i.e. the SPEC's "changed" test ``D < B - tau(D)`` is ``D < T``) and a
per-pixel lower bound of the free depth of any consistent measurement. Per cycle a pixel
costs two comparisons; the exact free depth is evaluated only in blocks holding a changed,
invalid or inconsistent pixel, and a camera whose blocks are all consistent reuses its
precomputed F(i) without any geometry work.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import manifold3d as m3
import numpy as np

from .camera import Camera
from .errors import FrameError, GeometryError
from .typed import ArrayBool, ArrayF32, ArrayF64

__all__ = [
    "CONSISTENT_BAND",
    "CameraStatic",
    "CameraFrameInfo",
    "free_depth",
    "block_min",
    "free_region_from_depth",
    "free_region_from_blocks",
    "check_manifold",
]


CONSISTENT_BAND = 1.5
"""Width of the static consistent band in depth tolerances (1.5 tau = 4.5 sigma at 3 sigma)."""


def check_manifold(m: m3.Manifold, what: str) -> m3.Manifold:
    """Return ``m`` if manifold3d reports no error, else raise :class:`GeometryError`."""
    status = m.status()
    if status != m3.Error.NoError:
        raise GeometryError(f"{what}: manifold3d status {status.name}")
    return m


def _tau_inverse_band(
    camera: Camera, reference: ArrayF64, width: float = 1.0
) -> tuple[ArrayF64, ArrayF64]:
    """Per-pixel band ``[T, U]`` around reference depth ``B`` (+inf where no hit).

    ``T = h^-1(B)`` with ``h(D) = D + width * tau(D)`` (increasing); with ``width = 1``,
    ``D < T`` iff ``D < B - tau(D)``, the SPEC's "changed" test. ``U = min(B + width *
    tau(B), far)``.
    """
    a = width * camera.tolerance_sigmas * camera.noise  # width * tau = max(a D^2, .. t_min)
    t_min = width * camera.tolerance_min
    B = reference
    cand_lin = B - t_min
    with np.errstate(invalid="ignore", over="ignore"):
        if a > 0:
            cand_quad = (np.sqrt(1.0 + 4.0 * a * B) - 1.0) / (2.0 * a)
        else:
            cand_quad = B
    T = np.minimum(cand_lin, cand_quad)
    U = np.minimum(B + width * camera.tau(np.minimum(B, camera.far)), camera.far)
    U = np.where(np.isinf(B), camera.far, U)
    return T, U


def free_depth(camera: Camera, depth: ArrayF64, reference: ArrayF64) -> ArrayF64:
    """Exact free depth per pixel [m] (SPEC section 2), float64 (H, W).

    Args:
        camera: The camera (range, noise model, kind).
        depth: Measured z-depth D [m]: 0/NaN unknown, -inf too close, +inf no return.
        reference: Reference z-depth B [m] of the empty cell, +inf where nothing is hit.

    Returns:
        f(p) [m]; ``near`` means nothing is free along the pixel's ray. Values are capped
        at ``far``.
    """
    D = np.asarray(depth, dtype=np.float64)
    B = np.asarray(reference, dtype=np.float64)
    near, far = camera.near, camera.far
    no_return = np.isposinf(D)
    valid = np.isfinite(D) & (D >= near) & (D <= far)
    D_eff = np.where(no_return, far, D)  # REP 117: +inf frees up to the rated range
    usable = valid | no_return
    B_eff = np.minimum(B, far)
    if camera.kind == "color":
        T, _ = _tau_inverse_band(camera, B_eff)  # beyond the range, +inf reads unchanged
        changed = D_eff < T
        f = np.where(usable & ~changed, B_eff - camera.tau(B_eff), near)
    else:
        f = np.where(usable, np.minimum(D_eff, B_eff) - camera.tau(D_eff), near)
    return np.clip(f, near, far)


def block_min(values: ArrayF64, block: int, fill: float = np.inf) -> ArrayF64:
    """Minimum over ``block`` x ``block`` tiles of an (H, W) array -> (ceil(H/b), ceil(W/b))."""
    H, W = values.shape
    Hb, Wb = -(-H // block), -(-W // block)
    if Hb * block != H or Wb * block != W:
        padded = np.full((Hb * block, Wb * block), fill, dtype=values.dtype)
        padded[:H, :W] = values
        values = padded
    return values.reshape(Hb, block, Wb, block).min(axis=(1, 3))


def _heightfield_mesh(
    camera: Camera, w_blocks: ArrayF64, block: int
) -> tuple[ArrayF64, np.ndarray]:
    """Vertices (image space) and triangles of the free solid above the surface ``w_blocks``.

    The solid lies between ``w_top = w_near - 1`` (beyond the frustum; trimmed later) and a
    piecewise-linear surface whose corner values are the minimum of the adjacent blocks.
    """
    H, W = camera.shape
    Hb, Wb = w_blocks.shape
    g = np.full((Hb + 2, Wb + 2), np.inf)
    g[1:-1, 1:-1] = w_blocks
    corners = np.minimum(np.minimum(g[:-1, :-1], g[1:, :-1]), np.minimum(g[:-1, 1:], g[1:, 1:]))
    us = np.clip(np.arange(Wb + 1) * block - 0.5, -0.5, W - 0.5)
    vs = np.clip(np.arange(Hb + 1) * block - 0.5, -0.5, H - 0.5)
    uu, vv = np.meshgrid(us, vs)
    n = (Hb + 1) * (Wb + 1)
    w_top = -1.0 / camera.near - 1.0
    verts = np.empty((2 * n, 3))
    verts[:n, 0] = verts[n:, 0] = uu.ravel()
    verts[:n, 1] = verts[n:, 1] = vv.ravel()
    verts[:n, 2] = corners.ravel()
    verts[n:, 2] = w_top
    idx = np.arange(n).reshape(Hb + 1, Wb + 1)
    a = idx[:-1, :-1].ravel()
    b = idx[:-1, 1:].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[1:, :-1].ravel()
    # The surface bounds the solid from +w (outward normal +w); the top cap from -w.
    bottom = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    top = np.concatenate([np.column_stack([a, c, b]), np.column_stack([a, d, c])]) + n
    ring = np.concatenate([idx[0, :-1], idx[:-1, -1], idx[-1, :0:-1], idx[:0:-1, 0]])
    nxt = np.roll(ring, -1)
    walls = np.concatenate(
        [np.column_stack([ring, nxt + n, nxt]), np.column_stack([ring, ring + n, nxt + n])]
    )
    tris = np.concatenate([bottom, top, walls]).astype(np.uint32)
    return verts, tris


def free_region_from_blocks(camera: Camera, free_blocks: ArrayF64, block: int) -> m3.Manifold:
    """World-frame target-free region F(i) from per-block free depth [m].

    Args:
        camera: The camera.
        free_blocks: (ceil(H/block), ceil(W/block)) free depth per block [m], already the
            minimum over the block's pixels; ``<= near`` frees nothing, ``> far`` is cut.
        block: Block side in [px].

    Returns:
        F(i) in the world frame (possibly empty), a valid manifold.
    """
    near, far = camera.near, camera.far
    fb = np.minimum(np.asarray(free_blocks, dtype=np.float64), far)
    w_near = -1.0 / near
    frees = fb > near
    if not np.any(frees):
        return m3.Manifold()
    w = np.where(frees, -1.0 / np.where(frees, fb, 1.0), w_near)
    verts, tris = _heightfield_mesh(camera, w, block)
    solid = m3.Manifold(m3.Mesh64(vert_properties=verts, tri_verts=tris))
    check_manifold(solid, f"camera '{camera.name}' free region (image space)")
    solid = solid.trim_by_plane((0.0, 0.0, 1.0), w_near)
    world = solid.warp_batch(camera.image_to_world)
    return check_manifold(world, f"camera '{camera.name}' free region")


def free_region_from_depth(camera: Camera, free: ArrayF64, block: int = 1) -> m3.Manifold:
    """World-frame F(i) from a full-resolution free-depth image (H, W) [m]."""
    free = np.asarray(free, dtype=np.float64)
    if free.shape != camera.shape:
        raise FrameError(
            f"camera '{camera.name}': free depth shape {free.shape} != image shape {camera.shape}"
        )
    return free_region_from_blocks(camera, block_min(free, block), block)


@dataclass(frozen=True)
class CameraFrameInfo:
    """What one cycle saw in one camera's frame.

    Attributes:
        dirty_blocks: Number of blocks recomputed from the measurement.
        invalid_share: Share of pixels without a usable depth (0, NaN, -inf, out of range).
        far_side_share: Share of background pixels (finite reference) reading farther than
            the reference allows, the camera-moved indicator.
    """

    dirty_blocks: int
    invalid_share: float
    far_side_share: float


@dataclass(frozen=True, eq=False)
class CameraStatic:
    """Everything about one camera that does not change between cycles.

    Attributes:
        camera: The camera.
        reference: (H, W) reference depth B [m], +inf where no hit.
        block: Block side [px].
        lower: (H, W) per-pixel consistent band lower bound T [m].
        upper: (H, W) consistent band upper bound U [m].
        free_static_pixels: (H, W) free depth [m] valid for any consistent measurement.
        free_static_blocks: Per-block free depth [m] valid for any consistent measurement.
        free_static: F(i) of a fully consistent frame (world frame).
    """

    camera: Camera
    reference: ArrayF64
    block: int
    lower: ArrayF64 = field(init=False, repr=False)
    upper: ArrayF64 = field(init=False, repr=False)
    free_static_pixels: ArrayF64 = field(init=False, repr=False)
    free_static_blocks: ArrayF64 = field(init=False, repr=False)
    free_static: m3.Manifold = field(init=False, repr=False)
    _background: ArrayBool = field(init=False, repr=False)
    _beyond: ArrayBool = field(init=False, repr=False)
    _has_beyond: bool = field(init=False, repr=False)

    def __post_init__(self) -> None:
        cam = self.camera
        B = np.asarray(self.reference, dtype=np.float64)
        if B.shape != cam.shape:
            raise FrameError(
                f"camera '{cam.name}': reference shape {B.shape} != image shape {cam.shape}"
            )
        # The consistent band is an implementation device, wider than the SPEC's "changed"
        # test so that ordinary noise (out to about 4.5 sigma) keeps a block static: any
        # depth inside it frees at least f_static, so widening only costs tightness.
        # A colour camera's depth is binary (changed or not at 1 tau), so its band stays
        # exactly the SPEC's "unchanged" test.
        width = 1.0 if cam.kind == "color" else CONSISTENT_BAND
        T, U = _tau_inverse_band(cam, B, width)
        in_range = np.isfinite(B) & (B <= cam.far)
        with np.errstate(invalid="ignore"):  # inf - inf where nothing is hit; masked below
            if cam.kind == "color":
                f_static = B - cam.tau(B)
            else:
                # min over D in [T, U] of min(D, B) - tau(D): at D = T or D = U.
                f_static = np.minimum(T - cam.tau(T), B - cam.tau(U))
        # Where the background lies beyond the rated range, drivers report 0, NaN, +inf (REP
        # 117 "no return") or a depth beyond the range: any of these is the static
        # expectation, freeing nothing (the exact path frees up to the range for +inf, so
        # this is the lower bound). Only an in-range depth there (something appeared) takes
        # the exact path.
        f_static = np.where(in_range, np.clip(f_static, cam.near, cam.far), cam.near)
        fsb = block_min(f_static, self.block)
        beyond = np.ascontiguousarray(~in_range)
        beyond.setflags(write=False)
        object.__setattr__(self, "_beyond", beyond)
        object.__setattr__(self, "_has_beyond", bool(beyond.any()))
        for name, value in (
            ("reference", B),
            ("lower", T),
            ("upper", U),
            ("free_static_pixels", f_static),
            ("free_static_blocks", fsb),
        ):
            value = np.ascontiguousarray(value)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "_background", in_range)
        object.__setattr__(self, "free_static", free_region_from_blocks(cam, fsb, self.block))

    def consistent_pixels(self, depth: ArrayF32 | ArrayF64) -> ArrayBool:
        """(H, W) pixels whose measurement is consistent with the static background: their
        free depth is at least ``free_static_pixels``."""
        D = depth
        consistent = (D >= self.lower) & (D <= self.upper)  # NaN compares False
        if self._has_beyond:
            cam = self.camera
            in_range = (D >= cam.near) & (D <= cam.far)
            consistent = np.where(self._beyond, ~in_range, consistent)
        return np.asarray(consistent, dtype=bool)

    def free_blocks(self, depth: ArrayF32 | ArrayF64) -> tuple[ArrayF64, ArrayBool, CameraFrameInfo]:
        """Per-block free depth of a measured frame, and which blocks were recomputed.

        Args:
            depth: (H, W) measured z-depth [m] (float32 or float64).

        Returns:
            (free depth per block [m], dirty block mask, frame info). A clean block keeps the
            precomputed value, which never exceeds the exact one.
        """
        cam, b = self.camera, self.block
        D = depth
        consistent = self.consistent_pixels(D)
        H, W = D.shape
        Hb, Wb = self.free_static_blocks.shape
        if Hb * b == H and Wb * b == W:
            dirty = np.asarray(~consistent.reshape(Hb, b, Wb, b).all(axis=(1, 3)), dtype=bool)
        else:
            dirty = np.asarray(block_min(consistent.astype(np.float64), b, 1.0) < 1.0, dtype=bool)
        if not dirty.any():
            return self.free_static_blocks, dirty, CameraFrameInfo(0, 0.0, 0.0)
        rows, cols = np.nonzero(dirty)
        fb = self.free_static_blocks.copy()
        # Exact free depth of the pixels of the dirty blocks only.
        vi = (rows[:, None] * b + np.arange(b)[None, :]).clip(0, H - 1)  # (n, b)
        ui = (cols[:, None] * b + np.arange(b)[None, :]).clip(0, W - 1)
        Dsub = np.asarray(D, dtype=np.float64)[vi[:, :, None], ui[:, None, :]]
        Bsub = self.reference[vi[:, :, None], ui[:, None, :]]
        f = free_depth(cam, Dsub, Bsub)
        fb[rows, cols] = np.minimum(f.min(axis=(1, 2)), fb[rows, cols])
        # Frame statistics for fault detection (cheap: on the inconsistent pixels only).
        bad = ~consistent
        Dbad = D[bad]
        usable = np.isposinf(Dbad) | ((Dbad >= cam.near) & (Dbad <= cam.far))
        invalid_share = float(np.count_nonzero(~usable)) / D.size
        far_side = np.count_nonzero((Dbad > self.upper[bad]) & np.isfinite(Dbad) & self._background[bad])
        bg = max(int(np.count_nonzero(self._background)), 1)
        info = CameraFrameInfo(int(rows.size), invalid_share, float(far_side) / bg)
        return fb, dirty, info

    def free_region(self, depth: ArrayF32 | ArrayF64) -> tuple[m3.Manifold, CameraFrameInfo]:
        """F(i) of a measured frame (world frame) and the frame info."""
        fb, dirty, info = self.free_blocks(depth)
        if not dirty.any():
            return self.free_static, info
        return free_region_from_blocks(self.camera, fb, self.block), info
