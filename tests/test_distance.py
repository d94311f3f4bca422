"""Region-robot distance with python-fcl against manifold3d min_gap; engine golden values."""

from __future__ import annotations

import importlib.util
import json
import math

import manifold3d as m3
import numpy as np
import pytest
from conftest import FIXTURES

from polyhull.cell import Cell, mesh_to_manifold
from polyhull.distance import RobotDistanceModel
from polyhull.robot import Robot

GOLDEN = FIXTURES / "golden" / "engine_small_walk.json"


@pytest.fixture(scope="module")
def robot(small_cell: Cell) -> Robot:
    return Robot.from_spec(small_cell.robot)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def model(robot: Robot) -> RobotDistanceModel:
    return RobotDistanceModel(robot.link_geometry())


def _box(center: tuple[float, float, float], size: tuple[float, float, float]) -> m3.Manifold:
    return m3.Manifold.cube(size, True).translate(center)


def _min_gap(region: m3.Manifold, robot: Robot, q: np.ndarray) -> tuple[float, str]:
    best, best_link = math.inf, ""
    for name, mesh in robot.link_meshes(q).items():
        link = mesh_to_manifold(mesh, name)
        gap = region.min_gap(link, 2.0)
        if gap < best:
            best, best_link = gap, name
    return best, best_link


@pytest.mark.parametrize(
    ("center", "size", "q"),
    [
        ((0.6, 0.6, 0.8), (0.3, 0.3, 0.5), [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]),
        ((2.3, 1.5, 1.2), (0.2, 0.8, 0.3), [0.0, -0.6, 1.2, 0.0, 0.8, 0.0]),
        ((1.5, 0.7, 1.0), (0.5, 0.2, 1.6), [0.5, -0.3, 0.9, 0.4, -0.6, 0.2]),
    ],
)
def test_distance_matches_min_gap(robot: Robot, model: RobotDistanceModel, center, size, q) -> None:  # noqa: ANN001
    q = np.asarray(q, dtype=np.float64)
    region = _box(center, size)
    result = model.distance(robot.link_transforms(q), region=region)
    gap, link = _min_gap(region, robot, q)
    assert 0.0 < gap < 2.0
    assert result.distance == pytest.approx(gap, abs=1e-3)
    assert result.link == link
    assert result.points is not None
    # The witness points are that far apart.
    assert np.linalg.norm(result.points[0] - result.points[1]) == pytest.approx(result.distance, abs=1e-6)


def test_contact_is_zero_and_names_link(robot: Robot, model: RobotDistanceModel) -> None:
    q = np.asarray([0.0, -0.6, 1.2, 0.0, 0.8, 0.0])
    T = robot.link_transforms(q)
    # A box around the gripper origin touches the gripper.
    p = T["gripper"][:3, 3]
    result = model.distance(T, region=_box(tuple(p), (0.1, 0.1, 0.1)))
    assert result.distance == 0.0
    assert result.link is not None
    assert result.points is None


def test_empty_region_is_inf(robot: Robot, model: RobotDistanceModel) -> None:
    result = model.distance(robot.link_transforms(np.zeros(6)), region=m3.Manifold())
    assert math.isinf(result.distance)
    assert result.link is None and result.points is None


