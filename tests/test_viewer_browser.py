"""The standalone HTML renders in a real browser: headless Chromium takes a screenshot.

The screenshot must not be blank or an error page, and the robot's orange must appear
exactly where the robot projects through the default view (meshcat's perspective camera:
75 degree vertical field of view, at ``view_pose``'s eye, looking at the scene origin).

Chromium is Debian's ``chromium`` package (``.ci/run`` installs it); without it the tests
are skipped. WebGL runs on SwiftShader (software), so no GPU is needed.
"""

from __future__ import annotations

import argparse
import colorsys
import os
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


def screenshot(html: Path, png: Path) -> np.ndarray:
    """Render ``html`` in headless Chromium and return the screenshot as (H, W, 3) uint8."""
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
        html.resolve().as_uri(),
    ]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert png.is_file(), f"no screenshot (exit {result.returncode}): {result.stderr[-2000:]}"
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


def test_regions_render_where_they_are(tmp_path: Path) -> None:
    """A verdict's region R shows in its colour at its projected place."""
    _chromium()
    cell = load_cell(PAPER_CELL)
    region = m3.Manifold.cube((0.6, 0.6, 1.8)).translate((1.0, 1.2, 0.0))
    empty = m3.Manifold()

    class Verdict:
        hull = region
        robot_occlusion = empty
        region_r2 = region
        removed = ()
        min_distance = float("inf")
        closest_points = None
        closest_link = None
        speed_scale = 1.0
        q = np.asarray(cell.robot.q if cell.robot else [])

    Verdict.region = region  # type: ignore[attr-defined]
    vis = pv.StaticVisualizer()
    pv.draw_scene(vis, cell, verdict=Verdict())  # type: ignore[arg-type]
    html = pv.write_html(vis, tmp_path / "region.html")
    image = screenshot(html, tmp_path / "region.png")
    assert_not_blank(image)

    corners = np.array([[x, y, z] for x in (1.0, 1.6) for y in (1.2, 1.8) for z in (0.0, 1.8)])
    uv = project(cell, corners, image.shape[:2])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    red = hue_mask(image, pv.STYLE.region, tol=0.04)
    ys, xs = np.nonzero(red)
    assert len(xs) > 200, f"only {len(xs)} region-coloured pixels"
    inside = (xs >= lo[0] - 8) & (xs <= hi[0] + 8) & (ys >= lo[1] - 8) & (ys <= hi[1] + 8)
    assert inside.mean() > 0.95
