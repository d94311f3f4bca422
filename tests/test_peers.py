"""The OctoMap peer (polyhull.peers, ``polyhull bench --peers``): the self filter, the point
clouds, the voxel distance, one comparison cycle on the small cell, and a missing extra.

The OctoMap tests are skipped with a reason when the optional 'peers' extra is missing.
No timing assertions: only the table's fields, their ranges and their consistency.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from polyhull.camera import Camera, Intrinsics
from polyhull.cli import main
from polyhull.errors import MissingExtraError, PolyhullError
from polyhull.frames import DepthFrame
from polyhull.peers import OctomapOptions, SelfFilter, format_table, frame_clouds, require_octomap

try:
    import octomap  # noqa: F401

    HAVE_OCTOMAP = True
except ImportError:
    HAVE_OCTOMAP = False

needs_octomap = pytest.mark.skipif(
    not HAVE_OCTOMAP, reason="the optional 'peers' extra is missing: pip install -e '.[peers]'"
)

SMALL_CELL = Path(__file__).resolve().parent.parent / "fixtures" / "cells" / "small_cell.toml"
# one cycle on the small cell; a 10 cm tree keeps OctoMap quick (the bench default is 5 cm)
SMALL = (
    "--cell", str(SMALL_CELL), "--cycles", "1", "--warmup", "0", "--empty-cycles", "0",
    "--tightness-samples", "20000", "--peers", "1", "--peers-resolution", "0.1",
)


def _bench(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["bench", *argv])
    return code, out.getvalue(), err.getvalue()


# -- no OctoMap needed ---------------------------------------------------------------------
def test_self_filter_is_the_padded_piece_at_the_link_pose() -> None:
    cube = np.array([[x, y, z] for x in (-0.1, 0.1) for y in (-0.1, 0.1) for z in (-0.1, 0.1)])
    f = SelfFilter(["link"], [cube])
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    T[:3, 3] = [1.0, 2.0, 0.5]
    pts = np.array([[1.0, 2.0, 0.5], [1.09, 2.09, 0.59], [1.11, 2.0, 0.5], [1.0, 2.0, 0.61], [0.0, 0.0, 0.0]])
    assert f.inside(pts, {"link": T}).tolist() == [True, True, False, False, False]
    assert f.inside(np.zeros((0, 3)), {"link": T}).shape == (0,)


def test_frame_clouds_follow_polyhulls_validity_rules() -> None:
    cam = Camera("c", "depth", Intrinsics(4, 2, 2.0, 2.0, 1.5, 0.5), np.eye(4), near=0.3, far=5.0)
    depth = np.array([[1.0, 0.0, np.nan, -np.inf], [np.inf, 0.2, 6.0, 2.0]], dtype=np.float32)
    clouds = frame_clouds([cam], {"c": DepthFrame("c", depth)})
    assert len(clouds) == 1
    c = clouds[0]
    # valid 1.0 and 2.0, and the no-return pixel (+inf) as a point beyond far
    assert c.points.shape == (3, 3) and c.maxrange == 5.0
    assert sorted(np.round(c.points[:, 2], 6).tolist()) == [1.0, 2.0, 10.0]
    np.testing.assert_allclose(c.origin, [0.0, 0.0, 0.0])
    # the end point of pixel (u=0, v=0) at 1 m lies on its ray
    np.testing.assert_allclose(c.points[np.argmin(c.points[:, 2])], [(0 - 1.5) / 2.0, (0 - 0.5) / 2.0, 1.0])
    assert frame_clouds([cam], {}) == []  # no frame: nothing inserted


def test_bad_peer_flags_are_one_line_errors() -> None:
    code, out, err = _bench("--peers", "-1")
    assert code != 0 and out == "" and "--peers must be >= 0" in err and err.count("\n") == 1
    with pytest.raises(PolyhullError, match="--peers-resolution"):
        OctomapOptions(resolution=0.0)


def test_missing_extra_names_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "octomap", None)  # import octomap -> ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'polyhull\[peers\]'"):
        require_octomap()
    code, out, err = _bench("--peers", "1")  # the CLI prints the one line before any work
    assert code != 0 and "polyhull[peers]" in err and out == ""


# -- with OctoMap --------------------------------------------------------------------------
@needs_octomap
def test_voxel_distance_is_centre_distance_minus_half_diagonal() -> None:
    import trimesh

    from polyhull.distance import RobotDistanceModel
    from polyhull.peers import voxel_distance

    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    model = RobotDistanceModel({"link": box})
    T = np.eye(4)
    T[:3, 3] = [1.0, 1.0, 1.0]
    res = 0.1
    centres = np.array([[1.45, 1.0, 1.0], [1.0, 1.0, 1.75], [3.0, 3.0, 3.0]])
    d, link = voxel_distance(model, {"link": T}, centres, res)
    assert link == "link"
    assert d == pytest.approx(0.35 - 0.5 * math.sqrt(3.0) * res, abs=1e-3)
    assert voxel_distance(model, {"link": T}, np.zeros((0, 3)), res) == (math.inf, None)


@pytest.fixture(scope="module")
def peers_json() -> dict:  # type: ignore[type-arg]
    code, out, err = _bench(*SMALL, "--json")
    assert code == 0, err
    return json.loads(out)  # stdout holds the one object


@needs_octomap
def test_one_cycle_on_the_small_cell_fills_the_table(peers_json: dict) -> None:  # type: ignore[type-arg]
    r = peers_json["peers"]
    assert r["cycles"] == 1 and r["samples"] == 20000
    o = r["options"]
    assert o["resolution_m"] == 0.1 and o["discretize"] is True and o["self_filter_padding_m"] > 0
    assert o["library"].startswith("octomap-python")
    zone = 3.0 * 3.0 * 2.5
    assert 0 < r["volume_exact_hull_m3"] <= zone
    m = r["methods"]
    assert set(m) == {"polyhull", "octomap_fresh", "octomap_incremental"}
    for name, row in m.items():
        assert row["cycle_ms"]["median"] > 0 and row["cycle_ms"]["p99"] >= row["cycle_ms"]["median"]
        assert 0 < row["volume_m3"] <= zone
        assert row["excess_percent"] == pytest.approx(100 * (row["volume_m3"] / r["volume_exact_hull_m3"] - 1))
        assert 0 <= row["exact_hull_free_m3"] <= r["volume_exact_hull_m3"]
        for share in (row["person_free_percent"]["median"], row["person_free_percent"]["max"], row["robot_free_percent"]):
            assert 0.0 <= share <= 100.0, name
        assert row["distance_m"] is None or row["distance_m"] >= 0
        assert isinstance(row["cycles_reported_above_true"], int)
    for name in ("octomap_fresh", "octomap_incremental"):
        stages = m[name]["stages_ms_median"]
        assert set(stages) == {"clouds", "insert", "region", "distance"}
        assert 0 < stages["insert"] < m[name]["cycle_ms"]["median"]
        assert r["speed_ratio"][name] == pytest.approx(m[name]["cycle_ms"]["median"] / m["polyhull"]["cycle_ms"]["median"])
    # the region polyhull's distance uses never claims to be farther than the person
    assert m["polyhull"]["cycles_reported_above_true"] == 0
    # polyhull's C holds the exact hull but for the dropout patches its small-gaps rule frees
    # (a reported removal; without dropouts nothing); OctoMap's free rays cut far deeper
    assert m["polyhull"]["exact_hull_free_m3"] <= 0.005 * r["volume_exact_hull_m3"]
    assert m["octomap_fresh"]["exact_hull_free_m3"] > m["polyhull"]["exact_hull_free_m3"]
    assert 0.0 <= r["exact_hull_person_free_percent"]["median"] <= 100.0
    assert r["true_distance_m"]["median"] > 0
    for name, row in m.items():  # reported + (true - reported) is the true distance
        if row["distance_m"] is not None:
            assert row["distance_m"] + row["true_minus_reported_m"] == pytest.approx(r["true_distance_m"]["median"]), name
    # after one cycle the incremental tree is the fresh one
    for key in ("volume_m3", "exact_hull_free_m3", "robot_free_percent", "distance_m"):
        assert m["octomap_incremental"][key] == m["octomap_fresh"][key], key
    # the text table names every row
    table = format_table(r)
    for row_label in ("cycle median", "speed ratio", "possibly occupied", "exact hull marked free", "person marked free", "robot links marked free", "min distance"):
        assert row_label in table