def _joint_range(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The joints' limits, -pi to pi where a joint has none (to draw q from)."""
    return np.where(np.isfinite(robot.lower), robot.lower, -np.pi), np.where(np.isfinite(robot.upper), robot.upper, np.pi)


def _hexahedra(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    from polyhull.engine.dynamic_rules import box_vertices

    return box_vertices(lo, hi)


@pytest.mark.parametrize("q", [[0.0, -0.6, 1.2, 0.0, 0.8, 0.0], [0.5, -0.3, 0.9, 0.4, -0.6, 0.2]])
def test_pieces_distance_matches_min_gap(robot: Robot, model: RobotDistanceModel, q) -> None:  # noqa: ANN001
    """Hexahedra pieces: the same distance as their union measured by manifold3d min_gap."""
    q = np.asarray(q, dtype=np.float64)
    lo = np.array([[0.4, 0.4, 0.2], [2.0, 1.2, 1.0], [1.2, 0.3, 0.0]])
    hi = lo + np.array([[0.3, 0.3, 0.5], [0.2, 0.6, 0.3], [0.4, 0.2, 1.6]])
    pieces = _hexahedra(lo, hi)
    union = m3.Manifold.batch_boolean([_box(tuple((a + b) / 2), tuple(b - a)) for a, b in zip(lo, hi, strict=True)], m3.OpType.Add)
    gap, link = _min_gap(union, robot, q)
    result = model.distance(robot.link_transforms(q), pieces=pieces)
    assert result.distance == pytest.approx(gap, abs=1e-3)
    assert result.link == link


def test_link_inside_a_piece_is_contact(robot: Robot, model: RobotDistanceModel) -> None:
    """FCL measures between surfaces: a link entirely inside a region piece would report a
    positive distance; the containment test makes it contact."""
    q = np.asarray([0.0, -0.6, 1.2, 0.0, 0.8, 0.0])
    T = robot.link_transforms(q)
    p = model.inner_points(T)["gripper"]
    big = _hexahedra(np.array([p - 0.6]), np.array([p + 0.6]))
    # the box encloses the whole gripper: no surface contact, yet the link is inside
    result = model.distance(T, pieces=big)
    assert result.distance == 0.0 and result.link is not None
    far = _hexahedra(np.array([p + 2.0]), np.array([p + 2.5]))
    assert model.distance(T, pieces=far).distance > 1.0


def test_link_inside_the_static_region_is_contact(robot: Robot, model: RobotDistanceModel) -> None:
    """The same for the static region, through its point-containment callback."""
    q = np.asarray([0.0, -0.6, 1.2, 0.0, 0.8, 0.0])
    T = robot.link_transforms(q)
    p = model.inner_points(T)["gripper"]
    region = _box(tuple(p), (1.2, 1.2, 1.2))
    from polyhull.distance import manifold_to_fcl, winding_numbers

    mesh = region.to_mesh64()
    v, t = np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)
    result = model.distance(
        T, static=manifold_to_fcl(region), static_contains=lambda pts: winding_numbers(pts, v, t) > 0.5
    )
    assert result.distance == 0.0


def test_golden_engine_values() -> None:
    """Volumes of C, M, R and the minimum distance of small_walk_000..002 stay put."""
    spec = importlib.util.spec_from_file_location("make_golden", FIXTURES / "golden" / "make_golden.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    got = module.compute()
    want = json.loads(GOLDEN.read_text())
    assert len(got["frames"]) == len(want["frames"]) == 3
    for g, w in zip(got["frames"], want["frames"], strict=True):
        assert g["file"] == w["file"]
        assert g["faults"] == w["faults"]
        # Tolerances follow what differs between machines: the reference depth is ray cast
        # in float32 (embree builds differ), so a pixel at the edge of the static band can
        # change class and with it one piece (a tile of at most 8 x 8 pixels, ~1e-3 m^3 in
        # the small cell) and the distance by up to a tile's width at 3 m (~0.06 m).
        for key in ("volume_hull", "volume_robot_occlusion", "volume_region"):
            assert np.isclose(g[key], w[key], rtol=0.02, atol=2e-3), (w["file"], key, g[key], w[key])
        if w["min_distance"] is None:
            assert g["min_distance"] is None
        else:
            assert abs(g["min_distance"] - w["min_distance"]) <= 0.06, (w["file"], g["min_distance"], w["min_distance"])


def test_static_distance_reuse_matches_fcl(robot: Robot, model: RobotDistanceModel) -> None:
    """The static distance reused across cycles (links measured only while their bound from
    the last measurement is below the best so far) equals FCL's full static distance at
    every pose of a motion, and measures fewer links than all of them per cycle."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import ChunkedMesh, StaticDistance, manifold_to_fcl

    region = _box((1.6, 0.4, 1.0), (0.4, 0.6, 1.4)) + _box((-0.2, 1.7, 0.4), (0.5, 0.3, 0.8))
    obj = manifold_to_fcl(region)
    # small chunks: a link meets several, and the chunked minimum must be the whole one's
    chunks = ChunkedMesh.of_manifold(region, chunk=0.2)
    assert chunks is not None and len(chunks) > 4
    lo, hi = _joint_range(robot)

    @settings(max_examples=15, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.floats(0.005, 0.3))
    def check(seed: int, step: float) -> None:
        rng = np.random.default_rng(seed)
        q = rng.uniform(lo, hi)
        cache = StaticDistance(model, chunks, None)
        for _ in range(12):
            q = np.clip(q + rng.uniform(-step, step, size=q.shape), lo, hi)
            T = robot.link_transforms(q)
            full = model.distance(T, static=obj)
            cycle = cache.cycle(T)
            got = cycle.nearer()
            assert got.distance == pytest.approx(full.distance, abs=1e-9)
            assert got.link == full.link or got.distance == pytest.approx(full.distance, abs=1e-9)
            # a nearer other part: the static links are measured only if they can beat it
            near = cache.cycle(T).nearer(type(full)(0.5 * full.distance, None, "other"))
            assert near.distance == pytest.approx(0.5 * full.distance)

    check()
    # a slow motion: after the first cycle, only the links near the minimum are measured
    cache = StaticDistance(model, chunks, None)
    q = 0.5 * (lo + hi)
    counts = []
    for k in range(20):
        cycle = cache.cycle(robot.link_transforms(q + 0.002 * k))
        cycle.nearer()
        counts.append(cycle.queries)
    assert counts[0] == len(model.link_names)
    assert sum(counts[1:]) <= 19 * 2, counts


def test_a_link_sought_below_a_bound_gets_its_distance_or_a_lower_bound(robot: Robot, model: RobotDistanceModel) -> None:
    """``query_chunks`` with a bound: FCL's distance when the link is nearer than the
    bound; farther, a value between the bound and the distance, with no points."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import ChunkedMesh, manifold_to_fcl

    region = _box((1.6, 0.4, 1.0), (0.4, 0.6, 1.4)) + _box((-0.2, 1.7, 0.4), (0.5, 0.3, 0.8))
    obj = manifold_to_fcl(region)
    chunks = ChunkedMesh.of_manifold(region, chunk=0.2)
    assert chunks is not None
    lo, hi = _joint_range(robot)
    seen = {"exact": 0, "bound": 0}

    @settings(max_examples=40, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.floats(0.0, 2.0), st.integers(-1, 3))
    def check(seed: int, frac: float, hint: int) -> None:
        q = np.random.default_rng(seed).uniform(lo, hi)
        T = robot.link_transforms(q)
        for name in model.link_names:
            full, _ = model._query(obj, name, T[name])
            bound = frac * full
            d, pts, _ = model.query_chunks(chunks, name, T[name], hint, bound)
            if full <= 0.0:
                assert d == 0.0
            elif full < bound:
                assert d == pytest.approx(full, abs=1e-9)
                assert pts is not None
                seen["exact"] += 1
            else:
                assert bound - 1e-12 <= d <= full + 1e-9
                assert pts is None
                seen["bound"] += 1

    check()
    assert seen["exact"] and seen["bound"], seen


def test_each_chunks_bound_is_below_its_fcl_distance(robot: Robot, model: RobotDistanceModel) -> None:
    """The chunks' bounds that order and stop ``query_chunks`` never exceed FCL's distance
    between the link and the chunk (random poses, every link and chunk), and the nearest
    chunk's bound is tight enough to be useful (within the chunk's diagonal)."""
    from polyhull.distance import ChunkedMesh, _chunk_bounds

    region = _box((1.6, 0.4, 1.0), (0.4, 0.6, 1.4)) + _box((-0.2, 1.7, 0.4), (0.5, 0.3, 0.8))
    chunks = ChunkedMesh.of_manifold(region, chunk=0.2)
    assert chunks is not None
    lo, hi = _joint_range(robot)
    rng = np.random.default_rng(3)
    for _ in range(10):
        T = robot.link_transforms(rng.uniform(lo, hi))
        for name in model.link_names:
            c, r = model._spheres[name]
            bounds = _chunk_bounds(chunks.lo, chunks.hi, model._corners[name], T[name], c, r)
            dists = np.array([model._query(obj, name, T[name])[0] for obj in chunks.objects])
            assert np.all(bounds <= dists + 1e-9), (name, float((bounds - dists).max()))
            k = int(np.argmin(dists))
            assert dists[k] - bounds[k] <= float(np.linalg.norm(chunks.hi[k] - chunks.lo[k])) + 1e-9


def test_a_links_displacement_bound_holds_and_is_the_spectral_one() -> None:
    """No point of a link's ball moves farther than ``_displacement`` between two poses,
    and a pure rotation by theta gives ``2 sin(theta / 2)`` times the radius (the
    Frobenius norm would give sqrt(2) times that)."""
    from scipy.spatial.transform import Rotation

    from polyhull.distance import _displacement

    rng = np.random.default_rng(7)
    for _ in range(200):
        T0, T1 = np.eye(4), np.eye(4)
        T0[:3, :3] = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
        T1[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0, 0.5)).as_matrix() @ T0[:3, :3]
        T0[:3, 3], T1[:3, 3] = rng.normal(size=3), rng.normal(size=3)
        c, r = rng.normal(size=3) * 0.3, float(rng.uniform(0.05, 0.6))
        bound = _displacement(T0, T1, c, r)
        dirs = rng.normal(size=(500, 3))
        p = c + r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        moved = np.linalg.norm((p @ T1[:3, :3].T + T1[:3, 3]) - (p @ T0[:3, :3].T + T0[:3, 3]), axis=1)
        assert moved.max() <= bound + 1e-12
    theta = 0.3
    T1 = np.eye(4)
    T1[:3, :3] = Rotation.from_rotvec([0.0, 0.0, theta]).as_matrix()
    assert _displacement(np.eye(4), T1, np.zeros(3), 1.0) == pytest.approx(2 * math.sin(theta / 2), abs=1e-5)


def test_pruned_piece_distance_equals_all_pieces(robot: Robot, model: RobotDistanceModel) -> None:
    """Many pieces: measuring only those whose lower bound (link ball, link box) can beat
    the best so far, in batches nearest first, gives FCL's distance to all of them."""
    import fcl
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import _bvh, hexahedra_triangles

    lo_q, hi_q = _joint_range(robot)

    @settings(max_examples=20, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.integers(9, 200))
    def check(seed: int, n: int) -> None:
        rng = np.random.default_rng(seed)
        T = robot.link_transforms(rng.uniform(lo_q, hi_q))
        # around the robot, mostly beyond its reach (a few may touch it)
        r, a = rng.uniform(0.6, 2.5, n), rng.uniform(0.0, 2.0 * np.pi, n)
        lo = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.0, 2.0, n)])
        pieces = _hexahedra(lo, lo + rng.uniform(0.01, 0.3, size=(n, 3)))
        got = model.distance(T, pieces=pieces)
        verts, tris = hexahedra_triangles(pieces)
        whole = fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())
        want = min(model._query(whole, name, T[name])[0] for name in model.link_names)
        if want <= 0.0:
            assert got.distance == 0.0
        else:
            assert got.distance == pytest.approx(want, abs=1e-9)

    check()


