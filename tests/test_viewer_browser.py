"""The standalone HTML renders in a real browser: what a person sees in headless Chromium.

Screenshots at the default view (meshcat's perspective camera: 75 degree vertical field
of view, at ``view_pose``'s eye, looking at the scene origin) must not be blank or an error
page; the robot's colour must appear where the robot projects; the dynamic region's red
must appear where the person projects in a person scene and not at all in an empty one;
the red share of the picture is bounded (the static blind space never paints the zone as
one red box); the distance line is text in the page's DOM. The demo page autoplays with
meshcat's animation controls open.

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it); without it the tests
are skipped. WebGL runs on SwiftShader (software), so no GPU is needed.
"""

from __future__ import annotations

import argparse
import colorsys
import os
import re
import shutil
import subprocess
from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
from PIL import Image

import polyhull_viewer as pv
from polyhull.cell import Cell
from polyhull.cellfile import load_cell
from polyhull.commands import view
from polyhull.robot import Robot
from polyhull_viewer._scene import view_pose

pytestmark = pytest.mark.browser

ROOT = Path(__file__).resolve().parents[1]
PAPER_CELL = ROOT / "fixtures" / "cells" / "paper_cell.toml"
WIDTH, HEIGHT = 1024, 768
FOV_DEG = 75.0  # meshcat's default PerspectiveCamera


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("chromium not installed: apt-get install chromium")


def screenshot(html: Path, png: Path, dom: list[str] | None = None) -> np.ndarray:
    """Render ``html`` in headless Chromium and return the screenshot as (H, W, 3) uint8.

    With ``dom``, the page's DOM after its scripts ran is appended to it (same run).
    """
    browser = _chromium()
    command = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={png.parent / 'chromium-profile'}",
        f"--screenshot={png}",
        f"--window-size={WIDTH},{HEIGHT}",
        "--virtual-time-budget=10000",
        *(["--dump-dom"] if dom is not None else []),
        html.resolve().as_uri(),
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert png.is_file(), f"no screenshot (exit {result.returncode}): {result.stderr[-2000:]}"
    if dom is not None:
        dom.append(result.stdout)
    keep = os.environ.get("POLYHULL_SCREENSHOT_DIR")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(png, Path(keep) / png.name)
    return np.asarray(Image.open(png).convert("RGB"))


