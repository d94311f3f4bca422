"""Robot occlusion M: piece growth, shadow hulls, and M containing the robot body."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest
import trimesh
from conftest import make_camera, manifold_contains

from polyhull.occlusion import grow_piece, robot_occlusion, robot_shadows, shadow_hull
from polyhull.person import sample_points_inside
from polyhull.robot import Robot


def _mesh(m: m3.Manifold) -> trimesh.Trimesh:
    mesh = m.to_mesh64()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def _unit_cube_vertices(center: tuple[float, float, float], half: float) -> np.ndarray:
    c = np.array(center, dtype=np.float64)
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + c


@pytest.mark.parametrize("padding", [0.0, 0.02, 0.1])
def test_grow_piece_moves_every_face_by_padding(padding: float) -> None:
    rng = np.random.default_rng(1)
    piece = rng.normal(size=(20, 3))
    grown = grow_piece(piece, padding)
    h0 = trimesh.convex.convex_hull(piece)
    h1 = trimesh.convex.convex_hull(grown)
    # Each face plane of the original hull: the grown hull reaches >= padding beyond it.
    for normal, origin in zip(h0.face_normals, h0.triangles[:, 0], strict=True):
        reach = float(np.max((grown - origin) @ normal))
        assert reach >= padding - 1e-9
    # And no point moved more than padding * sqrt(3).
    lo0, hi0 = piece.min(axis=0), piece.max(axis=0)
    assert np.all(grown.min(axis=0) >= lo0 - padding - 1e-12)
    assert np.all(grown.max(axis=0) <= hi0 + padding + 1e-12)
    # Points at distance <= padding from the piece are inside the grown hull.
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    probe = piece[rng.integers(0, len(piece), 200)] + 0.999 * padding * dirs
    assert h1.contains(probe).all() if padding > 0 else True


def test_shadow_hull_contains_piece_and_far_projection() -> None:
    cam = make_camera(position=(0.3, 0.2, 3.0), far=6.0)
    piece = _unit_cube_vertices((0.0, 0.0, 1.5), 0.1)
    hull = shadow_hull(cam, piece)
    assert hull is not None
    mesh = _mesh(hull)
    inner = _unit_cube_vertices((0.0, 0.0, 1.5), 0.099)
    assert mesh.contains(inner).all()
    pc = cam.world_to_camera(inner)
    for s in (1.0, 1.5, 2.0):  # points along the rays behind the piece, before far
        behind = cam.camera_to_world(pc * s)
        ok = cam.world_to_camera(behind)[:, 2] < cam.far - 1e-3
        assert mesh.contains(behind[ok]).all()
    far_proj = cam.camera_to_world(pc * ((cam.far - 1e-3) / pc[:, 2])[:, None])
    assert mesh.contains(far_proj).all()
    # Nothing beyond the far plane.
    v = np.asarray(hull.to_mesh64().vert_properties)[:, :3]
    assert cam.world_to_camera(v)[:, 2].max() <= cam.far + 1e-9


def test_shadow_hull_straddling_camera_plane_is_none() -> None:
    cam = make_camera(position=(0.3, 0.2, 3.0))
    assert shadow_hull(cam, _unit_cube_vertices((0.3, 0.2, 3.0), 0.2)) is None


def test_robot_occlusion_empty_without_pieces() -> None:
    cam = make_camera()
    assert robot_occlusion([cam], [cam.frustum()], cam.frustum(), []).is_empty()


def test_robot_occlusion_is_its_definition() -> None:
    """M, built only near the shadows, is ``F_static \\ F_static+robot`` built over the whole
    zone: the union of the free regions less each camera's free region outside its shadows
    (three cameras, free regions that end on a floor and a box, two pieces, with a band)."""
    cams = [
        make_camera(position=(2.0, 0.3, 3.0), target=(0.0, 0.0, 0.5)),
        make_camera(position=(-1.5, 1.8, 2.5), target=(0.0, 0.0, 0.5)),
        make_camera(position=(0.2, -2.2, 2.8), target=(0.3, 0.0, 0.3)),
    ]
    zone = m3.Manifold.cube((4.0, 4.0, 3.0), True).translate((0.0, 0.0, 1.5))
    solid = m3.Manifold.cube((0.6, 0.6, 0.8)).translate((-0.9, -0.8, 0.0))
    free = [(c.frustum() ^ zone) - solid - m3.Manifold.cube((4.0, 4.0, 0.2), True).translate((0.0, 0.0, 0.1)) for c in cams]
    pieces = [_unit_cube_vertices((0.0, 0.1, 0.6), 0.15), _unit_cube_vertices((0.25, -0.1, 1.0), 0.1)]
    bands = [lambda z: 0.02 * z, None, lambda z: np.full_like(z, 0.05)]
    got = robot_occlusion(cams, free, zone, pieces, bands)
    shadows = [robot_shadows(c, pieces, b) for c, b in zip(cams, bands, strict=True)]
    union = m3.Manifold.batch_boolean(free, m3.OpType.Add)
    seen = [m3.Manifold.batch_boolean([f, *s], m3.OpType.Subtract) for f, s in zip(free, shadows, strict=True)]
    want = m3.Manifold.batch_boolean([union, *seen], m3.OpType.Subtract)
    assert want.volume() > 0.02  # M is not trivially empty here
    assert (got - want).volume() == pytest.approx(0.0, abs=1e-9)
    assert (want - got).volume() == pytest.approx(0.0, abs=1e-9)


def test_occlusion_contains_robot_body(small_cell, small_monitor, small_sim) -> None:  # noqa: ANN001
    """Every point of the robot body at q lies in M, in a static solid, or outside every view."""
    monitor = small_monitor
    monitor.reset()
    robot = Robot.from_spec(small_cell.robot)
    solids = [o.manifold() for o in small_cell.solid_obstacles]
    free_union = m3.Manifold.batch_boolean([f for f in monitor.static.free if not f.is_empty()], m3.OpType.Add)
    for i, q in enumerate([np.asarray(small_cell.robot.q), np.array([0.5, -0.3, 0.9, 0.4, -0.6, 0.2])]):
        frames = small_sim.render(q=q, stamp=0.1 * (i + 1), seed=i)
        v = monitor.step(frames, q, stamp=0.1 * (i + 1))
        assert not any(f.startswith("internal") for f in v.faults), v.faults
        solid = m3.Manifold.batch_boolean(solids, m3.OpType.Add)
        for name, link in robot.link_meshes(q).items():
            pts = sample_points_inside(link, 60, seed=i)
            in_m = manifold_contains(v.robot_occlusion, pts)
            in_solid = manifold_contains(solid, pts)
            # Points no camera sees free in the empty cell are not in M (M is inside F_static),
            # and they stay in C anyway; they are excluded.
            seen = manifold_contains(free_union, pts)
            assert seen.any() or name == "base_link"
            bad = seen & ~in_m & ~in_solid
            assert not bad.any(), f"link {name}: {bad.sum()} body points outside M"
