"""Recording readers: round trips through rosbags' writers and imageio, time matching, and
one-line errors on bad input."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from polyhull.cell import Cell
from polyhull.cellfile import cell_from_mapping
from polyhull.errors import CellError, FrameError
from polyhull.frames import DepthFrame
from polyhull.recordings import JointSample, cycles, open_recording, recording_cycles
from polyhull.recordings.write import RecordedCycle, write_bag, write_folder
from polyhull.simulator import SensorEffects, Simulator

T0 = 1_700_000_000.0


def _recorded(cell: Cell, sim: Simulator, n: int, uint16: bool) -> list[RecordedCycle]:
    assert cell.robot is not None
    q0 = np.asarray(cell.robot.q)
    out = []
    for i in range(n):
        stamp = T0 + 0.1 * i
        q = q0 + np.array([0.05, 0.02, 0.0, 0.0, 0.0, 0.0]) * i
        frames = sim.render(q, seed=i, stamp=stamp, effects=SensorEffects(uint16=uint16))
        out.append(RecordedCycle(stamp, frames, q))
    return out


def _assert_same(written: list[RecordedCycle], read: list) -> None:  # noqa: ANN001
    assert len(read) == len(written)
    for w, r in zip(written, read, strict=True):
        assert sorted(r.frames) == sorted(w.frames)
        for name, frame in w.frames.items():
            assert np.array_equal(frame.depth, r.frames[name].depth, equal_nan=True), name
            assert r.frames[name].stamp == pytest.approx(frame.stamp, abs=1e-6)
        assert r.q is not None and np.allclose(r.q, w.q, atol=1e-12)
        assert r.q_stamp == pytest.approx(w.stamp, abs=1e-6)


@pytest.mark.parametrize("name", ["bag.mcap", "bag.db3", "bag.bag"])
@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_bag_round_trip_is_exact(tmp_path: Path, small_cell: Cell, small_sim: Simulator, name: str, encoding: str) -> None:
    """Simulator -> rosbags writer -> reader gives identical depth: uint16 millimetres
    through 16UC1, float32 metres through 32FC1; stamps and joint states too."""
    written = _recorded(small_cell, small_sim, 3, uint16=encoding == "16UC1")
    path = write_bag(tmp_path / name, small_cell, written, encoding=encoding)  # type: ignore[arg-type]
    recording = open_recording(path, small_cell)
    assert recording.cameras == ("sw", "ne") and recording.has_joints
    assert recording.frame_count("sw") == 3
    _assert_same(written, list(recording_cycles(recording, small_cell)))


def test_rep117_special_values_survive_32fc1(tmp_path: Path, small_cell: Cell) -> None:
    """NaN, +inf, -inf and 0 are carried as they are (REP 117), and 16UC1 0 reads as 0."""
    shape = small_cell.cameras[0].shape
    depth = np.full(shape, 2.0, dtype=np.float32)
    depth[0, :4] = [np.nan, np.inf, -np.inf, 0.0]
    frames = {c.name: DepthFrame(c.name, depth, stamp=T0) for c in small_cell.cameras}
    assert small_cell.robot is not None
    cyc = [RecordedCycle(T0, frames, np.asarray(small_cell.robot.q))]
    for enc in ("32FC1", "16UC1"):
        path = write_bag(tmp_path / f"special_{enc}.mcap", small_cell, cyc, encoding=enc)  # type: ignore[arg-type]
        got = next(iter(recording_cycles(open_recording(path, small_cell), small_cell)))
        row = got.frames["sw"].depth[0, :4]
        if enc == "32FC1":
            assert np.isnan(row[0]) and row[1] == np.inf and row[2] == -np.inf and row[3] == 0.0
        else:  # millimetres know no special values but 0 (unknown)
            assert np.all(row == 0.0)
        assert got.frames["sw"].depth[5, 5] == pytest.approx(2.0)


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_folder_round_trip_is_exact(tmp_path: Path, small_cell: Cell, small_sim: Simulator, encoding: str) -> None:
    """16-bit PNG millimetres and float32 TIFF metres read back identical, in stamp order."""
    written = _recorded(small_cell, small_sim, 3, uint16=encoding == "16UC1")
    path = write_folder(tmp_path / "rec", small_cell, written, encoding=encoding)  # type: ignore[arg-type]
    assert (path / "sw" / f"{T0 + 0.1:.6f}.{'png' if encoding == '16UC1' else 'tiff'}").is_file()
    _assert_same(written, list(recording_cycles(open_recording(path, small_cell), small_cell)))


def test_folder_stamps_csv_overrides_file_names(tmp_path: Path, small_cell: Cell, small_sim: Simulator) -> None:
    written = _recorded(small_cell, small_sim, 2, uint16=True)
    path = write_folder(tmp_path / "rec", small_cell, written)
    for cam in ("sw", "ne"):
        files = sorted((path / cam).glob("*.png"))
        for i, f in enumerate(files):
            f.rename(f.with_name(f"frame_{i}.png"))
        (path / cam / "stamps.csv").write_text(f"file,stamp\nframe_0.png,{T0}\nframe_1.png,{T0 + 0.1}\n")
    got = list(recording_cycles(open_recording(path, small_cell), small_cell))
    _assert_same(written, got)


def _frame(name: str, t: float) -> DepthFrame:
    return DepthFrame(name, np.ones((2, 2), dtype=np.float32), stamp=t)


def test_time_matching_within_max_age() -> None:
    """Each lead frame takes the nearest unused frame of the other camera within max_age;
    a camera without one is absent; the joint state is the newest at or before the stamp."""
    events = [
        JointSample(-0.01, np.array([0.0])),
        _frame("a", 0.00),
        _frame("b", 0.02),
        JointSample(0.09, np.array([1.0])),
        _frame("b", 0.08),  # nearer to 0.10 than 0.13 is, and unused
        _frame("a", 0.10),
        _frame("b", 0.13),
        _frame("a", 0.20),
        JointSample(0.25, np.array([2.0])),
        _frame("a", 0.30),
        _frame("b", 0.52),  # too far from 0.30, near 0.55
        _frame("a", 0.55),
    ]
    got = list(cycles(events, ("a", "b"), max_age=0.05))
    assert [round(c.frames["a"].stamp, 3) for c in got] == [0.0, 0.1, 0.2, 0.3, 0.55]
    assert [round(c.frames["b"].stamp, 3) if "b" in c.frames else None for c in got] == [0.02, 0.08, None, None, 0.52]
    assert [c.stamp for c in got] == pytest.approx([0.02, 0.1, 0.2, 0.3, 0.55])
    assert [float(c.q[0]) if c.q is not None else None for c in got] == [0.0, 1.0, 1.0, 2.0, 2.0]
    # 0.13 was not used by the cycle at 0.10 (0.08 was nearer) nor reachable from 0.20 (0.07 away)


def test_matched_frames_span_at_most_max_age() -> None:
    """Frames 0.04 before and 0.04 after the lead are each within 0.05 of it but 0.08 apart:
    the one farther from the lead is left out, so no frame of the cycle is stale."""
    events = [_frame("b", -0.04), _frame("a", 0.0), _frame("c", 0.035), _frame("a", 0.5)]
    got = list(cycles(events, ("a", "b", "c"), max_age=0.05))
    assert sorted(got[0].frames) == ["a", "c"] and got[0].stamp == pytest.approx(0.035)


def test_time_matching_without_joint_state_gives_none() -> None:
    got = list(cycles([_frame("a", 0.0), _frame("b", 0.01)], ("a", "b"), max_age=0.05))
    assert len(got) == 1 and got[0].q is None and got[0].q_stamp is None


# -- bad input: one line naming the file, topic or field ---------------------------------------


def _one_line(exc: pytest.ExceptionInfo[BaseException]) -> str:
    message = str(exc.value)
    assert "\n" not in message
    return message


def test_bag_without_the_topics_names_them(tmp_path: Path, small_cell: Cell, small_sim: Simulator) -> None:
    written = _recorded(small_cell, small_sim, 1, uint16=True)
    other = dataclasses.replace(
        small_cell, cameras=tuple(dataclasses.replace(c, topic=f"/elsewhere/{c.name}") for c in small_cell.cameras)
    )
    path = write_bag(tmp_path / "b.mcap", other, written)
    with pytest.raises(FrameError) as exc:
        open_recording(path, small_cell)
    message = _one_line(exc)
    assert "/cam_sw/depth/image_raw (sw)" in message and "/elsewhere/sw" in message


def test_camera_info_disagreeing_with_the_cell_is_refused(tmp_path: Path, small_cell: Cell, small_sim: Simulator) -> None:
    written = _recorded(small_cell, small_sim, 1, uint16=True)
    cam = small_cell.cameras[1]
    k = dataclasses.replace(cam.intrinsics, fx=cam.intrinsics.fx * 1.1)
    other = dataclasses.replace(small_cell, cameras=(small_cell.cameras[0], dataclasses.replace(cam, intrinsics=k)))
    path = write_bag(tmp_path / "b.mcap", other, written)
    with pytest.raises(FrameError) as exc:
        list(recording_cycles(open_recording(path, small_cell), small_cell))
    message = _one_line(exc)
    assert "/cam_ne/depth/camera_info" in message and "camera 'ne'" in message and "fx" in message


def test_wrong_image_size_and_encoding_are_named(tmp_path: Path, small_cell: Cell) -> None:
    from polyhull.recordings.rosbag import decode_depth_image

    class Msg:
        encoding = "rgb8"
        is_bigendian = 0
        height, width = 240, 320
        step = 320 * 3
        data = np.zeros(240 * 320 * 3, dtype=np.uint8)

    cam = small_cell.cameras[0]
    with pytest.raises(FrameError, match="encoding 'rgb8' is not a depth encoding"):
        decode_depth_image(Msg(), cam, "bag: topic /t")
    Msg.encoding, Msg.height = "16UC1", 100
    with pytest.raises(FrameError, match=r"bag: topic /t: image is 320 x 100 px, camera 'sw' is 320 x 240 px"):
        decode_depth_image(Msg(), cam, "bag: topic /t")


def test_folder_errors_name_the_file(tmp_path: Path, small_cell: Cell) -> None:
    import imageio.v3 as iio

    (tmp_path / "sw").mkdir()
    iio.imwrite(tmp_path / "sw" / "frame.png", np.zeros((240, 320), dtype=np.uint16))
    with pytest.raises(FrameError) as exc:
        open_recording(tmp_path, small_cell)
    assert "frame.png: no stamp in the file name" in _one_line(exc)
    (tmp_path / "sw" / "frame.png").unlink()
    iio.imwrite(tmp_path / "sw" / "1.5.png", np.zeros((240, 320), dtype=np.uint8))
    with pytest.raises(FrameError) as exc:
        list(open_recording(tmp_path, small_cell).events())
    assert "1.5.png: depth images must be 16-bit" in _one_line(exc)


def test_joint_csv_errors_name_file_and_line(tmp_path: Path, small_cell: Cell, small_sim: Simulator) -> None:
    written = _recorded(small_cell, small_sim, 1, uint16=True)
    path = write_folder(tmp_path / "rec", small_cell, written)
    csv = path / "joint_states.csv"
    csv.write_text("stamp,joint_1,joint_2\n0,0,0\n")
    with pytest.raises(FrameError) as exc:
        list(open_recording(path, small_cell).events())
    assert "joint_states.csv: line 1: joint state lacks joints ['joint_3'" in _one_line(exc)


def test_missing_recording_is_one_line(tmp_path: Path, small_cell: Cell) -> None:
    with pytest.raises(FrameError) as exc:
        open_recording(tmp_path / "nope.mcap", small_cell)
    assert "nope.mcap: no such recording" in _one_line(exc)
    (tmp_path / "garbage.mcap").write_bytes(b"not a bag")
    with pytest.raises(FrameError) as exc:
        open_recording(tmp_path / "garbage.mcap", small_cell)
    assert "garbage.mcap: not a readable ROS bag" in _one_line(exc)


def test_cell_file_topic_key(small_cell: Cell) -> None:
    """The camera ``topic`` key is read, and a non-string is a one-line error naming it."""
    assert [c.topic for c in small_cell.cameras] == ["/cam_sw/depth/image_raw", "/cam_ne/depth/image_raw"]
    assert small_cell.robot is not None and small_cell.robot.joint_state_topic == "/joint_states"
    data = {
        "zone": {"min": [0, 0, 0], "max": [1, 1, 1]},
        "cameras": [
            {"name": "a", "resolution": [8, 6], "intrinsics": [5, 5, 3.5, 2.5], "position": [0.5, 0.5, 2], "look_at": [0.6, 0.5, 0], "topic": 5}
        ],
    }
    with pytest.raises(CellError, match=r"x.toml: cameras\[0\].topic: expected a string"):
        cell_from_mapping(data, "x.toml")


def test_big_endian_rows_with_padding_decode(small_cell: Cell) -> None:
    """A 16UC1 image in big-endian byte order with 6 padding bytes per row reads correctly."""
    from polyhull.recordings.rosbag import decode_depth_image

    cam = small_cell.cameras[0]
    H, W = cam.shape
    depth = (np.arange(H * W, dtype=np.uint32) % 6000).astype(np.uint16).reshape(H, W)
    rows = np.zeros((H, W * 2 + 6), dtype=np.uint8)
    rows[:, : W * 2] = depth.astype(">u2").view(np.uint8).reshape(H, W * 2)

    class Msg:
        encoding = "16UC1"
        is_bigendian = 1
        height, width, step = H, W, W * 2 + 6
        data = rows.ravel()

    got = decode_depth_image(Msg(), cam, "t")
    assert got.dtype == np.uint16 and np.array_equal(got, depth)