def project(cell: Cell, points_world: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Pixel coordinates (N, 2) of world points through the default view of ``cell``."""
    T_scene_world, eye = view_pose(cell)
    p = points_world + T_scene_world[:3, 3]
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    d = p - eye
    x, y, z = d @ right, d @ up, d @ forward
    h, w = shape
    t = np.tan(np.deg2rad(FOV_DEG) / 2.0)
    return np.column_stack([(x / (z * t * w / h) + 1.0) / 2.0 * w, (1.0 - y / (z * t)) / 2.0 * h])


def hue_mask(image: np.ndarray, hex_color: int, tol: float = 0.07) -> np.ndarray:
    """Saturated pixels whose hue is within ``tol`` (of a full turn) of ``hex_color``'s."""
    rgb = image.astype(np.float64) / 255.0
    mx, mn = rgb.max(axis=2), rgb.min(axis=2)
    chroma = mx - mn
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    safe = np.where(chroma > 0, chroma, 1.0)
    hue = np.where(
        mx == r,
        ((g - b) / safe) % 6.0,
        np.where(mx == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0),
    ) / 6.0
    target_hue = colorsys.rgb_to_hsv(*pv.hex_to_rgb(hex_color))[0]
    distance = np.abs((hue - target_hue + 0.5) % 1.0 - 0.5)
    return (chroma > 0.35) & (mx > 0.45) & (distance < tol)


def assert_not_blank(image: np.ndarray) -> None:
    quantised = (image // 16).reshape(-1, 3)
    colours, counts = np.unique(quantised, axis=0, return_counts=True)
    assert len(colours) > 60, f"only {len(colours)} distinct colours: blank or error page"
    assert counts.max() < 0.7 * len(quantised), "one colour fills most of the page"


def test_paper_cell_renders_with_the_robot_where_it_stands(tmp_path: Path) -> None:
    _chromium()
    html = tmp_path / "cell.html"
    parser = argparse.ArgumentParser()
    view.register(parser.add_subparsers())
    args = parser.parse_args(["view", str(PAPER_CELL), "--html", str(html)])
    assert args.func(args) == 0

    image = screenshot(html, tmp_path / "paper_cell.png")
    assert image.shape[:2] == (HEIGHT, WIDTH)
    assert_not_blank(image)

    cell = load_cell(PAPER_CELL)
    assert cell.robot is not None
    meshes = Robot.from_spec(cell.robot).visual_meshes(cell.robot.q)
    uv = project(cell, np.concatenate([m.vertices for m in meshes.values()]), image.shape[:2])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    assert np.all(lo > 0) and np.all(hi < [WIDTH, HEIGHT])  # the view frames the robot

    orange = hue_mask(image, pv.STYLE.robot)
    ys, xs = np.nonzero(orange)
    assert len(xs) > 300, f"only {len(xs)} robot-coloured pixels"
    inside = (xs >= lo[0] - 8) & (xs <= hi[0] + 8) & (ys >= lo[1] - 8) & (ys <= hi[1] + 8)
    assert inside.mean() > 0.95, f"robot pixels outside its projected box {lo}..{hi}"
    # The robot fills a good part of its box (it is drawn, not a stray pixel).
    box_area = float(np.prod(hi - lo))
    assert len(xs) > 0.15 * box_area


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> m3.Manifold:
    size = tuple(b - a for a, b in zip(lo, hi, strict=True))
    return m3.Manifold.cube(size).translate(lo)


PERSON_LO, PERSON_HI = (1.5, 1.8, 0.0), (2.0, 2.2, 1.8)


def _static_region() -> m3.Manifold:
    """Blind space as the engine finds it: under the ceiling, behind the tables and the rack."""
    return (
        _box((0.0, 0.0, 2.7), (6.0, 6.0, 3.5))
        + _box((2.2, 0.85, 0.0), (3.8, 1.4, 0.8))
        + _box((4.6, 2.2, 0.0), (5.15, 3.8, 0.8))
        + _box((0.8, 3.3, 0.0), (1.4, 5.1, 2.0))
    )


def _verdict(cell: Cell, dynamic: m3.Manifold, speed: float) -> object:
    """A verdict with the given dynamic region, the static region above, and a distance."""
    static = _static_region()
    assert cell.robot is not None
    empty = m3.Manifold()
    q = np.asarray(cell.robot.q)
    if dynamic.is_empty():
        points, distance, link = None, float("inf"), None
    else:
        points = np.array([[2.0, 2.2, 1.0], [2.8, 2.9, 1.0]])
        distance, link = float(np.linalg.norm(points[1] - points[0])), "link_3"

    class Verdict:
        region = static + dynamic
        region_dynamic = dynamic
        hull = robot_occlusion = region_r2 = empty
        removed = ()
        min_distance = distance
        closest_points = points
        closest_link = link
        speed_scale = speed

    Verdict.q = q  # type: ignore[attr-defined]
    return Verdict()


def _red(image: np.ndarray) -> np.ndarray:
    return hue_mask(image, pv.STYLE.region, tol=0.04)


def test_person_scene_shows_the_person_region_and_the_distance_in_the_dom(tmp_path: Path) -> None:
    _chromium()
    cell = load_cell(PAPER_CELL)
    person = _box(PERSON_LO, PERSON_HI)
    vis = pv.StaticVisualizer()
    pv.draw_scene(vis, cell, verdict=_verdict(cell, person, speed=0.62), static_region=_static_region())  # type: ignore[arg-type]
    dom: list[str] = []
    image = screenshot(pv.write_html(vis, tmp_path / "person.html"), tmp_path / "person.png", dom)
    assert_not_blank(image)

    corners = np.array([[x, y, z] for x in (PERSON_LO[0], PERSON_HI[0]) for y in (PERSON_LO[1], PERSON_HI[1]) for z in (PERSON_LO[2], PERSON_HI[2])])
    uv = project(cell, corners, image.shape[:2])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    red = _red(image)
    ys, xs = np.nonzero(red)
    inside = (xs >= lo[0] - 8) & (xs <= hi[0] + 8) & (ys >= lo[1] - 8) & (ys <= hi[1] + 8)
    assert inside.sum() > 0.3 * float(np.prod(hi - lo)), f"only {inside.sum()} red pixels where the person is"
    assert inside.mean() > 0.95, "red pixels away from the person: the static region is not faint"
    # The zone is not one red box: the red share of the whole picture is small.
    assert red.mean() < 0.05, f"red share {red.mean():.3f}"
    # The robot still shows in its colour.
    assert hue_mask(image, 0xFF6B00).sum() > 300
    # The distance line is text in the page, as a person reads it.
    match = re.search(r'<span id="polyhull-text">([^<]*)</span>', dom[0])
    assert match is not None and match.group(1) == "1.06 m to link_3, speed 62 %"


def test_empty_scene_has_no_dynamic_region_pixels(tmp_path: Path) -> None:
    _chromium()
    cell = load_cell(PAPER_CELL)
    vis = pv.StaticVisualizer()
    pv.draw_scene(vis, cell, verdict=_verdict(cell, m3.Manifold(), speed=1.0), static_region=_static_region())  # type: ignore[arg-type]
    image = screenshot(pv.write_html(vis, tmp_path / "empty.html"), tmp_path / "empty.png")
    assert_not_blank(image)
    assert _red(image).sum() < 30, f"{_red(image).sum()} red pixels in an empty cell"
    assert hue_mask(image, 0xFF6B00).sum() > 300


def test_demo_page_autoplays_with_its_controls_and_status_line(tmp_path: Path) -> None:
    _chromium()
    cell = load_cell(PAPER_CELL)
    assert cell.robot is not None
    robot = Robot.from_spec(cell.robot)
    recorder = pv.DemoRecorder(cell, robot=robot, static_region=_static_region())
    q0 = np.asarray(cell.robot.q)
    person = _box(PERSON_LO, PERSON_HI)
    for k in range(4):  # the person stands still; the robot turns
        q = q0 + np.array([0.2 * k, 0, 0, 0, 0, 0])
        recorder.add_cycle(0.5 * k, q, [], _verdict(cell, person, speed=0.25 * k))  # type: ignore[arg-type]
    html = recorder.write_html(tmp_path / "demo.html")
    assert html.stat().st_size < 5_000_000
    dom: list[str] = []
    image = screenshot(html, tmp_path / "demo.png", dom)
    assert_not_blank(image)
    assert "Close Controls" in dom[0]  # meshcat's controls (with the animation's) are open
    match = re.search(r'<span id="polyhull-text">([^<]*)</span>', dom[0])
    assert match is not None and re.fullmatch(r"t = \d\.\d s: 1\.06 m to link_3, speed \d+ %", match.group(1))
    corners = np.array([PERSON_LO, PERSON_HI])
    uv = project(cell, corners, image.shape[:2])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    ys, xs = np.nonzero(_red(image))
    inside = (xs >= lo[0] - 8) & (xs <= hi[0] + 8) & (ys >= lo[1] - 8) & (ys <= hi[1] + 8)
    assert inside.sum() > 500
