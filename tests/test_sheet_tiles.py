"""Sheet tiles: a foot lying in one camera's band sheet reads as the surface (static); where
another camera's robot shadow crosses that sheet it is not M, so near a surface seen the
sheet's segments run to the empty cell's free depth."""

from __future__ import annotations

import numpy as np
from conftest import (
    in_raster_shadows,
    lost_points,
    make_camera,
    pixel_points,
    robot_shadow_poses,
)

from polyhull.engine.edge_wedges import SheetTiles
from polyhull.engine.pixels import BLOCK, PixelBuffers, classify_frame, prepare_static
from polyhull.engine.static_model import StaticCamera
from polyhull.monitor import Monitor
from polyhull.person import make_person, sample_points_inside
from polyhull.simulator import SensorEffects, Simulator

TILE = 8


def _classify(static: StaticCamera, D: np.ndarray, buffers: PixelBuffers, sheets, shadow=None, rect=None):  # noqa: ANN001, ANN202
    cam = static.camera
    return classify_frame(
        D, static.reference, static.lower, static.upper, static.free_static,
        np.full(cam.shape, np.inf, dtype=np.float32) if shadow is None else shadow, near=cam.near, far=cam.far,
        tau_a=static.tau_a, tau_min=cam.tolerance_min, is_color=False, tile=TILE, shadow_rect=rect,
        static=prepare_static(static.lower, static.upper, static.free_static, cam.near, static.edge),
        buffers=buffers, free_empty=static.free_empty, sheets=sheets,
    )


