"""Tests of ``polyhull view``: standalone HTML, frames and regions, and the live server."""

from __future__ import annotations

import argparse
import base64
import json
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import umsgpack

import polyhull_viewer
from polyhull.cellfile import load_cell
from polyhull.commands import view
from polyhull.errors import FrameError, MissingExtraError, PolyhullError
from polyhull.frames import DepthFrame, save_frames

ROOT = Path(__file__).resolve().parents[1]
PAPER_CELL = ROOT / "fixtures" / "cells" / "paper_cell.toml"
SMALL_CELL = ROOT / "fixtures" / "cells" / "small_cell.toml"

# Runs the command the way `polyhull view ...` does, without needing every other command.
# Ctrl-C as a terminal delivers it: a process started in the background by a shell without
# job control (as CI may start the suite) inherits SIGINT ignored, and Python then installs
# no KeyboardInterrupt handler; the runner installs it, as an interactive start would have.
SIGINT_AS_IN_A_TERMINAL = "import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n"

RUNNER = (
    SIGINT_AS_IN_A_TERMINAL
    + "import faulthandler\n"
    "faulthandler.register(signal.SIGUSR1)  # a hung run's threads, for the test's message\n"
    "import argparse, sys\n"
    "from polyhull.commands import view\n"
    "p = argparse.ArgumentParser(prog='polyhull')\n"
    "view.register(p.add_subparsers())\n"
    "args = p.parse_args(['view', *sys.argv[1:]])\n"
    "sys.exit(args.func(args))\n"
)


def run_view(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="polyhull")
    view.register(parser.add_subparsers())
    args = parser.parse_args(["view", *argv])
    return int(args.func(args))


def html_commands(path: Path) -> list[dict[str, Any]]:
    html = path.read_text(encoding="utf-8")
    match = re.search(r"var commands = (\[.*?\]);", html, re.S)
    assert match is not None
    return [umsgpack.unpackb(base64.b64decode(b)) for b in json.loads(match.group(1))]


def object_paths(path: Path) -> list[str]:
    return [c["path"] for c in html_commands(path) if c["type"] == "set_object"]