def test_frame_box_gaps_never_exceed_the_distance(robot: Robot, model: RobotDistanceModel) -> None:
    """The tight bound of the pieces' batches (the link's box against the box of the
    piece's vertices in the link's frame) is never above FCL's distance between the piece
    and the link, for long slanted pieces (the dynamic region's columns), and it is far
    above the balls' bound for some of them (what makes it worth its cost)."""
    import fcl
    from hypothesis import given, settings
    from hypothesis import strategies as st
    from scipy.spatial.transform import Rotation

    from polyhull.distance import _bvh, _frame_box_gaps, _piece_bounds, hexahedra_triangles

    lo_q, hi_q = _joint_range(robot)
    names = model.link_names
    gains = []

    @settings(max_examples=20)
    @given(st.integers(0, 2**31 - 1))
    def check(seed: int) -> None:
        rng = np.random.default_rng(seed)
        T = robot.link_transforms(rng.uniform(lo_q, hi_q))
        n = 12
        centre = rng.uniform([-1.0, -1.0, 0.0], [4.0, 4.0, 2.5], size=(n, 3))
        half = rng.uniform(0.01, 0.1, size=(n, 3)) * np.array([1.0, 1.0, 8.0])  # columns
        corners = _hexahedra(-half, half)
        R = Rotation.random(n, random_state=int(seed % 2**32)).as_matrix()
        pieces = np.einsum("nij,nkj->nki", R, corners) + centre[:, None, :]
        poses = np.array([T[m][:3, :4] for m in names])
        boxes = np.array([[model._corners[m][0], model._corners[m][7]] for m in names])
        gaps = _frame_box_gaps(pieces, poses, boxes)
        sph_c = np.array([T[m][:3, :3] @ model._spheres[m][0] + T[m][:3, 3] for m in names])
        sph_r = np.array([model._spheres[m][1] for m in names])
        inner = np.array([T[m][:3, :3] @ model._inner[m] + T[m][:3, 3] for m in names])
        cheap = _piece_bounds(pieces, sph_c, sph_r, poses, boxes, inner)[0]
        for i in range(n):
            verts, tris = hexahedra_triangles(pieces[i : i + 1])
            obj = fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())
            for j, m in enumerate(names):
                d = model._query(obj, m, T[m])[0]
                assert gaps[j, i] <= d + 1e-9
                gains.append(gaps[j, i] - max(cheap[j, i], 0.0))

    check()
    assert max(gains) > 0.3


