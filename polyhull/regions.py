"""Free depth per pixel, and camera free regions F(i) as manifolds.

The free depth of pixel p is ``f(p) = min(D(p), B(p)) - tau(D(p))`` for a valid depth camera
pixel and ``near`` (nothing free) for an invalid one; for a colour camera a changed pixel
frees nothing and an unchanged one frees up to ``B(p) - tau(B(p))``.

F(i) is built in the camera's inverse-depth image space ``(u, v, w = -1/z)`` as the solid
between the plane ``w = -1/near`` and a piecewise-linear surface over a grid of b x b pixel
blocks, then mapped to the world by the projective map of :class:`~polyhull.camera.Camera`,
which keeps faces planar. The surface never lies behind the free depth of any pixel it
spans (:func:`conservative_surface`): it interpolates the free depth at the block corners
and is lowered wherever the interpolation would pass behind a pixel, which costs almost
nothing on smooth surfaces (the floor, a table top) and a strip of up to one block along
depth edges.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
from numpy.lib.stride_tricks import as_strided

from .camera import Camera
from .errors import FrameError, GeometryError
from .typed import ArrayF64

__all__ = [
    "check_manifold",
    "consistent_band",
    "free_depth",
    "block_min",
    "conservative_surface",
    "free_region_from_surface",
    "free_region_from_depth",
]


def check_manifold(m: m3.Manifold, what: str) -> m3.Manifold:
    """Return ``m`` if manifold3d reports no error, else raise :class:`GeometryError`."""
    status = m.status()
    if status != m3.Error.NoError:
        raise GeometryError(f"{what}: manifold3d status {status.name}")
    return m


def consistent_band(
    camera: Camera, reference: ArrayF64, width: float = 1.0
) -> tuple[ArrayF64, ArrayF64]:
    """Per-pixel band ``[T, U]`` [m] of depths consistent with reference depth ``B``.

    ``T = h^-1(B)`` with ``h(D) = D + width * tau(D)`` (increasing), so with ``width = 1``
    ``D < T`` iff ``D < B - tau(D)``, the test of a changed pixel. ``U = min(B + width *
    tau(B), far)``; ``U = far`` where nothing is hit (``B = +inf``).
    """
    a = width * camera.tolerance_sigmas * camera.noise  # width * tau = max(a D^2, .. t_min)
    t_min = width * camera.tolerance_min
    B = np.asarray(reference, dtype=np.float64)
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
    """Exact free depth per pixel [m] (as defined in the module docstring), float64 (H, W).

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
        T, _ = consistent_band(camera, B_eff)
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


def _pixel_corner_min(w: ArrayF64) -> ArrayF64:
    """(H + 1, W + 1) minimum of ``w`` over the up to four pixels around each pixel corner."""
    H, W = w.shape
    g = np.full((H + 2, W + 2), np.inf)
    g[1:-1, 1:-1] = w
    return np.minimum(np.minimum(g[:-1, :-1], g[1:, :-1]), np.minimum(g[:-1, 1:], g[1:, 1:]))