@pytest.fixture(scope="module")
def small_frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames of the small cell: floor, table, the robot at its default q and a person."""
    from polyhull.person import make_person
    from polyhull.raycast import StaticScene
    from polyhull.robot import Robot

    cell = load_cell(SMALL_CELL)
    assert cell.robot is not None
    q = np.asarray(cell.robot.q)
    dynamic = [Robot.from_spec(cell.robot).mesh(q), make_person(position=(0.6, 0.7), yaw=0.8)]
    scene = StaticScene([o.mesh for o in cell.obstacles], cell.zone.floor_z)
    frames = {c.name: DepthFrame(c.name, scene.render(c, dynamic), stamp=2.0) for c in cell.cameras}
    return save_frames(tmp_path_factory.mktemp("frames") / "small.npz", frames, q, 2.0)


# -- standalone HTML ------------------------------------------------------------------------


def test_html_of_paper_cell(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from polyhull.robot import Robot

    out = tmp_path / "cell.html"
    assert run_view(str(PAPER_CELL), "--html", str(out)) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    paths = set(object_paths(out))
    cell = load_cell(PAPER_CELL)
    assert cell.robot is not None
    links = Robot.from_spec(cell.robot).visual_meshes(cell.robot.q)
    assert {f"/polyhull/robot/{link}" for link in links} <= paths
    assert {f"/polyhull/cameras/{c.name}/frustum" for c in cell.cameras} <= paths
    assert {f"/polyhull/cell/obstacles/{o.name}" for o in cell.obstacles} <= paths
    assert "/polyhull/cell/zone" in paths
    assert not any("/regions/" in p or "/frames/" in p for p in paths)
    html = out.read_text(encoding="utf-8")
    assert "<title>polyhull: paper cell</title>" in html
    assert not re.search(r"<(script|link|img)[^>]+(src|href)\s*=", html, re.I)


def test_html_with_frames_draws_regions(
    tmp_path: Path, small_frames: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from polyhull.frames import load_frames
    from polyhull.monitor import Monitor

    out = tmp_path / "frames.html"
    assert run_view(str(SMALL_CELL), "--frames", str(small_frames), "--html", str(out), "--max-points", "700") == 0
    stdout = capsys.readouterr().out
    assert "polyhull view: distance" in stdout
    paths = set(object_paths(out))
    cell = load_cell(SMALL_CELL)
    names = [c.name for c in cell.cameras]
    assert {f"/polyhull/frames/{n}" for n in names} <= paths
    assert {f"/polyhull/regions/camera/{n}" for n in names} <= paths
    # The same cycle, run here: every non-empty region of the verdict is drawn.
    recorded = load_frames(small_frames)
    monitor = Monitor(cell)
    verdict = monitor.step(recorded.frames, recorded.q, stamp=recorded.stamp)
    static = monitor.static.region
    for name, region in (("hull", verdict.hull), ("robot_occlusion", verdict.robot_occlusion)):
        assert (f"/polyhull/regions/{name}" in paths) == (not region.is_empty()), name
    # what the cycle adds is drawn from the verdict's pieces as they are (not their union)
    _, faces = verdict.region_dynamic_drawing()
    assert len(faces) > 0 and "/polyhull/regions/dynamic" in paths
    drawn = [c for c in html_commands(out) if c["type"] == "set_object" and c["path"] == "/polyhull/regions/dynamic"]
    assert len(drawn[-1]["object"]["geometries"][0]["data"]["index"]["array"].data) // 12 == len(faces)
    # The static region is drawn near the robot, and beyond (hidden), when it reaches there.
    drawn_static = {p for p in paths if p.startswith("/polyhull/regions/static/")}
    assert drawn_static and drawn_static <= {"/polyhull/regions/static/near", "/polyhull/regions/static/far"}
    assert not static.is_empty()
    has_distance = verdict.closest_points is not None and np.isfinite(verdict.min_distance)
    assert ("/polyhull/distance/segment" in paths) == has_distance
    # At most --max-points points per camera.
    for command in html_commands(out):
        if command["type"] == "set_object" and "/frames/" in command["path"]:
            position = command["object"]["geometries"][0]["data"]["attributes"]["position"]
            assert 0 < len(position["array"].data) // 12 <= 700


def test_frames_without_monitor_draws_point_clouds_only(
    tmp_path: Path, small_frames: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "polyhull.monitor", None)  # import fails
    out = tmp_path / "clouds.html"
    assert run_view(str(SMALL_CELL), "--frames", str(small_frames), "--html", str(out)) == 0
    assert "point clouds only" in capsys.readouterr().err
    paths = object_paths(out)
    assert any(p.startswith("/polyhull/frames/") for p in paths)
    assert not any(p.startswith("/polyhull/regions") or p.startswith("/polyhull/distance") for p in paths)


# -- errors ---------------------------------------------------------------------------------


def test_missing_viewer_is_a_missing_extra_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "polyhull_viewer", None)
    with pytest.raises(MissingExtraError, match=r"pip install 'polyhull\[viewer\]'"):
        run_view(str(PAPER_CELL), "--html", str(tmp_path / "x.html"))
    assert not (tmp_path / "x.html").exists()


def test_bad_input_raises_polyhull_errors(tmp_path: Path, small_frames: Path) -> None:
    with pytest.raises(PolyhullError):
        run_view(str(tmp_path / "missing.toml"), "--html", str(tmp_path / "x.html"))
    with pytest.raises(PolyhullError, match="max-points"):
        run_view(str(PAPER_CELL), "--html", str(tmp_path / "x.html"), "--max-points", "0")
    with pytest.raises(FrameError):
        run_view(str(PAPER_CELL), "--frames", str(tmp_path / "missing.npz"), "--html", str(tmp_path / "x.html"))
    # Frames of the small cell do not fit the paper cell's cameras.
    with pytest.raises(FrameError):
        run_view(str(PAPER_CELL), "--frames", str(small_frames), "--html", str(tmp_path / "x.html"))
    # The paper cell's frames hold two cameras the small cell does not have.
    paper_frames = ROOT / "fixtures" / "frames" / "paper_walk_000.npz"
    with pytest.raises(FrameError, match="frames of cameras nw, se, which the cell does not have"):
        run_view(str(SMALL_CELL), "--frames", str(paper_frames), "--html", str(tmp_path / "x.html"))
    assert not (tmp_path / "x.html").exists()


# -- the live server ------------------------------------------------------------------------


def _get(url: str) -> tuple[int, str]:
    with urllib.request.urlopen(url, timeout=10) as response:
        return response.status, response.read().decode("utf-8", "replace")


def _refused(url: str) -> bool:
    try:
        _get(url)
    except (urllib.error.URLError, ConnectionError, OSError):
        return True
    return False


def test_serve_seconds_closes_the_server(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    opened: list[polyhull_viewer.LiveViewer] = []
    urls: list[tuple[int, str]] = []

    class Recording(polyhull_viewer.LiveViewer):
        def __init__(self) -> None:
            super().__init__()
            opened.append(self)

        def close(self, timeout: float = 5.0) -> None:
            if not self.closed:
                urls.append(_get(self.url))  # still serving right before closing
            super().close(timeout)

    monkeypatch.setattr(polyhull_viewer, "LiveViewer", Recording)
    assert run_view(str(SMALL_CELL), "--serve-seconds", "0.2") == 0
    out = capsys.readouterr().out
    assert len(opened) == 1
    live = opened[0]
    assert f"at {live.url} (Ctrl-C to stop)" in out and "server stopped" in out
    assert urls[0][0] == 200 and "MeshCat" in urls[0][1]
    assert live.closed
    assert live.process is not None and live.process.poll() is not None
    assert _refused(live.url)
    live.close()  # idempotent


def test_server_is_closed_when_drawing_fails(small_frames: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    opened: list[polyhull_viewer.LiveViewer] = []

    class Recording(polyhull_viewer.LiveViewer):
        def __init__(self) -> None:
            super().__init__()
            opened.append(self)

    monkeypatch.setattr(polyhull_viewer, "LiveViewer", Recording)
    monkeypatch.setitem(sys.modules, "polyhull.monitor", None)
    # The small cell's frames have the wrong shape for the paper cell's cameras.
    with pytest.raises(FrameError, match="does not match"):
        run_view(str(PAPER_CELL), "--frames", str(small_frames), "--serve-seconds", "30")
    assert len(opened) == 1 and opened[0].closed
    assert opened[0].process is not None and opened[0].process.poll() is not None
    assert _refused(opened[0].url)


@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_signal_stops_serving_and_the_server(stop_signal: int) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", RUNNER, str(SMALL_CELL)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line)

    threading.Thread(target=pump, daemon=True).start()
    try:
        line = lines.get(timeout=60)
        match = re.search(r"at (http://\S+) \(Ctrl-C to stop\)", line)
        assert match is not None, line
        url = match.group(1)
        status, body = _get(url)
        assert status == 200 and "MeshCat" in body
        proc.send_signal(stop_signal)
        try:
            code = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:  # say where it hangs: every thread's stack
            proc.send_signal(signal.SIGUSR1)
            time.sleep(2.0)
            proc.kill()
            _, err = proc.communicate(timeout=10)
            rest = "".join(lines.get() for _ in range(lines.qsize()))
            pytest.fail(f"still running 30 s after the signal; stdout after the URL: {rest!r}; stderr:\n{err}")
        assert code == 0
        assert "server stopped" in lines.get(timeout=10)
        assert _refused(url)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_serving_stops_when_the_signal_reaches_another_thread() -> None:
    """The kernel may deliver Ctrl-C to any thread that does not block it (macOS does; Linux
    prefers the main thread), here a helper thread: Python's handler then waits for the main
    thread, which must not be inside one long sleep."""
    code = SIGINT_AS_IN_A_TERMINAL + (
        "import threading, time\n"
        "from polyhull.commands.view import _serve\n"
        "def poke():\n"
        "    time.sleep(0.5)\n"
        "    signal.pthread_kill(threading.get_ident(), signal.SIGINT)\n"
        "threading.Thread(target=poke).start()\n"
        "t = time.monotonic()\n"
        "_serve(None)\n"
        "print(f'stopped after {time.monotonic() - t:.1f} s')\n"
    )
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("still serving 30 s after Ctrl-C reached a thread other than the main one")
    assert proc.returncode == 0 and "stopped after" in proc.stdout, proc.stderr
