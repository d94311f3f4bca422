"""Monitor fault paths (README, "Never raises, never silent"): every fault stops the robot, is
named, and latches."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import exactly_possibly_occupied, manifold_contains

import polyhull.monitor as monitor_module
from polyhull.errors import GeometryError
from polyhull.frames import DepthFrame
from polyhull.monitor import Monitor, Verdict
from polyhull.simulator import Simulator

_EXACT: dict[str, np.ndarray] = {}


@pytest.fixture(autouse=True)
def _exact_depth(small_sim: Simulator) -> None:
    """Noise-free depth of the empty cell with the robot at its default q (cached)."""
    if not _EXACT:
        _EXACT.update(small_sim.render_exact())


def _clean(monitor: Monitor, stamp: float, offset: float = 0.0) -> dict[str, DepthFrame]:
    """Noise-free frames of the empty cell with the robot (+ ``offset`` [m]) at ``stamp`` [s]."""
    out = {}
    for s in monitor.statics:
        exact = _EXACT[s.camera.name]
        depth = np.where(np.isfinite(exact), exact + offset, np.inf).astype(np.float32)
        out[s.camera.name] = DepthFrame(camera=s.camera.name, depth=depth, stamp=stamp)
    return out


def _q(monitor: Monitor) -> np.ndarray:
    return np.asarray(monitor.cell.robot.q, dtype=np.float64)  # type: ignore[union-attr]


def _assert_fault(v: Verdict, *words: str) -> None:
    assert v.speed_scale == 0.0
    assert v.allowed_speed == 0.0
    assert v.faults, "expected a fault"
    text = " | ".join(v.faults).lower()
    for w in words:
        assert w.lower() in text, (w, v.faults)


def _assert_latches_then_resets(monitor: Monitor, stamp: float, *words: str) -> None:
    v = monitor.step(_clean(monitor, stamp), _q(monitor), stamp=stamp)
    _assert_fault(v, *words)
    monitor.reset()
    v = monitor.step(_clean(monitor, stamp + 0.1), _q(monitor), stamp=stamp + 0.1)
    assert v.faults == ()


def test_clean_frame_no_fault(fresh_monitor: Monitor) -> None:
    v = fresh_monitor.step(_clean(fresh_monitor, 1.0), _q(fresh_monitor), stamp=1.0)
    assert v.faults == ()
    assert v.min_distance > 0.0
    assert "total" in v.timings


def _first(monitor: Monitor) -> str:
    return monitor.statics[0].camera.name


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "stale",
        "wrong_shape",
        "not_a_frame",
        "unknown_camera",
        "q_none",
        "q_limits",
        "q_nan",
        "stamp_nan",
        "stamp_inf",
        "all_missing",
        "camera_moved",
        "frames_not_mapping",
    ],
)
def test_single_cycle_faults(fresh_monitor: Monitor, case: str) -> None:
    m = fresh_monitor
    cam = _first(m)
    frames: object = _clean(m, 1.0)
    q: np.ndarray | None = _q(m)
    stamp = 1.0
    words: tuple[str, ...]
    if case == "missing":
        del frames[cam]  # type: ignore[attr-defined]
        words = (cam, "missing")
    elif case == "stale":
        frames[cam] = DepthFrame(camera=cam, depth=frames[cam].depth, stamp=0.5)  # type: ignore[index]
        words = (cam, "stale")
    elif case == "wrong_shape":
        frames[cam] = DepthFrame(camera=cam, depth=np.ones((10, 12), np.float32), stamp=1.0)  # type: ignore[index]
        words = (cam, "shape")
    elif case == "not_a_frame":
        frames[cam] = frames[cam].depth  # type: ignore[index]
        words = (cam, "DepthFrame")
    elif case == "unknown_camera":
        frames["nobody"] = DepthFrame(camera="nobody", depth=np.ones((4, 4), np.float32), stamp=1.0)  # type: ignore[index]
        words = ("nobody", "unknown")
    elif case == "q_none":
        q = None
        words = ("joint state", "missing")
    elif case == "q_limits":
        q = q.copy()  # type: ignore[union-attr]
        q[1] = 100.0
        words = ("joint state", "invalid")
    elif case == "q_nan":
        q = q.copy()  # type: ignore[union-attr]
        q[0] = np.nan
        words = ("joint state", "invalid")
    elif case == "stamp_nan":
        stamp = float("nan")
        words = ("stamp", "finite")
    elif case == "stamp_inf":
        stamp = float("inf")
        words = ("stamp", "finite")
    elif case == "all_missing":
        frames = {}
        words = ("coverage lost",)
    elif case == "camera_moved":
        frames = _clean(m, 1.0, offset=0.5)
        words = ("moved",)
    elif case == "frames_not_mapping":
        frames = list(frames.values())  # type: ignore[attr-defined]
        words = ("mapping",)
    v = m.step(frames, q, stamp=stamp)  # type: ignore[arg-type]
    _assert_fault(v, *words)
    _assert_latches_then_resets(m, 5.0, *words)


def test_duplicated_frame(fresh_monitor: Monitor) -> None:
    m = fresh_monitor
    frames = _clean(m, 1.0)
    assert m.step(frames, _q(m), stamp=1.0).faults == ()
    v = m.step(frames, _q(m), stamp=1.05)
    _assert_fault(v, "duplicated")
    _assert_latches_then_resets(m, 5.0, "duplicated")


def test_out_of_order_frame(fresh_monitor: Monitor) -> None:
    m = fresh_monitor
    assert m.step(_clean(m, 1.0), _q(m), stamp=1.0).faults == ()
    v = m.step(_clean(m, 0.95), _q(m), stamp=1.05)
    _assert_fault(v, "out of order")
    _assert_latches_then_resets(m, 5.0, "out of order")


def test_camera_without_frame_stops_at_once(fresh_monitor: Monitor) -> None:
    """A camera without a usable frame frees nothing: the cycle is a stop verdict naming it,
    its region the whole zone (a superset of what that camera's blindness leaves), with no
    pieces built; the other cameras' pixel faults are still listed."""
    m = fresh_monitor
    frames = _clean(m, 1.0)
    other = m.statics[1].camera.name
    frames[other] = DepthFrame(camera=other, depth=np.zeros_like(frames[other].depth), stamp=1.0)  # blind
    del frames[_first(m)]
    v = m.step(frames, _q(m), stamp=1.0)
    _assert_fault(v, _first(m), "missing")
    _assert_fault(v, other, "blind")
    assert v.min_distance == 0.0
    assert v.counts == {}
    assert v.region.volume() == pytest.approx(m.cell.zone.volume, rel=1e-9)
    assert "pieces" not in v.timings and "pixels" in v.timings
    assert m.last_images is None


def test_stale_joint_state(fresh_monitor: Monitor) -> None:
    m = fresh_monitor
    v = m.step(_clean(m, 1.0), _q(m), stamp=1.0, q_stamp=0.5)
    _assert_fault(v, "joint state", "stale")
    _assert_latches_then_resets(m, 5.0, "stale")


def test_contamination(fresh_monitor: Monitor) -> None:
    m = fresh_monitor
    cam = _first(m)
    assert m.step(_clean(m, 1.0), _q(m), stamp=1.0).faults == ()
    frames = _clean(m, 1.1)
    depth = frames[cam].depth.copy()
    rng = np.random.default_rng(0)
    depth[rng.uniform(size=depth.shape) < 0.5] = 0.0
    frames[cam] = DepthFrame(camera=cam, depth=depth, stamp=1.1)
    v = m.step(frames, _q(m), stamp=1.1)
    _assert_fault(v, cam, "contamination")
    _assert_latches_then_resets(m, 5.0, "contamination")


@pytest.mark.parametrize("exc", [GeometryError("boom: degenerate"), RuntimeError("unexpected boom")])
def test_exceptions_become_verdicts(fresh_monitor: Monitor, monkeypatch: pytest.MonkeyPatch, exc: Exception) -> None:
    m = fresh_monitor

    def broken(*args: object, **kwargs: object) -> None:
        # a fresh instance: raising the parametrized one would store this call's traceback
        # in it (frames holding the monitor) for as long as the module lives
        raise type(exc)(*exc.args)

    monkeypatch.setattr(monitor_module, "carve", broken)
    v = m.step(_clean(m, 1.0), _q(m), stamp=1.0)
    _assert_fault(v, type(exc).__name__, "boom")
    monkeypatch.undo()
    _assert_latches_then_resets(m, 5.0, "boom")


@pytest.mark.parametrize(
    "q",
    ["abc", "0,0,0,0,0,0", object(), {}, [[0.0, 1.0], [2.0]], np.zeros((1, 6)), np.zeros(6) + 1j, [0.0] * 5],
    ids=["str", "csv", "object", "dict", "ragged", "shape-1x6", "complex", "short"],
)
def test_hostile_joint_state_is_a_named_fault(fresh_monitor: Monitor, q: object) -> None:
    """``Monitor.step`` never raises; a bad q gives speed 0 and a joint-state fault,
    without a warning and without echoing a cast of the bad input."""
    import warnings

    frames = _clean(fresh_monitor, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        v = fresh_monitor.step(frames, q, stamp=1.0)  # type: ignore[arg-type]
    assert v.speed_scale == 0.0
    assert any(f.startswith("joint state") for f in v.faults), v.faults
    real = (isinstance(q, np.ndarray) and q.dtype.kind == "f") or (
        isinstance(q, list) and all(isinstance(x, float) for x in q)
    )
    if not real:
        assert v.q.size == 0  # never a cast of input that is not real numbers


def test_cycle_images_are_reused_only_when_nobody_holds_them(fresh_monitor: Monitor, small_sim: Simulator) -> None:
    """A kept verdict, and separately the images of a kept cycle, stay as they were while
    later cycles run (their buffers are not reused); dropped ones are reused (a few buffer
    sets in all)."""
    import gc

    mon = fresh_monitor
    q = _q(mon)
    kept = mon.step(small_sim.render(q, seed=1, stamp=1.0), q, stamp=1.0)  # its verdict only
    hull = kept.hull.volume()
    v = mon.step(small_sim.render(q, seed=2, stamp=2.0), q, stamp=2.0)
    images = mon.last_images  # its images only
    assert images is not None
    del v
    copies = {k: np.array(a) for k, a in images.free.items()}
    covered = {k: np.array(r.covered) for k, r in images.raster.items()}
    assert any(c.any() for c in covered.values())
    first = next(iter(copies))
    ids = set()
    for k in range(3, 9):
        qk = q + np.array([0.05 * k] + [0.0] * (len(q) - 1))  # the robot moves: new rasters
        v = mon.step(small_sim.render(qk, seed=k, stamp=float(k)), qk, stamp=float(k))
        ids.add(id(mon.last_images.free[first].base))  # type: ignore[union-attr]
        del v
        gc.collect()
    for k, a in images.free.items():
        np.testing.assert_array_equal(a, copies[k])
    for k, r in images.raster.items():
        np.testing.assert_array_equal(r.covered, covered[k])
    kept._geometry.cache.clear()  # type: ignore[union-attr]
    assert kept.hull.volume() == pytest.approx(hull, rel=1e-9)
    assert len(ids) <= 3


def test_kept_verdicts_do_not_keep_the_rasters(fresh_monitor: Monitor, small_sim: Simulator) -> None:
    """A verdict holds its cycle's free-depth images (its lazy geometry reads them), not the
    robot's rasters: with every verdict kept, the rasters' buffers are still reused."""
    mon = fresh_monitor
    q = _q(mon)
    kept, free_ids, raster_ids = [], set(), set()
    for k in range(1, 7):
        kept.append(mon.step(small_sim.render(q, seed=k, stamp=float(k)), q, stamp=float(k)))
        images = mon.last_images
        assert images is not None
        name = next(iter(images.free))
        free_ids.add(id(images.free[name].base))
        raster_ids.add(id(images.raster[name].covered))
    assert len(free_ids) == 6  # every kept verdict keeps its own images
    assert len(raster_ids) <= 3


def test_a_cell_without_a_robot(small_cell) -> None:  # noqa: ANN001
    """A cell with no robot: no joint state is needed, no distance is reported (inf, full
    speed), nothing is the robot's occlusion, and a standing person's points lie in R3 (or
    are excused: in a solid, or seen free by the exact per-pixel free depth)."""
    from dataclasses import replace

    from polyhull.distance import points_in_hexahedra
    from polyhull.oracles import in_solids
    from polyhull.person import make_person, sample_points_inside

    bare = replace(small_cell, robot=None)
    sim = Simulator(bare)
    monitor = Monitor(bare, references=sim.reference())
    person = make_person(position=(0.8, 0.8))
    for k in range(3):
        frames = sim.render(None, targets=[person], seed=k, stamp=0.1 * k)
        v = monitor.step(frames, None, stamp=0.1 * k)
        assert v.faults == () and v.speed_scale == 1.0
        assert v.min_distance == np.inf and v.closest_link is None and v.closest_points is None
        assert v.counts["kept_pieces"] > 0  # the person is seen
    assert v.robot_occlusion.is_empty()
    points = sample_points_inside(person, 2000, seed=1)
    in_r3 = manifold_contains(monitor.static.region, points) | points_in_hexahedra(points, v._geometry.kept)
    excused = in_solids(bare, points) | ~exactly_possibly_occupied(monitor, frames, points)
    assert in_r3[~excused].all() and (~excused).sum() > 1000


def test_the_dynamic_region_drawing_is_what_the_cycle_adds(small_cell, small_sim: Simulator) -> None:  # noqa: ANN001
    """``region_dynamic_drawing`` (the viewer's fast path): the hexahedra of the kept pieces
    not wholly in C_static, then the surface of the sheets' part outside the static region;
    every piece of ``region_dynamic`` that is dropped lies in C_static, and together the
    pieces and the sheets are ``region_dynamic``; a stop verdict draws nothing."""
    from polyhull.distance import points_in_hexahedra
    from polyhull.person import make_person

    monitor = Monitor(small_cell, references=small_sim.reference())
    person = make_person(position=(0.7, 0.9))
    q = _q(monitor)
    v = monitor.step(small_sim.render(q, targets=[person], seed=3, stamp=0.0), q, stamp=0.0)
    g = v._geometry
    assert g is not None
    vertices, faces = v.region_dynamic_drawing()
    assert faces.shape[1] == 3 and faces.min() >= 0 and faces.max() < len(vertices)
    drawn, merged = g.drawn_pieces(), g.merged_pieces()
    assert 0 < len(drawn) <= len(merged)
    np.testing.assert_array_equal(vertices[: 8 * len(drawn)], drawn.reshape(-1, 3))
    head = faces[: 12 * len(drawn)]
    assert np.all(head // 8 == np.repeat(np.arange(len(drawn)), 12)[:, None])  # one hexahedron each
    # the dropped pieces lie in C_static: their centres (a convex piece's interior point) are in it
    kept = {p.tobytes() for p in drawn}
    dropped = np.array([p for p in merged if p.tobytes() not in kept]).reshape(-1, 8, 3)
    assert monitor.static.hull_contains(dropped.mean(axis=1), small_cell.reconstruction.k_of_n).all()
    # the rest is the surface of the sheets outside the static region: its enclosed volume
    # (divergence theorem) is that manifold's
    tri = vertices[faces[12 * len(drawn) :]]
    enclosed = float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0
    sheets = g.get("dynamic_sheets")
    # (the drawing builds it as the boxes with R2_static - R3_static: the same set by other
    # booleans, equal to 2e-9 relative with a freshly built static model; one sheet box less
    # would be 1e-4 m^3)
    assert enclosed == pytest.approx((sheets - monitor.static.region).volume(), rel=1e-6, abs=1e-9)
    # and the pieces (all of them) with the sheets are region_dynamic: points classified by
    # the pieces' half-spaces and by the sheets' manifold, against the union's manifold
    dynamic = v.region_dynamic
    lo, hi = np.asarray(dynamic.bounding_box()).reshape(2, 3)
    rng = np.random.default_rng(5)
    weights = rng.dirichlet(np.ones(8), size=2000)  # points in the pieces, then moved up to 3 cm
    near = np.einsum("nk,nkj->nj", weights, merged[rng.integers(0, len(merged), 2000)])
    points = np.concatenate([near + rng.normal(0.0, 0.015, near.shape), rng.uniform(lo, hi, size=(1000, 3))])
    zone = np.all((points >= small_cell.zone.min) & (points <= small_cell.zone.max), axis=1)
    want = (points_in_hexahedra(points, merged) & zone) | manifold_contains(sheets, points)
    assert want.sum() > 1000 and (~want).sum() > 1000
    np.testing.assert_array_equal(manifold_contains(dynamic, points), want)
    stop = monitor.step({}, q, stamp=0.1)
    assert stop.faults and [a.shape[0] for a in stop.region_dynamic_drawing()] == [0, 0]
