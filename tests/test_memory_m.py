"""The shadow memory holds only ``C n M`` (:mod:`polyhull.engine.memory`), with ``M`` by its
definition.

``M = F_static \\ F_static+robot`` (here with the padded robot): what some k
cameras see free in the empty cell and fewer than k see free with the robot in it. The
memory's pieces start as one camera's robot shadow and used to be carved by the frame's
free depth only, so they also held space that other cameras would see free with the robot
(hidden from them only by a person) and, with k >= 2, space inside ``C_static``: with eight
colour cameras the memory reached 55,000 pieces near the robot. Carving tests M as well
(:class:`polyhull.engine.pieces.MTest`), and what it drops is in the other pieces or in
``C_static`` (the engine's cover argument: a camera's segment ends are the free depth of
the empty cell with the padded robot).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from conftest import exactly_possibly_occupied, in_robot_occlusion, in_robot_span, manifold_contains
from hypothesis import given, settings
from hypothesis import strategies as st

import polyhull.monitor as monitor_module
from polyhull.cellfile import default_cell_path, load_cell
from polyhull.commands.bench import rescale_camera
from polyhull.distance import points_in_hexahedra
from polyhull.engine.memory import ShadowMemory
from polyhull.engine.pieces import (
    CameraStack,
    CarveParams,
    ImageStack,
    MTest,
    PieceSet,
    PyramidStack,
    carve,
)
from polyhull.monitor import Monitor
from polyhull.oracles import in_solids, pixels_of
from polyhull.person import make_person, sample_points_inside
from polyhull.simulator import SensorEffects, Simulator


def _images(stack: CameraStack, rng: np.random.Generator, lo: float, hi: float, patch: int) -> ImageStack:
    """Every camera's image in ``patch`` x ``patch`` px patches of depths uniform in [lo, hi]."""
    out = ImageStack(stack, fill=None)
    for i in range(len(stack.near)):
        H, W = out.shape(i)
        coarse = rng.uniform(lo, hi, size=(-(-H // patch), -(-W // patch))).astype(np.float32)
        out.image(i)[:] = np.kron(coarse, np.ones((patch, patch), dtype=np.float32))[:H, :W]
    return out


def _box_points(boxes: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) integer pixel (u, v) and depth z of ``n`` points in each box (N, 7) of camera 0."""
    b = np.repeat(boxes, n, axis=0)
    u = rng.integers(b[:, 1].astype(int), b[:, 2].astype(int) + 1)
    v = rng.integers(b[:, 3].astype(int), b[:, 4].astype(int) + 1)
    z = rng.uniform(b[:, 5], b[:, 6])
    return np.column_stack([u, v]), z


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.sampled_from([1, 2]), patch=st.sampled_from([4, 16, 64]))
def test_carving_with_the_m_test_keeps_every_point_of_c_n_m(seed: int, k: int, patch: int) -> None:
    """Point oracle of the kernel on the small cell (two cameras): random free depths, segment
    ends (the empty cell with the robot) and static free depths of camera 1, in patches; the
    pieces of camera 0 carved with the M test. Every point (in the zone) that fewer than k
    cameras free now, fewer than k would free with the robot (camera 1's end), and at least
    k would free in the empty cell (camera 0, whose segment it is, and camera 1 by its f_s)
    lies in a kept piece."""
    cell = load_cell("fixtures/cells/small_cell.toml")
    stack = CameraStack.of(cell.cameras)
    rng = np.random.default_rng(seed)
    free = _images(stack, rng, 0.5, 6.0, patch)
    ends = _images(stack, rng, 0.5, 6.0, patch)
    static = _images(stack, rng, 0.5, 6.0, patch)
    seg_end = ImageStack(stack, fill=6.0)
    free.image(0)[:] = 0.3  # camera 0's own segments: from near it to 6 m
    active = np.ones(len(cell.cameras), dtype=bool)
    u0 = rng.integers(0, 150, size=40).astype(float)
    v0 = rng.integers(0, 110, size=40).astype(float)
    z0 = rng.uniform(0.5, 4.0, size=40)
    init = np.column_stack([np.zeros(40), u0, u0 + rng.integers(0, 16, 40), v0, v0 + rng.integers(0, 16, 40), z0, z0 + rng.uniform(0.1, 2.0, 40)])
    zlo, zhi = np.asarray(cell.zone.min, float), np.asarray(cell.zone.max, float)
    m_test = MTest(PyramidStack.build(ends, active), PyramidStack.build(static, active))
    params = CarveParams(alpha=0.1, size_min=0.05, size_max=0.3)
    pieces, overflow = carve(
        init, stack, active, PyramidStack.build(free, active), free, seg_end, np.array([[0.0, 0.0, 1.0, 0.3]]),
        zlo, zhi, k, params, m_test=m_test,
    )
    assert not overflow
    uv, z = _box_points(init, 100, rng)
    fx, fy, cx, cy = stack.intr[0]
    pc = np.column_stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z])
    world = pc @ stack.R_wc[0].T + stack.t_wc[0]
    ui, vi, z1, seen = pixels_of(cell.cameras[1], world)
    seen &= z1 > cell.cameras[1].near  # (a camera frees nothing before its near plane)
    z1 = np.where(seen, z1, -np.inf)

    def in_front(img: ImageStack) -> np.ndarray:
        return seen & (z1 < np.where(seen, img.image(1)[vi, ui], -np.inf))

    n_free = in_front(free).astype(int)  # camera 0 never frees its own segment
    n_end = in_front(ends).astype(int)
    n_static = 1 + in_front(static).astype(int)
    in_zone = cell.zone.contains(world)
    in_cm = in_zone & (n_free < k) & (n_end < k) & (n_static >= k)
    b = pieces.boxes
    held = np.zeros(len(z), dtype=bool)
    for box in b:  # the kept pieces are camera 0's: membership in its image space
        held |= (uv[:, 0] >= box[1]) & (uv[:, 0] <= box[2]) & (uv[:, 1] >= box[3]) & (uv[:, 1] <= box[4]) & (z >= box[5]) & (z <= box[6])
    lost = in_cm & ~held
    assert not lost.any(), f"{lost.sum()} of {in_cm.sum()} points of C n M dropped (k = {k}), e.g. {uv[lost][:3]}, {z[lost][:3]}"


def test_the_m_test_drops_what_the_robot_does_not_hide_and_what_c_static_holds() -> None:
    """Camera 1 frees nothing now (a person in front of it, say): without the M test the
    pieces stay whole. If camera 1 would see them free with the robot (its segment ends far),
    they are not in M: dropped (k = 1). If it would not (ends at ``near``) but sees them in
    the empty cell, they are in M: kept. With k = 2 and camera 1 blind in the empty cell
    (f_s at ``near``), only camera 0 sees them free there: inside C_static, dropped."""
    cell = load_cell("fixtures/cells/small_cell.toml")
    stack = CameraStack.of(cell.cameras)
    active = np.ones(len(cell.cameras), dtype=bool)
    free = ImageStack(stack, fill=0.0)
    seg_end = ImageStack(stack, fill=6.0)
    init = np.array([[0.0, 90, 110, 70, 90, 2.0, 3.5]])
    zlo, zhi = np.asarray(cell.zone.min, float), np.asarray(cell.zone.max, float)
    pyr = PyramidStack.build(free, active)

    def run(k: int, ends: float, fs: float) -> PieceSet:
        m = MTest(PyramidStack.build(ImageStack(stack, fill=ends), active), PyramidStack.build(ImageStack(stack, fill=fs), active))
        return carve(init, stack, active, pyr, free, seg_end, np.zeros((0, 4)), zlo, zhi, k, CarveParams(), m_test=m)[0]

    whole = carve(init, stack, active, pyr, free, seg_end, np.zeros((0, 4)), zlo, zhi, 1, CarveParams())[0]
    assert len(whole) == 1
    assert len(run(1, ends=20.0, fs=20.0)) == 0  # camera 1 would see it with the robot: not M
    kept = run(1, ends=0.0, fs=20.0)  # hidden by the robot from camera 1: M
    assert len(kept) == 1 and np.allclose(kept.boxes, init)
    assert len(run(2, ends=0.0, fs=20.0)) == 1  # two cameras see it in the empty cell: M
    assert len(run(2, ends=0.0, fs=0.0)) == 0  # camera 0 alone sees it there: C_static


@pytest.fixture(scope="module", params=[1, 2], ids=["k1", "k2"])
def color_k(request: pytest.FixtureRequest) -> tuple[Monitor, Simulator]:
    """The paper cell's four cameras as colour cameras (320 x 240), k-of-n as given."""
    base = load_cell(default_cell_path())
    cameras = tuple(
        replace(rescale_camera(c, 320, 240), kind="color", noise=0.0, tolerance_min=0.02) for c in base.cameras
    )
    cell = replace(base, cameras=cameras, reconstruction=replace(base.reconstruction, k_of_n=request.param))
    sim = Simulator(cell)
    return Monitor(cell, references=sim.reference()), sim


def _second_cycle(monitor: Monitor, sim: Simulator, with_m_test: bool) -> dict[str, Any]:
    """A person reaching over the arm, seen twice: the second cycle's memory and all its
    pieces before the rules."""
    seen: dict[str, Any] = {"memory": []}
    memory = ShadowMemory.pieces

    def record(self: ShadowMemory, *args: Any) -> PieceSet:
        out = memory(self, *args)
        seen["memory"].append(out)
        return out

    mp = pytest.MonkeyPatch()
    mp.setattr(ShadowMemory, "pieces", record)
    if not with_m_test:
        mp.setattr(monitor_module, "MTest", lambda *a: None)
    try:
        q = np.asarray(monitor.cell.robot.q)  # type: ignore[union-attr]
        person = make_person(height=1.808, pose="reaching", position=(2.836, 2.306), yaw=0.945)
        monitor.reset()
        for c in range(2):
            seen["memory"].clear()
            seen["seeds"] = (monitor._seed_lo, monitor._seed_hi)  # the last cycle's
            frames = sim.render(q, targets=[person], seed=4 + c, stamp=1.0 + 0.1 * c, effects=SensorEffects.none())
            v = monitor.step(frames, q, stamp=1.0 + 0.1 * c)
    finally:
        mp.undo()
    assert not any("internal" in f for f in v.faults), v.faults
    seen["pieces"], seen["frames"] = v._geometry.pieces, frames  # type: ignore[union-attr]
    return seen


def test_what_the_m_test_drops_from_the_memory_is_in_the_region_or_free(color_k: tuple[Monitor, Simulator]) -> None:
    """The same two cycles with and without the M test: every point of the memory without
    it lies, with it, in the memory or the other pieces (before the rules), in C_static, or
    is freed by at least k cameras' free depth (a piece kept whole holds some), outside the
    zone or beyond a person's reach of the seeds (the memory's pieces are finer). The test drops part of the memory (colour cameras: a third to a half)."""
    monitor, sim = color_k
    k = monitor.cell.reconstruction.k_of_n
    old = _second_cycle(monitor, sim, with_m_test=False)
    new = _second_cycle(monitor, sim, with_m_test=True)
    old_mem = PieceSet.concat(old["memory"])
    new_mem = PieceSet.concat(new["memory"])
    assert len(old_mem) > 50
    assert len(new_mem) < 0.9 * len(old_mem)
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(old_mem), 20_000)
    t = rng.uniform(size=(len(idx), 3))
    # points in the pieces: trilinear in the hexahedron's (u, v, z) cube (vertex order of
    # PieceSet: near face from (u0, v0) counter-clockwise, then the far face)
    v = old_mem.vertices[idx]
    a, b, c = t[:, 0:1], t[:, 1:2], t[:, 2:3]
    near = (1 - b) * ((1 - a) * v[:, 0] + a * v[:, 1]) + b * ((1 - a) * v[:, 3] + a * v[:, 2])
    far = (1 - b) * ((1 - a) * v[:, 4] + a * v[:, 5]) + b * ((1 - a) * v[:, 7] + a * v[:, 6])
    pts = (1 - c) * near + c * far
    assert monitor.last_images is not None
    n_free = np.zeros(len(pts), dtype=int)
    for cam in monitor.cell.cameras:
        ui, vi, z, ok = pixels_of(cam, pts)
        n_free += ok & (z < np.where(ok, monitor.last_images.free[cam.name][vi, ui], -np.inf))
    # the memory is what comes within a person's reach of the seeds: a coarse piece that
    # does at a corner stands for more, and its finer pieces beyond reach are dropped
    lo, hi = new["seeds"]
    reach = monitor.cell.safety.human_speed * 0.1 + 1e-3
    gap = np.full(len(pts), np.inf)
    for a, b in zip(lo, hi, strict=True):
        gap = np.minimum(gap, np.linalg.norm(np.maximum(np.maximum(a - pts, pts - b), 0.0), axis=1))
    ok = (
        (gap > reach)
        | points_in_hexahedra(pts, new["pieces"])
        | monitor.static.hull_contains(pts, k)
        | (n_free >= k)
        | ~monitor.cell.zone.contains(pts)
    )
    assert ok.all(), f"{(~ok).sum()} of {len(pts)} points of the old memory lost (k = {k}): {pts[~ok][:3]}"


# Found by a search of 60 walks past the robot (seeds 70000-70059; the checked points are
# within a person's reach of the last cycle's seeds, in M by its definition, possibly
# occupied by the exact free depth, outside the padded robot's depth span and the solids):
# 15 of the 35 checked cycles lost 1 to 8 such points, all within a few centimetres in
# front of the padded robot in every camera, in the band a depth camera's tolerance hides
# (the shadow start to the padded front) that the memory held for colour cameras only.
@pytest.mark.parametrize("seed", [70030, 70053, 70059])
def test_the_memory_holds_the_band_before_the_robot(paper: tuple[Monitor, Simulator], seed: int) -> None:
    """A person walking past the robot's arm (depth cameras, sensor effects as drawn): at
    every cycle after the first, every body point the memory stands for is in R3."""
    monitor, sim = paper
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None and cell.robot is not None
    bx, by = cell.robot.base[:2]
    rng = np.random.default_rng(seed)
    r0, th = rng.uniform(0.6, 1.2), rng.uniform(-np.pi, np.pi)
    x, y = bx + r0 * np.cos(th), by + r0 * np.sin(th)
    head = th + np.pi / 2 * rng.choice([-1, 1]) + rng.uniform(-0.4, 0.4)  # past the robot
    step, pose, height = rng.uniform(0.08, 0.16), str(rng.choice(["standing", "walking", "reaching"])), rng.uniform(1.5, 1.95)
    q = robot.lower + rng.random(6) * (robot.upper - robot.lower)
    dq = rng.uniform(-0.05, 0.05, 6)
    effects = [SensorEffects.none(), SensorEffects()][int(rng.integers(2))]
    monitor.reset()
    checked = 0
    for c in range(6):
        seeds = (monitor._seed_lo, monitor._seed_hi)
        px, py = x + c * step * np.cos(head), y + c * step * np.sin(head)
        person = make_person(height=height, pose=pose, position=(px, py), yaw=head)  # type: ignore[arg-type]
        qc = np.clip(q + c * dq, robot.lower, robot.upper)
        frames = sim.render(qc, targets=[person], seed=seed * 10 + c, stamp=1.0 + 0.1 * c, effects=effects)
        v = monitor.step(frames, qc, stamp=1.0 + 0.1 * c)
        if v.faults:  # a contact stops the robot whatever the region
            break
        if seeds[0] is None or not len(seeds[0]):
            continue
        body = sample_points_inside(person, 400, seed=seed + c)
        body = body[cell.zone.contains(body)]
        reach = cell.safety.human_speed * 0.1
        gap = np.full(len(body), np.inf)
        for a, b in zip(*seeds, strict=True):
            gap = np.minimum(gap, np.linalg.norm(np.maximum(np.maximum(a - body, body - b), 0.0), axis=1))
        held = (
            (gap <= reach) & in_robot_occlusion(monitor, body) & exactly_possibly_occupied(monitor, frames, body)
            & ~in_robot_span(monitor, body) & ~in_solids(cell, body)
        )
        checked += int(held.sum())
        in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
        lost = held & ~in_r3
        assert not lost.any(), f"cycle {c}: {lost.sum()} of {held.sum()} points the memory stands for lost: {body[lost][:3]}"
    assert checked > 0  # the walk tests the memory
