"""The small_gaps rule frees only reading-less clusters walled in by readings of the static
scene or of the robot, and only where their rays are narrower than the detection capability
(synthetic images, exact expectations, and a ball oracle in front of a wall and in front of
the robot)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.pixels import only_marked_segments, small_gaps

H, W = 60, 80
F = 600.0  # focal length [px]
NEAR = 0.1
SIZE = 0.07  # detection capability [m]


def _scene(depth: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A static wall at ``depth``: every pixel free to its static free depth."""
    fs = np.full((H, W), depth - 0.1, dtype=np.float32)
    return fs.copy(), fs.copy(), np.zeros((H, W), dtype=bool), fs


def _drop(free, invalid, v0, v1, u0, u1):  # noqa: ANN001, ANN202
    free[v0:v1, u0:u1] = NEAR
    invalid[v0:v1, u0:u1] = True


def _gaps(free, end, invalid, fs, size=SIZE):  # noqa: ANN001, ANN202
    """The pixels the rule frees (wholly or in part)."""
    return small_gaps(free, end, invalid, fs, NEAR, F, F, size) > free


def _cut(ext_u: int, ext_v: int, size: float = SIZE) -> np.float32:
    """Where a cluster of ``ext_u`` x ``ext_v`` px too wide at its far end is freed to: its
    rays (with a pixel either side) widen to ``size`` at zcut; ``zcut - size``, as float32."""
    lim = size * min(F / (ext_u + 2), F / (ext_v + 2)) - size
    f = np.float32(lim)
    return f if float(f) <= lim else np.nextafter(f, np.float32(0))


def test_a_dropout_patch_in_the_static_scene_is_a_small_gap() -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 24, 30, 34)  # 4 x 4 px: (4 + 2) * 3.9 / 600 = 0.039 m
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, SIZE)
    assert (new > free).sum() == 16 and (new[20:24, 30:34] == end[20:24, 30:34]).all()


def test_a_patch_wider_than_the_detection_capability_is_freed_where_its_rays_are_narrower() -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 24, 30, 41)  # 11 px: (11 + 2) * 3.9 / 600 = 0.085 m > 0.07
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, SIZE)
    # the rays are 0.07 m wide at 0.07 * 600 / 13 = 3.23 m: freed to 3.16 m, the rest stays
    assert (new > free).sum() == 44
    assert (new[20:24, 30:41] == _cut(11, 4)).all() and 3.16 < _cut(11, 4) < 3.161
    assert (new[20:24, 30:41] < end[20:24, 30:41]).all()
    # the same patch is small for a coarser declared capability: freed whole
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, 0.1)
    assert (new[20:24, 30:41] == end[20:24, 30:41]).all()
    # a capability so fine that zcut - size lies before the patch's free depth frees nothing
    # (0.002 * 600 / 13 - 0.002 = 0.090 m < near, 0.1 m)
    assert not _gaps(free, end, invalid, fs, size=0.002).any()
    assert (small_gaps(free, end, invalid, fs, NEAR, F, F, 0.01)[20:24, 30:41] == _cut(11, 4, 0.01)).all()


def test_valid_readings_are_never_filled() -> None:
    """A hand seen through a gap: valid readings in front of the wall."""
    free, end, invalid, fs = _scene()
    free[20:22, 30:32] = 1.5
    assert not _gaps(free, end, invalid, fs).any()


def test_a_patch_walled_in_by_the_robot_is_a_small_gap() -> None:
    """A dropout patch on the robot's image: every pixel around it reads the robot (free to
    its shadow start, no segment), and the patch's segments end at the shadow start."""
    free, end, invalid, fs = _scene()
    end[17:27, 27:37] = free[17:27, 27:37] = 2.0  # the robot's surface, explained
    _drop(free, invalid, 20, 24, 30, 34)
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, SIZE)
    assert (new > free).sum() == 16 and (new[20:24, 30:34] == 2.0).all()
    # the segments' far end sets the width: at the wall's depth the same patch is too wide,
    # and is freed only to where its rays are narrower than 0.035 m (3.5 m, less 0.035)
    end[20:24, 30:34] = fs[20:24, 30:34]
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, 0.035)
    assert (new[20:24, 30:34] == _cut(4, 4, 0.035)).all() and _cut(4, 4, 0.035) < end[20, 30]
    new = small_gaps(free, end, invalid, fs, NEAR, F, F, 0.04)
    assert (new[20:24, 30:34] == end[20:24, 30:34]).all()