def conservative_surface(w_pixels: ArrayF64, block: int) -> ArrayF64:
    """Corner values of a piecewise-linear surface that never passes behind a pixel.

    The surface is linear on the two triangles of every ``block`` x ``block`` pixel block
    (split along the diagonal from its top-left to its bottom-right corner). It starts at
    the pixel-corner minimum of ``w_pixels`` at every block corner, then every triangle
    whose interpolation exceeds the pixel-corner minimum anywhere inside it lowers its
    three corners by that excess. Lowering all three corners of a triangle by ``e`` lowers
    the interpolation by exactly ``e`` everywhere on it, and a pixel square inside a block
    is cut by the diagonal only through pixel corners, so checking the pixel corners is
    exact: the surface is at or in front of every pixel's value over the pixel's whole
    footprint.

    Args:
        w_pixels: (H, W) value per pixel, larger = farther (inverse depth ``-1/z``).
        block: Block side [px]; H and W are padded up to multiples of it by repeating the
            last row and column (the caller clips the solid to the image).

    Returns:
        (ceil(H/b) + 1, ceil(W/b) + 1) surface values at the block corners.
    """
    w = np.asarray(w_pixels, dtype=np.float64)
    H, W = w.shape
    b = int(block)
    Hb, Wb = -(-H // b), -(-W // b)
    if Hb * b != H or Wb * b != W:
        w = np.pad(w, ((0, Hb * b - H), (0, Wb * b - W)), mode="edge")
    wc = _pixel_corner_min(w)  # (Hb*b + 1, Wb*b + 1)
    G = wc[::b, ::b].copy()  # (Hb + 1, Wb + 1)
    s0, s1 = wc.strides
    sub = as_strided(wc, shape=(Hb, Wb, b + 1, b + 1), strides=(b * s0, b * s1, s0, s1))
    t = np.arange(b + 1, dtype=np.float64) / b
    y, x = t[:, None], t[None, :]  # local row (v) and column (u) fractions
    Ga = G[:-1, :-1, None, None]
    Gb = G[:-1, 1:, None, None]
    Gc = G[1:, 1:, None, None]
    Gd = G[1:, :-1, None, None]
    with np.errstate(invalid="ignore"):
        upper = Ga + (Gb - Ga) * x + (Gc - Gb) * y  # triangle (a, b, c): x >= y
        lower = Ga + (Gc - Gd) * x + (Gd - Ga) * y  # triangle (a, c, d): y >= x
        in_upper = np.broadcast_to(x >= y, (b + 1, b + 1))
        in_lower = np.broadcast_to(y >= x, (b + 1, b + 1))
        e_up = np.where(in_upper, upper - sub, -np.inf).max(axis=(2, 3))
        e_lo = np.where(in_lower, lower - sub, -np.inf).max(axis=(2, 3))
    e_up = np.maximum(np.nan_to_num(e_up, nan=np.inf, posinf=np.inf), 0.0)
    e_lo = np.maximum(np.nan_to_num(e_lo, nan=np.inf, posinf=np.inf), 0.0)
    drop = np.zeros_like(G)
    e_both = np.maximum(e_up, e_lo)  # corners a and c belong to both triangles
    np.maximum(drop[:-1, :-1], e_both, out=drop[:-1, :-1])
    np.maximum(drop[1:, 1:], e_both, out=drop[1:, 1:])
    np.maximum(drop[:-1, 1:], e_up, out=drop[:-1, 1:])
    np.maximum(drop[1:, :-1], e_lo, out=drop[1:, :-1])
    return G - drop


def _heightfield_mesh(
    camera: Camera, corners: ArrayF64, block: int, w_top: float
) -> tuple[ArrayF64, np.ndarray]:
    """Vertices (image space) and triangles of the solid between ``w_top`` and the surface."""
    Hb1, Wb1 = corners.shape
    us = np.arange(Wb1) * float(block) - 0.5
    vs = np.arange(Hb1) * float(block) - 0.5
    uu, vv = np.meshgrid(us, vs)
    n = Hb1 * Wb1
    verts = np.empty((2 * n, 3))
    verts[:n, 0] = verts[n:, 0] = uu.ravel()
    verts[:n, 1] = verts[n:, 1] = vv.ravel()
    verts[:n, 2] = corners.ravel()
    verts[n:, 2] = w_top
    idx = np.arange(n).reshape(Hb1, Wb1)
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


def free_region_from_surface(camera: Camera, corners_w: ArrayF64, block: int) -> m3.Manifold:
    """World-frame F(i) under a surface of :func:`conservative_surface` corner values.

    The solid lies in front of the surface, behind ``near`` and inside the image rectangle
    (the grid may overhang the image by less than a block; that part is cut off).
    """
    near, far = camera.near, camera.far
    w_near, w_far = -1.0 / near, -1.0 / far
    corners = np.minimum(np.asarray(corners_w, dtype=np.float64), w_far)
    if not np.any(corners > w_near):
        return m3.Manifold()
    # Corners lowered before near stay where they are (raising one would push the surface
    # behind a pixel); the top cap lies before all of them.
    w_top = min(float(corners.min()), w_near) - 1.0
    verts, tris = _heightfield_mesh(camera, corners, block, w_top)
    solid = m3.Manifold(m3.Mesh64(vert_properties=verts, tri_verts=tris))
    check_manifold(solid, f"camera '{camera.name}' free region (image space)")
    H, W = camera.shape
    solid = solid.trim_by_plane((0.0, 0.0, 1.0), w_near)
    solid = solid.trim_by_plane((-1.0, 0.0, 0.0), -(W - 0.5))
    solid = solid.trim_by_plane((0.0, -1.0, 0.0), -(H - 0.5))
    if solid.is_empty():
        return solid
    world = solid.warp_batch(camera.image_to_world)
    return check_manifold(world, f"camera '{camera.name}' free region")


def free_region_from_depth(camera: Camera, free: ArrayF64, block: int = 1) -> m3.Manifold:
    """World-frame F(i) from a full-resolution free-depth image (H, W) [m].

    Pixels at or before ``near`` free nothing; depth beyond ``far`` is cut at ``far``.
    """
    free = np.asarray(free, dtype=np.float64)
    if free.shape != camera.shape:
        raise FrameError(
            f"camera '{camera.name}': free depth shape {free.shape} != image shape {camera.shape}"
        )
    f = np.minimum(free, camera.far)
    w = np.where(f > camera.near, -1.0 / np.maximum(f, 1e-12), -1.0 / camera.near)
    return free_region_from_surface(camera, conservative_surface(w, block), block)
