"""Per-camera free depth and free regions F(i): golden values, conservativeness, oracle."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import make_camera
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from polyhull.engine.pixels import (
    PixelBuffers,
    _packed_band,
    build_pyramid,
    classify_frame,
    prepare_static,
    pyramid_layout,
    small_gap_pixels,
    tile_segments,
    update_pyramid,
)
from polyhull.engine.static_model import StaticCamera
from polyhull.regions import (
    _pixel_corner_min,
    block_min,
    conservative_surface,
    free_depth,
    free_region_from_depth,
)


def _mesh(m) -> trimesh.Trimesh:  # noqa: ANN001 - manifold3d Manifold
    mesh = m.to_mesh64()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def test_free_depth_golden_depth_camera() -> None:
    cam = make_camera(width=8, height=1, near=0.3, far=6.0, noise=0.003)
    B = np.array([[3.0, 3.0, 3.0, 3.0, 3.0, 3.0, np.inf, 3.0]])
    D = np.array([[2.0, 4.0, 0.0, np.nan, -np.inf, np.inf, np.inf, 7.0]])
    f = free_depth(cam, D, B)
    tau = lambda z: max(3 * 0.003 * z * z, 0.01)  # noqa: E731
    expected = [
        2.0 - tau(2.0),  # valid, nearer than the background
        3.0 - tau(4.0),  # valid, beyond the background: min(D, B) - tau(D)
        0.3,  # 0: unknown -> near
        0.3,  # NaN -> near
        0.3,  # -inf: too close -> near
        3.0 - tau(6.0),  # +inf: no return -> min(far, B) - tau(far)
        6.0 - tau(6.0),  # +inf, no background -> far - tau(far)
        0.3,  # beyond the rated range -> near
    ]
    np.testing.assert_allclose(f[0], expected, rtol=0, atol=1e-12)


def test_free_depth_below_near_is_near() -> None:
    cam = make_camera(width=2, height=1, near=0.3)
    f = free_depth(cam, np.array([[0.1, 0.31]]), np.array([[2.0, 2.0]]))
    assert f[0, 0] == 0.3
    assert f[0, 1] == 0.3  # 0.31 - 0.01 is clipped to near


def test_free_depth_golden_color_camera() -> None:
    cam = make_camera(width=3, height=1, kind="color", noise=0.003)
    B = np.array([[3.0, 3.0, 3.0]])
    tau_b = max(3 * 0.003 * 9.0, 0.01)
    D = np.array([[2.0, 3.0, 0.0]])  # changed, unchanged, unknown
    f = free_depth(cam, D, B)
    np.testing.assert_allclose(f[0], [0.3, 3.0 - tau_b, 0.3], atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(
    values=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=20), elements=st.floats(-10, 10)),
    block=st.integers(1, 7),
)
def test_block_min_against_loop(values: np.ndarray, block: int) -> None:
    got = block_min(values, block)
    H, W = values.shape
    for r in range(got.shape[0]):
        for c in range(got.shape[1]):
            assert got[r, c] == values[r * block : (r + 1) * block, c * block : (c + 1) * block].min()
    assert got.shape == (-(-H // block), -(-W // block))


def _reference(cam) -> np.ndarray:  # noqa: ANN001
    """A floor at z = 0 seen by ``cam`` plus a box-like step; +inf in one corner."""
    rays = cam.pixel_rays()
    R = cam.T_world_camera[:3, :3]
    dirs_w = rays @ R.T
    z0 = cam.center[2]
    B = -z0 / dirs_w[..., 2]  # z-depth along unit-z rays to the plane z = 0
    B = np.where(B > 0, B, np.inf)
    B[5:12, 10:20] -= 0.8  # a static object
    B[:3, :4] = np.inf  # no return
    B[-3:, -5:] = 7.5  # beyond the rated range
    return B


_SPECIAL = st.sampled_from([0.0, np.nan, np.inf, -np.inf, 0.1, 9.0])


def _classify(static: StaticCamera, D: np.ndarray, shadow: np.ndarray | None = None):  # noqa: ANN202
    cam = static.camera
    if shadow is None:
        shadow = np.full(cam.shape, np.inf, dtype=np.float32)
    return classify_frame(
        D, static.reference, static.lower, static.upper, static.free_static, shadow,
        near=cam.near, far=cam.far, tau_a=static.tau_a, tau_min=cam.tolerance_min,
        is_color=cam.kind == "color", edge=static.edge,
    )


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    kind=st.sampled_from(["depth", "color"]),
    special=st.lists(_SPECIAL, min_size=0, max_size=30),
    spread=st.floats(0.0, 1.0),
)
def test_engine_free_depth_never_above_exact(seed: int, kind: str, special: list[float], spread: float) -> None:
    """The pixel classes' free depth is at most the exact free depth (``regions.free_depth``),
    every pixel, whatever the frame (noise, people, REP 117 special values); a static pixel
    frees the static free depth, which is itself at most the exact one."""
    cam = make_camera(width=40, height=30, kind=kind)
    B = _reference(cam)
    static = StaticCamera.build(cam, B, 2)
    rng = np.random.default_rng(seed)
    D = np.where(np.isfinite(B), B, 3.0) + rng.normal(0.0, 0.01 + 0.3 * spread * rng.uniform(), size=B.shape)
    keep = rng.uniform(size=B.shape) < 0.8
    D = np.where(keep, np.where(np.isfinite(B), B + rng.normal(0, 0.003, B.shape), np.inf), D)
    idx = rng.integers(0, B.size, size=len(special))
    D.ravel()[idx] = special
    D = D.astype(np.float32)
    cls = _classify(static, D)
    exact = free_depth(cam, D.astype(np.float64), B)
    assert np.all(cls.free <= exact + 1e-6), float(np.max(cls.free - exact))
    # clamped to the static free depth, except a static edge pixel reading in its band,
    # which frees its own exact free depth (at least the static one)
    in_band = (D >= static.lower) & (D <= static.upper) & (D >= cam.near) & (D <= cam.far)
    own = static.edge & in_band
    assert np.all((cls.free <= static.free_static) | own)
    assert np.all(cls.free[own] >= static.free_static[own])
    # every pixel either frees its static free depth or has a segment up to it
    seg = cls.free < cls.end
    assert np.all(seg | (cls.free >= static.free_static))
    # the tile flags (8 px) are exactly the tiles with a segment pixel; the passes that
    # visit only those tiles give what visiting every tile gives
    pad = np.zeros((32, 40), dtype=bool)
    pad[:30] = seg
    np.testing.assert_array_equal(cls.tiles, pad.reshape(4, 8, 5, 8).any(axis=(1, 3)))
    covered = np.zeros(cam.shape, dtype=bool)
    covered[::7, ::5] = True
    np.testing.assert_array_equal(
        tile_segments(cls.free, cls.end, covered, 8, tiles=cls.tiles), tile_segments(cls.free, cls.end, covered, 8)
    )
    invalid = ~np.isfinite(D) | (D <= 0)
    gaps = (cls.free, cls.end, invalid, static.free_static, cam.near, 30.0, 30.0, 0.5)
    got, full = small_gap_pixels(*gaps, tiles=(8, cls.tiles)), small_gap_pixels(*gaps)
    rows = [sorted(zip(map(tuple, vu), to.tolist(), strict=True)) for vu, to in (got, full)]
    assert rows[0] == rows[1]


def test_clean_frame_has_no_segment_and_a_person_has_one() -> None:
    cam = make_camera(width=40, height=30)
    B = _reference(cam)
    static = StaticCamera.build(cam, B, 2)
    D = np.where(np.isfinite(B) & (B <= cam.far), B, 0.0).astype(np.float32)
    assert _classify(static, D).unexplained == 0
    D2 = D.copy()
    D2[10:14, 20:24] = 1.0  # something appeared
    cls = _classify(static, D2)
    assert cls.unexplained == 16
    assert np.all(cls.free[10:14, 20:24] < cls.end[10:14, 20:24])


def test_robot_shadow_explains_pixels_behind_its_start() -> None:
    """A reading at or behind the robot's shadow start has no segment (explained by the
    robot); one well in front of it has a segment that ends at the shadow start."""
    cam = make_camera(width=40, height=30)
    B = np.full(cam.shape, 4.0)
    static = StaticCamera.build(cam, B, 2)
    shadow = np.full(cam.shape, np.inf, dtype=np.float32)
    shadow[5:15, 5:15] = 2.0
    D = np.full(cam.shape, 4.0, dtype=np.float32)
    D[5:10, 5:15] = 2.2  # the robot's surface, behind the shadow start
    D[10:15, 5:15] = 1.0  # a hand in front of the robot
    cls = _classify(static, D, shadow)
    assert not np.any(cls.free[5:10, 5:15] < cls.end[5:10, 5:15])
    assert np.all(cls.free[10:15, 5:15] < cls.end[10:15, 5:15])
    assert np.all(cls.end[10:15, 5:15] == np.float32(2.0))
    # told the rectangle outside which the shadow is +inf, the classes are the same
    cam_ = static.camera
    inrect = classify_frame(
        D, static.reference, static.lower, static.upper, static.free_static, shadow,
        near=cam_.near, far=cam_.far, tau_a=static.tau_a, tau_min=cam_.tolerance_min, is_color=False,
        shadow_rect=(5, 14, 5, 14),
    )
    for name in ("free", "end", "invalid", "tiles"):
        np.testing.assert_array_equal(getattr(inrect, name), getattr(cls, name))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(["depth", "color"]), cycles=st.integers(2, 5))
def test_reused_buffers_and_pyramids_equal_fresh_ones(seed: int, kind: str, cycles: int) -> None:
    """Classifying a sequence of frames into one camera's reused buffers (restored only
    where the last frame changed them), with the pyramids updated only in the changed
    blocks, gives what fresh buffers and a full pyramid build give, frame after frame."""
    cam = make_camera(width=37, height=29, kind=kind)  # not a multiple of the 8 px blocks
    B = _reference(cam)
    static = StaticCamera.build(cam, B, 2)
    prep = prepare_static(static.lower, static.upper, static.free_static, cam.near)
    H, W = cam.shape
    reused = PixelBuffers(prep, static.free_static)
    offsets, shapes = pyramid_layout(H, W)
    size = int((shapes[1:, 0] * shapes[1:, 1]).sum())
    o = offsets.copy()
    mins, maxs = np.empty(size, np.float32), np.empty(size, np.float32)
    build_pyramid(reused.free, mins, maxs, o, shapes)
    rng = np.random.default_rng(seed)
    for _ in range(cycles):
        D = np.where(np.isfinite(B), B, 3.0) + rng.normal(0.0, 0.003, size=B.shape)
        v0, u0 = rng.integers(0, H - 4), rng.integers(0, W - 4)
        D[v0 : v0 + rng.integers(1, 12), u0 : u0 + rng.integers(1, 12)] = rng.uniform(0.5, 3.0)  # a target
        D.ravel()[rng.integers(0, B.size, size=rng.integers(0, 20))] = rng.choice([0.0, np.nan, np.inf, -np.inf, 9.0])
        D = D.astype(np.float32)
        shadow = np.full(cam.shape, np.inf, dtype=np.float32)
        rect = None
        if rng.uniform() < 0.7:
            a, b = sorted(rng.integers(0, W, size=2))
            c, d = sorted(rng.integers(0, H, size=2))
            shadow[c : d + 1, a : b + 1] = rng.uniform(0.5, 4.0, size=(d - c + 1, b - a + 1))
            rect = (int(a), int(b), int(c), int(d))
        args = (D, static.reference, static.lower, static.upper, static.free_static, shadow)
        kw = dict(near=cam.near, far=cam.far, tau_a=static.tau_a, tau_min=cam.tolerance_min, is_color=kind == "color")
        got = classify_frame(*args, **kw, shadow_rect=rect, static=prep, buffers=reused)
        fresh = classify_frame(*args, **kw)
        for name in ("free", "end", "invalid", "tiles"):
            np.testing.assert_array_equal(getattr(got, name), getattr(fresh, name), err_msg=name)
        assert (got.unexplained, got.invalid_share, got.far_side_share) == (
            fresh.unexplained, fresh.invalid_share, fresh.far_side_share
        )
        update_pyramid(reused.free, mins, maxs, o, shapes, reused.changed)
        fmins, fmaxs = np.empty(size, np.float32), np.empty(size, np.float32)
        build_pyramid(fresh.free, fmins, fmaxs, o, shapes)
        np.testing.assert_array_equal(mins, fmins)
        np.testing.assert_array_equal(maxs, fmaxs)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), block=st.sampled_from([1, 2, 3, 4, 8]), H=st.integers(5, 30), W=st.integers(5, 30))
def test_conservative_surface_never_behind_a_pixel(seed: int, block: int, H: int, W: int) -> None:
    """The surface, interpolated at every pixel corner, is at or before the corner's
    smallest pixel value (so over every pixel's whole footprint, being linear there)."""
    rng = np.random.default_rng(seed)
    w = -1.0 / (2.0 + rng.normal(0, 0.3, size=(H, W)).cumsum(axis=1) * 0.1)
    w[rng.uniform(size=(H, W)) < 0.05] = -1.0 / 0.3  # jumps to "nothing free"
    S = conservative_surface(w, block)
    Hb, Wb = -(-H // block), -(-W // block)
    wp = np.pad(w, ((0, Hb * block - H), (0, Wb * block - W)), mode="edge")
    wc = _pixel_corner_min(wp)
    ys, xs = np.mgrid[0 : Hb * block + 1, 0 : Wb * block + 1]
    i = np.minimum(xs // block, Wb - 1)
    j = np.minimum(ys // block, Hb - 1)
    fx = (xs - i * block) / block
    fy = (ys - j * block) / block
    Ga, Gb, Gc, Gd = S[j, i], S[j, i + 1], S[j + 1, i + 1], S[j + 1, i]
    interp = np.where(fx >= fy, Ga + (Gb - Ga) * fx + (Gc - Gb) * fy, Ga + (Gc - Gd) * fx + (Gd - Ga) * fy)
    assert np.all(interp <= wc + 1e-9), float(np.max(interp - wc))


@pytest.mark.parametrize("f", [0.8, 2.0, 5.5])
def test_constant_free_depth_volume_is_frustum_slab(f: float) -> None:
    cam = make_camera(width=64, height=48, near=0.3, far=6.0)
    k = cam.intrinsics
    region = free_region_from_depth(cam, np.full(cam.shape, f), 8)
    expected = k.width * k.height / (k.fx * k.fy) * (f**3 - cam.near**3) / 3.0
    assert region.volume() == pytest.approx(expected, rel=1e-9)
    # nothing free -> empty
    assert free_region_from_depth(cam, np.full(cam.shape, cam.near), 8).is_empty()


def test_free_depth_beyond_far_is_cut() -> None:
    cam = make_camera(width=16, height=16, far=6.0)
    k = cam.intrinsics
    region = free_region_from_depth(cam, np.full(cam.shape, 50.0), 8)
    expected = k.width * k.height / (k.fx * k.fy) * (cam.far**3 - cam.near**3) / 3.0
    assert region.volume() == pytest.approx(expected, rel=1e-9)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), block=st.sampled_from([1, 3, 8]))
def test_free_region_point_oracle(seed: int, block: int) -> None:
    """F(i) never claims free what the exact per-pixel free depth does not."""
    cam = make_camera(width=40, height=30, near=0.3, far=6.0)
    rng = np.random.default_rng(seed)
    # A smooth background with blobs of near depth and invalid pixels.
    vv, uu = np.mgrid[0 : cam.shape[0], 0 : cam.shape[1]]
    phase = rng.uniform(0, 2 * np.pi, size=2)
    D = rng.uniform(2.0, 4.5) + 0.5 * np.sin(uu / 5.0 + phase[0]) * np.cos(vv / 7.0 + phase[1])
    for _ in range(3):
        r, c = rng.integers(0, 30), rng.integers(0, 40)
        D[r : r + 6, c : c + 6] = rng.uniform(0.5, 2.0)
    D[rng.uniform(size=D.shape) < 0.005] = 0.0
    B = np.full(cam.shape, 5.0)
    f_exact = free_depth(cam, D, B)
    region = free_region_from_depth(cam, f_exact, block)
    assert not region.is_empty()
    mesh = _mesh(region)
    # Sample points uniformly in the frustum's image-space box (u, v, z).
    n = 6000
    uv = rng.uniform([-0.5, -0.5], [cam.intrinsics.width - 0.5, cam.intrinsics.height - 0.5], size=(n, 2))
    z = rng.uniform(cam.near, cam.far, size=n)
    pts = cam.unproject(uv, z)
    inside = mesh.contains(pts)
    assert inside.sum() > 20  # the oracle must test something
    # The point's pixel: nearest centre (boundary points may go to either side).
    u_p, _ = cam.project(pts)
    ui = np.clip(np.floor(u_p[:, 0] + 0.5).astype(int), 0, cam.intrinsics.width - 1)
    vi = np.clip(np.floor(u_p[:, 1] + 0.5).astype(int), 0, cam.intrinsics.height - 1)
    z_ok = z <= f_exact[vi, ui] + 1e-6
    misses = inside & ~z_ok
    assert not misses.any(), f"{misses.sum()} points claimed free beyond the exact free depth"
    # Loose tightness for block 1 (corners take the minimum of their four pixels, so each
    # invalid pixel removes its neighbourhood): at least half of the free points are kept.
    if block == 1:
        assert inside.sum() >= 0.5 * z_ok.sum()


_BOUND = st.one_of(st.floats(0.0, 80.0, width=32), st.sampled_from([np.inf, -np.inf, np.nan, 0.0, 65.534, 65.535, 65.536]))


@settings(max_examples=300, deadline=None)
@given(T=_BOUND, U=_BOUND, d=st.one_of(st.floats(-1.0, 90.0, width=32), st.sampled_from([np.inf, -np.inf, np.nan, 0.0])))
def test_packed_band_says_static_only_inside_the_band(T: float, U: float, d: float) -> None:
    """The packed millimetre band (the classification's first test) holds a reading only
    when the exact band [T, U] does (the other readings are tested exactly)."""
    band = _packed_band(np.array([[T]], np.float32), np.array([[U]], np.float32))[0, 0]
    tq, uq = np.float32(band & 0xFFFF), np.float32(band >> 16)
    dm = np.float32(1000.0) * np.float32(d)
    with np.errstate(invalid="ignore"):
        surely = bool(dm >= tq and (dm <= uq or uq == np.float32(65535.0)))
        exact = bool(np.float32(d) >= np.float32(T) and np.float32(d) <= np.float32(U))
    assert not surely or exact


def test_a_static_edge_pixel_frees_what_it_reads() -> None:
    """At a static depth edge the band is the neighbourhood's (flying pixels), so the static
    free depth is the nearer surface's; a reading in that band frees its own exact free
    depth: the farther surface's reading frees up to it, a flying pixel between the two
    frees up to itself, and neither is a change."""
    cam = make_camera(width=40, height=30)
    B = _reference(cam)
    static = StaticCamera.build(cam, B, 2)
    edge = static.edge
    # the object's outline (0.8 m in front of the background) and nothing else
    assert edge.any() and not edge[20:, :].any()
    D = np.where(np.isfinite(B) & (B <= cam.far), B, 0.0).astype(np.float32)
    cls = _classify(static, D)
    exact = free_depth(cam, D.astype(np.float64), B)
    assert cls.unexplained == 0
    np.testing.assert_allclose(cls.free[edge], exact[edge], rtol=0, atol=1e-5)
    far_side = edge & (B > static.reference.min() + 0.5)
    assert far_side.any() and np.all(cls.free[far_side] > static.free_static[far_side] + 0.5)
    # a flying pixel halfway between the object and the background behind it
    v, u = np.argwhere(far_side)[0]
    D2 = D.copy()
    D2[v, u] = B[v, u] - 0.4
    cls2 = _classify(static, D2)
    assert cls2.unexplained == 0
    assert static.free_static[v, u] < cls2.free[v, u] <= free_depth(cam, D2.astype(np.float64), B)[v, u]
    # without the edge pixels, the static free depth (the wedge behind the edge)
    plain = classify_frame(
        D, static.reference, static.lower, static.upper, static.free_static,
        np.full(cam.shape, np.inf, dtype=np.float32), near=cam.near, far=cam.far,
        tau_a=static.tau_a, tau_min=cam.tolerance_min, is_color=False,
    )
    np.testing.assert_array_equal(plain.free[edge], static.free_static[edge])