@pytest.mark.parametrize("where", ["person", "person at the robot", "robot colour", "blind", "border"])
def test_a_patch_next_to_anything_but_the_static_scene_or_the_robot_stays(where: str) -> None:
    free, end, invalid, fs = _scene()
    _drop(free, invalid, 20, 23, 30, 33)
    if where == "person":
        free[23, 31] = 1.5  # a valid changed reading touching the patch
    elif where == "person at the robot":
        end[17:26, 27:36] = free[17:26, 27:36] = 2.0  # the robot's surface around the patch
        _drop(free, invalid, 20, 23, 30, 33)
        free[19, 29] = 1.5  # a reading in front of the robot: a segment (a hand)
    elif where == "robot colour":
        # a colour camera's pixel the robot changes frees nothing (near, rounded toward the camera)
        end[19, 29] = free[19, 29] = np.nextafter(np.float32(NEAR), np.float32(0))
    elif where == "blind":
        fs[20, 33] = free[20, 33] = end[20, 33] = 0.5 * NEAR  # sees nothing even in the empty cell
    else:
        _drop(free, invalid, 0, 3, 30, 33)
        free[20:23, 30:33] = fs[20:23, 30:33]
        invalid[20:23, 30:33] = False
    assert not _gaps(free, end, invalid, fs).any()


def _reference_small_gaps(free, end, invalid, fs, near, fx, fy, size):  # noqa: ANN001, ANN202
    """The rule written plainly with scipy.ndimage.label (the oracle of the compiled pass):
    the free depth after it."""
    from scipy import ndimage

    mask = (free < end) & invalid
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    out = free.copy()
    H, W = mask.shape
    for k in range(1, n + 1):
        vs, us = np.nonzero(labels == k)
        ring = ndimage.binary_dilation(labels == k, structure=np.ones((3, 3), dtype=bool)) & (labels != k)
        touches_border = vs.min() == 0 or us.min() == 0 or vs.max() == H - 1 or us.max() == W - 1
        f64 = fs[ring].astype(np.float64)  # compared in float64, as the compiled pass does
        static = (f64 > near) & (free[ring] >= fs[ring])
        robot = ~invalid[ring] & (free[ring].astype(np.float64) > near) & (free[ring] >= end[ring])
        closed = not touches_border and (static | robot).all()
        if not closed:
            continue
        zmax = float(end[vs, us].astype(np.float64).max())
        if (np.ptp(us) + 3) * zmax / fx < size and (np.ptp(vs) + 3) * zmax / fy < size:
            out[vs, us] = end[vs, us]
            continue
        lim = size * min(fx / (np.ptp(us) + 3), fy / (np.ptp(vs) + 3)) - size
        f = np.float32(lim)
        f = f if float(f) <= lim else np.nextafter(f, np.float32(0))  # rounded toward the camera
        out[vs, us] = np.maximum(free[vs, us], np.minimum(end[vs, us], f))
    return out


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_small_gaps_match_the_plain_rule(seed: int) -> None:
    """The compiled cluster pass frees exactly what the rule written with ndimage frees."""
    rng = np.random.default_rng(seed)
    H, W = (int(x) for x in rng.integers(3, 30, size=2))
    fs = rng.uniform(0.5, 5, size=(H, W)).astype(np.float32)
    fs[rng.random((H, W)) < 0.05] = 0.3
    free = np.where(rng.random((H, W)) < 0.8, fs, fs * rng.uniform(0.5, 1, size=(H, W))).astype(np.float32)
    end = np.where(rng.random((H, W)) < 0.4, fs, free).astype(np.float32)
    invalid = rng.random((H, W)) < rng.uniform(0.05, 0.6)
    free = np.where(invalid & (rng.random((H, W)) < 0.7), np.float32(0.3), free).astype(np.float32)
    size = float(rng.uniform(0.05, 2.0))
    got = small_gaps(free, end, invalid, fs, 0.3, 30.0, 30.0, size)
    np.testing.assert_array_equal(got, _reference_small_gaps(free, end, invalid, fs, 0.3, 30.0, 30.0, size))


BALL_F = 40.0  # a coarse camera: a few pixels span the ball
BALL_H, BALL_W = 24, 24
BALL_C = (BALL_W - 1) / 2


def _rays() -> np.ndarray:
    """(H, W, 3) the pixel centres' rays, scaled to z-depth 1."""
    v, u = np.mgrid[0:BALL_H, 0:BALL_W].astype(np.float64)
    return np.stack([(u - BALL_C) / BALL_F, (v - BALL_C) / BALL_F, np.ones_like(u)], axis=-1)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.floats(0.1, 0.6),  # ball diameter [m] (the declared capability)
    st.integers(1, 6), st.integers(1, 6),  # the dropout patch [px]
    st.booleans(),  # the patch lies on the robot's image
)
def test_no_point_of_a_ball_of_the_declared_size_is_freed(
    seed: int, size: float, ph: int, pw: int, on_robot: bool
) -> None:
    """Independent oracle: a ball of diameter ``size`` stands in front of a wall, or in
    front of the robot's surface (readings explained by the robot, free to its shadow start)
    that covers the patch and the pixels around it; pixels whose centre ray meets the ball
    read it (z-depth of the hit), a dropout patch reads nothing. Where the rule frees a
    pixel, no point of the ball that projects to it lies in front of its new free depth
    (elsewhere, the ball's points within a pixel's footprint may lie in front of its centre
    ray's reading: the pixel model, not this rule). 20 balls each."""
    rng = np.random.default_rng(seed)
    for _ in range(20):
        _ball_in_a_patch(rng, size, ph, pw, on_robot)