def test_a_candidate_sheet_runs_to_the_empty_cells_free_depth_near_a_surface_seen() -> None:
    """A wall 4 m away; one candidate tile (reach 2 tiles). A surface seen 2 tiles away, 0.2
    m in front of the wall, gives the tile's static pixels a segment to ``B - tau(B)``; 3
    tiles away, or nearer than the sheet's depths less the margin, or farther in front of
    the wall than the lift (not a lower leg), or on the robot's image, it does not; the
    next cycle without it puts the tile back."""
    cam = make_camera(width=64, height=48)
    static = StaticCamera.build(cam, np.full(cam.shape, 4.0), 2)
    buffers = PixelBuffers(prepare_static(static.lower, static.upper, static.free_static, cam.near, static.edge), static.free_static)
    nv, nu = 48 // TILE, 64 // TILE
    cand = np.zeros((nv, nu), dtype=bool)
    cand[2, 2] = True
    reach = np.full((nv, nu), 2, dtype=np.int64)
    depths = np.stack([np.full((nv, nu), static.free_static.min()), np.full((nv, nu), static.free_empty.max())])
    sheets = (cand, reach, depths, static.free_empty, 0.3, 0.6)
    fs, fe = static.free_static[20, 20], static.free_empty[20, 20]
    assert fe > fs + 0.05

    def surface_at(tile_u: int, depth: float) -> np.ndarray:
        D = static.reference.copy()
        D[17:22, tile_u * TILE + 1 : tile_u * TILE + 6] = depth  # a 5 x 5 surface in tile row 2
        return D

    cls = _classify(static, surface_at(4, 3.8), buffers, sheets)
    tile = (slice(16, 24), slice(16, 24))
    assert (cls.end[tile] == static.free_empty[tile]).all() and (cls.free[tile] < cls.end[tile]).all()
    assert cls.tiles[2, 2] and buffers.sheets is not None and buffers.sheets[2, 2]
    assert buffers.end_changed[16 // BLOCK, 16 // BLOCK]
    cls = _classify(static, surface_at(5, 3.8), buffers, sheets)  # beyond the reach
    assert (cls.end[tile] == static.free_static[tile]).all()  # put back
    assert 3.45 < depths[0].min() - 0.1 and 4.0 - 3.45 <= 0.6  # in front of the sheet's margin of 0.1 m
    cls = _classify(static, surface_at(4, 3.45), buffers, (cand, reach, depths, static.free_empty, 0.1, 0.6))
    assert (cls.end[tile] == static.free_static[tile]).all()
    assert (_classify(static, surface_at(4, 3.45), buffers, sheets).end[tile] == static.free_empty[tile]).all()
    cls = _classify(static, surface_at(4, 3.8), buffers, (cand, reach, depths, static.free_empty, 0.3, 0.1))  # higher than the lift
    assert (cls.end[tile] == static.free_static[tile]).all()
    # the same surface on the robot's image (covered: its shadow starts behind it)
    shadow = np.full(cam.shape, np.inf, dtype=np.float32)
    shadow[17:22, 33:38] = 3.9
    cls = _classify(static, surface_at(4, 3.8), buffers, sheets, shadow, (33, 37, 17, 21))
    assert (cls.end[tile] == static.free_static[tile]).all()
    # not a candidate: nothing
    cls = _classify(static, surface_at(4, 3.8), buffers, (np.zeros_like(cand), reach, depths, static.free_empty, 0.3, 0.6))
    assert (cls.end[tile] == static.free_static[tile]).all()


def test_every_sheet_a_robot_shadow_meets_is_a_candidate(paper: tuple[Monitor, Simulator]) -> None:
    """Oracle: points sampled in the band sheets (a pixel's footprint, between the static
    free depth and its sheet's end) that another camera's raster puts in the padded robot's
    shadow (a covered pixel, at or behind the shadow's start) belong to candidate tiles, at
    the cell's joint state and five random ones."""
    monitor, _ = paper
    cams = monitor.cell.cameras
    tiles = SheetTiles.build(monitor.static.cameras, TILE, 0.3, 0.3)
    rng = np.random.default_rng(1)
    hits = 0
    for trial, (boxes, rasters) in enumerate(robot_shadow_poses(monitor, rng)):
        for i, s in enumerate(monitor.static.cameras):
            chosen = tiles.candidates(i, boxes)
            ends = tiles.ends(i)
            v, u = np.nonzero(ends > s.free_static)
            pick = rng.integers(0, len(v), 40_000)
            vp, up = v[pick], u[pick]
            pts = pixel_points(cams[i], vp, up, s.free_static[vp, up], ends[vp, up], rng)
            for j, shadowed in in_raster_shadows(cams, rasters, i, pts):
                hits += len(shadowed)
                missed = ~chosen[vp[shadowed] // TILE, up[shadowed] // TILE]
                assert not missed.any(), (trial, i, j, int(missed.sum()))
    assert hits > 100  # the oracle tested something


def test_a_foot_read_as_the_floor_where_the_arm_hides_it_stays_in_r3(small_monitor: Monitor, small_sim: Simulator) -> None:
    """Found by a search of walks up to the robot in the small cell (seed 108151, cycle 0,
    feet sampled, noise and dropouts): camera sw read a reaching person's foot top within
    its band of the floor (static), the arm hid it from ne; the point 12 cm over the floor
    lay in sw's sheet, which the empty cell shows sw (not M), and no segment held it."""
    cell = small_monitor.cell
    person = make_person(height=1.7063, pose="reaching", position=(1.2267, 2.2062), yaw=5.7614)
    q = np.array([1.8002, 1.5403, -1.8564, -1.3718, -2.0144, 5.7853])
    effects = SensorEffects(flying_pixels=False)
    small_monitor.reset()
    frames = small_sim.render(q, targets=[person], seed=1081510, stamp=1.0, effects=effects)
    v = small_monitor.step(frames, q, stamp=1.0)
    body = np.vstack([sample_points_inside(person, 4000, seed=s) for s in (108151, 1081510)])
    body = body[(body[:, 2] < 0.2) & cell.zone.contains(body)]
    lost = lost_points(small_monitor, frames, v, body)
    small_monitor.reset()
    assert len(lost) == 0, lost[:5].tolist()


def test_sheet_tiles_only_lengthen_segments() -> None:
    """Invariant (hypothesis): on random frames of a wall with random surfaces, candidates
    and reaches, the sheet tiles leave every free depth as it is and never shorten a
    segment's end (the possibly occupied region only grows)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    cam = make_camera(width=64, height=48)
    static = StaticCamera.build(cam, np.full(cam.shape, 4.0), 2)
    prepared = prepare_static(static.lower, static.upper, static.free_static, cam.near, static.edge)
    nv, nu = 48 // TILE, 64 // TILE
    depths = np.stack([np.full((nv, nu), static.free_static.min()), np.full((nv, nu), static.free_empty.max())])

    @settings(max_examples=40, deadline=None)
    @given(st.integers(0, 2**31 - 1))
    def check(seed: int) -> None:
        rng = np.random.default_rng(seed)
        D = (static.reference + rng.normal(0, 0.03, cam.shape)).astype(np.float32)
        for _ in range(int(rng.integers(0, 4))):  # surfaces in front of the wall
            v0, u0 = int(rng.integers(0, 44)), int(rng.integers(0, 60))
            D[v0 : v0 + int(rng.integers(2, 8)), u0 : u0 + int(rng.integers(2, 8))] = rng.uniform(2.5, 3.9)
        D[rng.random(cam.shape) < 0.02] = 0.0  # dropouts
        sheets = (rng.random((nv, nu)) < 0.5, rng.integers(0, 4, (nv, nu)), depths, static.free_empty, 0.3, 0.6)
        plain = _classify(static, D, PixelBuffers(prepared, static.free_static), None)
        with_sheets = _classify(static, D, PixelBuffers(prepared, static.free_static), sheets)
        np.testing.assert_array_equal(with_sheets.free, plain.free)
        assert (with_sheets.end >= plain.end).all()

    check()