def _hugging_pieces(robot: Robot, q: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` small boxes (N, 8, 3) just off the links' surfaces, 0.5 to 10 cm out along
    the surface normal (as the shadow memory's pieces hug the padded robot)."""
    meshes = list(robot.link_meshes(q).values())
    which = rng.integers(0, len(meshes), n)
    centres, halves = np.empty((n, 3)), rng.uniform(0.005, 0.03, size=(n, 3))
    for i, k in enumerate(which):
        point, face = meshes[k].sample(1, return_index=True, seed=int(rng.integers(2**31)))
        normal = meshes[k].face_normals[face[0]]
        gap = rng.uniform(0.005, 0.1)
        centres[i] = point[0] + normal * (gap + np.linalg.norm(halves[i]))
    return _hexahedra(centres - halves, centres + halves)


def test_plane_gaps_never_exceed_the_distance_and_are_tight_at_the_surface(robot: Robot) -> None:
    """The links' face-plane bound of a piece's distance (convex pieces of each link, or
    its mesh's hull where the given pieces do not hold the mesh) is never above FCL's
    distance; for pieces hugging a link it is close to it (what spares building a BVH of
    the thousands of shadow-memory pieces beside the robot), nearer than the links' boxes."""
    import fcl
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import _bvh, _frame_box_gaps, _plane_gaps, hexahedra_triangles

    pieces_model = RobotDistanceModel(robot.link_geometry(), robot.link_convex_pieces())
    shrunk = {n: [0.5 * p for p in ps] for n, ps in robot.link_convex_pieces().items()}
    hull_model = RobotDistanceModel(robot.link_geometry(), shrunk)  # do not hold: the hulls
    assert len(hull_model._planes[1]) - 1 == len(hull_model.link_names)  # one piece a link
    assert len(pieces_model._planes[1]) - 1 > len(pieces_model.link_names)
    lo_q, hi_q = _joint_range(robot)
    names = pieces_model.link_names
    ratios: list[float] = []
    box_ratios: list[float] = []

    @settings(max_examples=15, deadline=None)
    @given(st.integers(0, 2**31 - 1))
    def check(seed: int) -> None:
        rng = np.random.default_rng(seed)
        q = rng.uniform(lo_q, hi_q)
        T = robot.link_transforms(q)
        pieces = _hugging_pieces(robot, q, 12, rng)
        poses = np.array([T[m][:3, :4] for m in names])
        boxes = np.array([[pieces_model._corners[m][0], pieces_model._corners[m][7]] for m in names])
        box = _frame_box_gaps(pieces, poses, boxes)
        for model in (pieces_model, hull_model):
            gaps = _plane_gaps(pieces, poses, *model._planes, np.zeros((len(names), len(pieces))), np.inf)
            for i in range(len(pieces)):
                verts, tris = hexahedra_triangles(pieces[i : i + 1])
                obj = fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())
                for j, m in enumerate(names):
                    d = model._query(obj, m, T[m])[0]
                    assert gaps[j, i] <= d + 1e-9
                    if model is pieces_model and 0.0 < d < 0.1:
                        ratios.append(gaps[j, i] / d)
                        box_ratios.append(box[j, i] / d)

    check()
    plane, box = np.array(ratios), np.array(box_ratios)
    assert np.median(plane) > 0.95
    # within 10 % of the distance: about three quarters of the pieces by the planes, a
    # third by the boxes (measured over 389 pairs)
    assert (plane >= 0.9).mean() > (box >= 0.9).mean() + 0.2


def test_a_flat_piece_is_bounded_by_its_box() -> None:
    """A convex piece without a hull (three points, flat) is bounded by its box's planes:
    every vertex inside them, and a piece beyond them bounded by its gap to the box."""
    from polyhull.distance import _convex_planes, _plane_gaps

    triangle = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    planes = _convex_planes(triangle)
    assert len(planes) == 6
    assert (triangle @ planes[:, :3].T <= planes[:, 3]).all()
    piece = _hexahedra(np.array([[0.2, 0.2, 0.3]]), np.array([[0.3, 0.3, 0.4]]))
    pose = np.eye(4)[None, :3, :]
    gap = _plane_gaps(piece, pose, planes, np.array([0, 6]), np.array([0, 1]), np.zeros((1, 1)), np.inf)
    assert gap[0, 0] == pytest.approx(0.3, abs=1e-8)  # above the plane z = 0: 0.3 m


def test_pruned_distance_among_pieces_hugging_the_robot_equals_all_pieces(robot: Robot) -> None:
    """Hundreds of pieces just off the links and a few farther: the pruned, batched
    measurement gives FCL's distance to all of them, with and without the links' convex
    pieces."""
    import fcl
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import _bvh, hexahedra_triangles

    models = (
        RobotDistanceModel(robot.link_geometry(), robot.link_convex_pieces()),
        RobotDistanceModel(robot.link_geometry()),
    )
    lo_q, hi_q = _joint_range(robot)

    @settings(max_examples=10, deadline=None)
    @given(st.integers(0, 2**31 - 1), st.integers(20, 400))
    def check(seed: int, n: int) -> None:
        rng = np.random.default_rng(seed)
        q = rng.uniform(lo_q, hi_q)
        T = robot.link_transforms(q)
        pieces = _hugging_pieces(robot, q, n, rng)
        verts, tris = hexahedra_triangles(pieces)
        whole = fcl.CollisionObject(_bvh(verts, tris), fcl.Transform())
        want = min(models[0]._query(whole, name, T[name])[0] for name in models[0].link_names)
        for model in models:
            got = model.distance(T, pieces=pieces)
            if want <= 0.0:
                assert got.distance == 0.0
            else:
                assert got.distance == pytest.approx(want, abs=1e-9)

    check()


def test_static_distance_on_a_simplified_mesh_is_never_farther(robot: Robot, model: RobotDistanceModel) -> None:
    """The static region's mesh simplified to a tolerance (far fewer triangles: a full
    pixel resolution surface is mostly coplanar) gives, less that tolerance, a distance
    never above FCL's to the whole region, and at most twice the tolerance below it; the
    region point it names is the distance away from the link point."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from polyhull.distance import ChunkedMesh, StaticDistance, manifold_to_fcl

    tol = 2e-3
    # finely triangulated flat faces (as the static region's) and a curved part
    region = _box((1.2, 0.3, 0.9), (0.5, 0.7, 1.2)).refine(12) + m3.Manifold.sphere(0.3, 192).translate((2.6, 1.5, 1.0))
    obj = manifold_to_fcl(region)
    chunks = ChunkedMesh.of_manifold(region, chunk=0.2, tolerance=tol)
    assert chunks is not None and chunks.tolerance == tol
    assert region.simplify(tol).num_tri() < region.num_tri() / 2
    lo, hi = _joint_range(robot)

    @settings(max_examples=15)
    @given(st.integers(0, 2**31 - 1))
    def check(seed: int) -> None:
        rng = np.random.default_rng(seed)
        q = rng.uniform(lo, hi)
        cache = StaticDistance(model, chunks, None)
        for _ in range(6):
            q = np.clip(q + rng.uniform(-0.2, 0.2, size=q.shape), lo, hi)
            T = robot.link_transforms(q)
            full = model.distance(T, static=obj).distance
            got = cache.cycle(T).nearer()
            assert got.distance <= full + 1e-9
            assert got.distance >= full - 2.0 * tol - 1e-9 or full <= tol
            if got.points is not None:
                assert np.linalg.norm(got.points[1] - got.points[0]) == pytest.approx(got.distance, abs=1e-9)

    check()