def _ball_in_a_patch(rng: np.random.Generator, size: float, ph: int, pw: int, on_robot: bool = False) -> None:
    wall = 8.0
    rays = _rays()
    fs = np.full((BALL_H, BALL_W), wall - 0.1, dtype=np.float32)
    v0, u0 = int(rng.integers(4, BALL_H - 4 - ph)), int(rng.integers(4, BALL_W - 4 - pw))
    # the surface behind the ball: the wall, or the robot's (a rectangle around the patch)
    end = fs.copy()
    front = wall
    if on_robot:
        front = rng.uniform(1.2 + 1.5 * size, wall - 0.5)
        end[max(v0 - 3, 0) : v0 + ph + 3, max(u0 - 3, 0) : u0 + pw + 3] = front - 0.1
    # the ball's centre on a ray through the patch (or near it), wholly in front of the surface
    pv, pu = v0 + rng.uniform(-1.5, ph + 0.5), u0 + rng.uniform(-1.5, pw + 0.5)
    zc = rng.uniform(NEAR + size, front - 0.1 - size / 2)
    centre = np.array([(pu - BALL_C) / BALL_F, (pv - BALL_C) / BALL_F, 1.0]) * zc
    r = size / 2
    # ray-ball hits (rays are d = rays[v, u], points t * d, z-depth t)
    d = rays.reshape(-1, 3)
    a = (d * d).sum(axis=1)
    b = -2 * d @ centre
    c = centre @ centre - r * r
    disc = b * b - 4 * a * c
    hit = (disc >= 0).reshape(BALL_H, BALL_W)
    t_hit = ((-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)).reshape(BALL_H, BALL_W)
    free = np.where(hit, np.minimum(t_hit - 0.05, end), end).astype(np.float32)
    invalid = np.zeros((BALL_H, BALL_W), dtype=bool)
    free[v0 : v0 + ph, u0 : u0 + pw] = NEAR
    invalid[v0 : v0 + ph, u0 : u0 + pw] = True
    got = small_gaps(free, end, invalid, fs, NEAR, BALL_F, BALL_F, size)
    # the ball's points (a shell and its interior), projected to their pixels
    x = rng.normal(size=(4000, 3))
    x = centre + r * x / np.linalg.norm(x, axis=1, keepdims=True) * rng.uniform(0, 1, size=(4000, 1)) ** (1 / 3)
    u = np.rint(x[:, 0] / x[:, 2] * BALL_F + BALL_C).astype(int)
    v = np.rint(x[:, 1] / x[:, 2] * BALL_F + BALL_C).astype(int)
    inside = (u >= 0) & (u < BALL_W) & (v >= 0) & (v < BALL_H)
    vi, ui = v[inside], u[inside]
    lost = (x[inside, 2] < got[vi, ui]) & (got[vi, ui] > free[vi, ui])
    assert not lost.any(), f"{int(lost.sum())} ball points freed (patch {ph}x{pw} at {v0},{u0}, z {zc:.2f})"


def test_residue_pieces_are_those_whose_segment_pixels_are_all_marked() -> None:
    """:func:`only_marked_segments` (which carved pieces are only a small gap's far part)
    against a plain loop, on random images: a rectangle with an unmarked segment pixel, or
    none, is not residue."""
    rng = np.random.default_rng(3)
    free = rng.uniform(1, 2, size=(20, 30)).astype(np.float32)
    end = np.where(rng.random((20, 30)) < 0.5, free + 1, free).astype(np.float32)
    mark = rng.random((20, 30)) < 0.7
    u0, v0 = rng.integers(0, 30, 200), rng.integers(0, 20, 200)
    rects = np.column_stack([u0, np.minimum(u0 + rng.integers(0, 4, 200), 29), v0, np.minimum(v0 + rng.integers(0, 4, 200), 19)])
    got = only_marked_segments(rects, free, end, mark)
    for r, g in zip(rects, got, strict=True):
        seg = (free < end)[r[2] : r[3] + 1, r[0] : r[1] + 1]
        assert g == (seg.any() and mark[r[2] : r[3] + 1, r[0] : r[1] + 1][seg].all())
    assert got.any() and not got.all()
