"""Standalone HTML scenes without a server: a visualizer that records meshcat commands.

:class:`StaticVisualizer` has the drawing interface of ``meshcat.Visualizer``
(``vis["a/b"].set_object(...)``, ``set_transform``, ``set_property``, ``set_animation``,
``delete``) but sends nothing anywhere: it keeps the scene tree the way the meshcat server
does and writes it as one HTML file that carries the meshcat/three.js bundle inline and
replays the commands when opened, so the file opens from disk with no server and no
network. ``meshcat.Visualizer.static_html()`` does the same but needs the meshcat server
process, two ports and a ZeroMQ round trip per command.

The tree is also what the tests inspect (:meth:`StaticVisualizer.object_paths`).
"""

from __future__ import annotations

import base64
import functools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import meshcat
import meshcat.commands as mc
import numpy as np
import umsgpack
from meshcat.path import Path as MeshcatPath

from polyhull.errors import PolyhullError

__all__ = ["VisualizerLike", "StaticVisualizer", "meshcat_bundle", "write_html"]


class VisualizerLike(Protocol):
    """What the drawing functions need: ``meshcat.Visualizer`` or :class:`StaticVisualizer`."""

    def __getitem__(self, path: str) -> VisualizerLike: ...

    def set_object(self, geometry: Any, material: Any = None) -> Any: ...

    def set_transform(self, matrix: Any = ...) -> Any: ...

    def set_property(self, key: str, value: Any) -> Any: ...

    def delete(self) -> Any: ...


@dataclass
class _Node:
    """One node of the scene tree: what the server keeps per path."""

    children: dict[str, _Node] = field(default_factory=dict)
    object: dict[str, Any] | None = None
    properties: dict[str, dict[str, Any]] = field(default_factory=dict)
    transform: dict[str, Any] | None = None

    def find(self, entries: tuple[str, ...], create: bool) -> _Node | None:
        node: _Node | None = self
        for name in entries:
            assert node is not None
            child = node.children.get(name)
            if child is None:
                if not create:
                    return None
                child = node.children[name] = _Node()
            node = child
        return node

    def walk(self, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], _Node]]:
        out = [(prefix, self)]
        for name, child in self.children.items():
            out.extend(child.walk(prefix + (name,)))
        return out


@dataclass
class _Scene:
    root: _Node = field(default_factory=_Node)
    animation: dict[str, Any] | None = None
    status: tuple[str, int] | None = None  # text, colour 0xRRGGBB
    timeline: dict[str, Any] | None = None  # times [s], texts, colours (one per cycle)


class StaticVisualizer:
    """A ``meshcat.Visualizer`` stand-in that records the scene and writes standalone HTML.

    Example::

        vis = StaticVisualizer()
        polyhull_viewer.draw_cell(vis, cell)
        Path("cell.html").write_text(vis.static_html())

    Like meshcat, a view ``vis["a/b"]`` shares the scene with ``vis``; paths starting with
    ``/`` are absolute, others relative to the view (the root view is ``/meshcat``).
    """

    __slots__ = ("path", "_scene")

    def __init__(self, *, _scene: _Scene | None = None, _path: MeshcatPath | None = None) -> None:
        self._scene = _scene if _scene is not None else _Scene()
        self.path = _path if _path is not None else MeshcatPath(("meshcat",))

    def __getitem__(self, path: str) -> StaticVisualizer:
        return StaticVisualizer(_scene=self._scene, _path=self.path.append(path))

    def __repr__(self) -> str:
        return f"<StaticVisualizer at path: {self.path.lower()}>"

    # -- the meshcat.Visualizer drawing interface -------------------------------------------
    def set_object(self, geometry: Any, material: Any = None) -> None:
        """Set the object at this path (a meshcat geometry and material, or an Object)."""
        cmd = mc.SetObject(geometry, material, self.path).lower()
        node = self._scene.root.find(self.path.entries, create=True)
        assert node is not None
        node.object = cmd

    def set_transform(self, matrix: Any = None) -> None:
        """Set the (4, 4) homogeneous transform of this path (identity when omitted)."""
        m = np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"set_transform at {self.path.lower()}: need a finite (4, 4) matrix")
        node = self._scene.root.find(self.path.entries, create=True)
        assert node is not None
        node.transform = mc.SetTransform(m, self.path).lower()

    def set_property(self, key: str, value: Any) -> None:
        """Set one property (``visible``, ``position``, ``color``, ...) of this path."""
        node = self._scene.root.find(self.path.entries, create=True)
        assert node is not None
        node.properties[key] = mc.SetProperty(key, value, self.path).lower()

    def set_animation(self, animation: Any, play: bool = True, repetitions: int = 1) -> None:
        """Set the scene's animation (a ``meshcat.animation.Animation``)."""
        self._scene.animation = mc.SetAnimation(animation, play=play, repetitions=repetitions).lower()

    def delete(self) -> None:
        """Delete this path and everything under it (the root: the whole scene)."""
        entries = self.path.entries
        if not entries:
            self._scene.root = _Node()
            return
        parent = self._scene.root.find(entries[:-1], create=False)
        if parent is not None:
            parent.children.pop(entries[-1], None)

    # -- the page's status line (HTML only) ----------------------------------------------------
    def set_status(self, text: str, color: int = 0x000000) -> None:
        """The status line shown as HTML text over the view (``#polyhull-status``).

        ``color`` (``0xRRGGBB``) is the colour of the swatch before the text.
        """
        self._scene.status = (str(text), int(color))

    def set_timeline(
        self, times: Any, texts: list[str], colors: list[int], duration: float
    ) -> None:
        """A status line per animation cycle, and a progress bar (``#polyhull-timeline``).

        Args:
            times: Start of each cycle in animation time [s], increasing (N,).
            texts: The status line of each cycle (N).
            colors: The swatch colour of each cycle (N), ``0xRRGGBB``.
            duration: Length of the animation [s].
        """
        t = [float(x) for x in np.asarray(times, dtype=np.float64).reshape(-1)]
        if not (len(t) == len(texts) == len(colors)) or not t:
            raise ValueError(
                f"set_timeline: need as many times ({len(t)}), texts ({len(texts)}) and "
                f"colours ({len(colors)}), at least one"
            )
        if any(b <= a for a, b in zip(t, t[1:], strict=False)):
            raise ValueError("set_timeline: times must increase")
        self._scene.timeline = {
            "times": t,
            "texts": [str(x) for x in texts],
            "colors": [f"#{int(c):06x}" for c in colors],
            "duration": float(duration),
        }

    @property
    def status(self) -> tuple[str, int] | None:
        """The status line (text, colour), if any."""
        return self._scene.status

    @property
    def timeline(self) -> dict[str, Any] | None:
        """The per-cycle status lines of the animation, if any."""
        return self._scene.timeline

    # -- inspection ---------------------------------------------------------------------------
    def object_paths(self) -> list[str]:
        """Paths (``/polyhull/robot/link_1``) that hold an object, in drawing order."""
        return ["/" + "/".join(p) for p, node in self._scene.root.walk() if node.object is not None]

    def node_info(self, path: str) -> dict[str, Any] | None:
        """The lowered commands kept at ``path`` (object, properties, transform), or None."""
        node = self._scene.root.find(MeshcatPath().append(path).entries, create=False)
        if node is None:
            return None
        return {
            "object": node.object,
            "properties": {k: v["value"] for k, v in node.properties.items()},
            "transform": node.transform,
            "children": list(node.children),
        }

    @property
    def animation(self) -> dict[str, Any] | None:
        """The lowered ``set_animation`` command, if any."""
        return self._scene.animation

    def commands(self) -> list[dict[str, Any]]:
        """Every lowered command, in the order the HTML replays them."""
        out: list[dict[str, Any]] = []
        for _, node in self._scene.root.walk():
            if node.object is not None:
                out.append(node.object)
            out.extend(node.properties.values())
            if node.transform is not None:
                out.append(node.transform)
        if self._scene.animation is not None:
            out.append(self._scene.animation)
        return out

    # -- output -----------------------------------------------------------------------------
    def static_html(self, title: str = "polyhull") -> str:
        """The scene as one standalone HTML document (meshcat bundle inline, no server)."""
        blobs = [base64.b64encode(umsgpack.packb(cmd)).decode("ascii") for cmd in self.commands()]
        status = self._scene.status
        timeline = self._scene.timeline
        if timeline is not None:  # the status line follows the animation
            text, color = timeline["texts"][0], timeline["colors"][0]
        elif status is not None:
            text, color = status[0], f"#{status[1]:06x}"
        else:
            text, color = "", "#000000"
        return _HTML_TEMPLATE.format(
            title=_escape_html(title),
            bundle=meshcat_bundle(),
            commands=json.dumps(blobs),
            status=_escape_html(text),
            status_display="flex" if text else "none",
            swatch=color,
            timeline_display="block" if timeline else "none",
            timeline=_script_json(timeline),
        )


def _escape_html(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _script_json(value: Any) -> str:
    """JSON safe inside a <script> element (no '</' can close it)."""
    return json.dumps(value).replace("</", "<\\/")


@functools.cache
def meshcat_bundle() -> str:
    """The meshcat viewer's JavaScript bundle (three.js included), as shipped with meshcat."""
    path = Path(os.path.dirname(meshcat.__file__)) / "viewer" / "dist" / "main.min.js"
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise PolyhullError(
            f"{path}: the meshcat viewer bundle is missing ({exc}); reinstall meshcat: "
            "pip install --force-reinstall 'polyhull[viewer]'"
        ) from exc
    if "</script" in text.lower():
        raise PolyhullError(f"{path}: the bundle contains '</script' and cannot be inlined")
    return text


# The commands are decoded synchronously and in order (meshcat's own static HTML fetches
# data: URLs, whose promises may resolve out of order). The status line sits over the view;
# with a timeline it follows the animation's time (meshcat's animator), the animation
# controls are shown open, and the animation redraws at 20 Hz.
_HTML_TEMPLATE = """<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ margin: 0; }}
#meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
#polyhull-overlay {{ position: absolute; left: 12px; top: 12px; max-width: 60vw;
  font: 16px/1.35 sans-serif; color: #111; pointer-events: none; }}
#polyhull-status {{ display: {status_display}; align-items: center; gap: 8px;
  background: rgba(255, 255, 255, 0.85); padding: 6px 10px; border-radius: 4px; }}
#polyhull-swatch {{ width: 14px; height: 14px; border-radius: 7px; flex: none;
  background: {swatch}; }}
#polyhull-timeline {{ display: {timeline_display}; margin-top: 6px; height: 6px; width: 320px;
  background: rgba(0, 0, 0, 0.15); border-radius: 3px; }}
#polyhull-progress {{ height: 100%; width: 0%; background: #333; border-radius: 3px; }}
</style>
</head>
<body>
<div id="meshcat-pane"></div>
<div id="polyhull-overlay">
<div id="polyhull-status"><span id="polyhull-swatch"></span><span id="polyhull-text">{status}</span></div>
<div id="polyhull-timeline"><div id="polyhull-progress"></div></div>
</div>
<script>
{bundle}
</script>
<script>
var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
(function () {{
  var commands = {commands};
  for (var i = 0; i < commands.length; i++) {{
    var text = atob(commands[i]);
    var bytes = new Uint8Array(text.length);
    for (var j = 0; j < text.length; j++) {{ bytes[j] = text.charCodeAt(j); }}
    viewer.handle_command_bytearray(bytes);
  }}
}})();
(function () {{
  var timeline = {timeline};
  if (!timeline) {{ return; }}
  viewer.gui.open();
  // The animation advances (and the scene redraws) at most 20 times a second: smooth enough
  // for cycles of a tenth of a second or more, and a third of the drawing at 60 Hz, which
  // is what a browser without a GPU (software WebGL) spends its time on.
  var animator = viewer.animator, advance = animator.update.bind(animator), last = -Infinity;
  animator.update = function () {{
    var now = performance.now();
    if (now - last < 50) {{ return; }}
    last = now;
    advance();
  }};
  var text = document.getElementById("polyhull-text");
  var swatch = document.getElementById("polyhull-swatch");
  var progress = document.getElementById("polyhull-progress");
  var shown = -1;
  function update() {{
    var t = viewer.animator ? viewer.animator.time : 0;
    var k = 0;
    while (k + 1 < timeline.times.length && timeline.times[k + 1] <= t) {{ k++; }}
    if (k !== shown) {{
      text.textContent = timeline.texts[k];
      swatch.style.background = timeline.colors[k];
      shown = k;
    }}
    var share = timeline.duration > 0 ? Math.min(1, Math.max(0, t / timeline.duration)) : 0;
    progress.style.width = (100 * share).toFixed(1) + "%";
    requestAnimationFrame(update);
  }}
  update();
}})();
</script>
</body>
</html>
"""


def write_html(vis: Any, path: str | Path, title: str = "polyhull") -> Path:
    """Write the scene of ``vis`` to ``path`` as standalone HTML; return the path.

    Args:
        vis: A :class:`StaticVisualizer`, or a ``meshcat.Visualizer`` (whose server is
            asked for its scene).
        path: Output file; parent directories are created.
        title: Page title.
    """
    out = Path(path)
    html = vis.static_html(title=title) if isinstance(vis, StaticVisualizer) else vis.static_html()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(html, encoding="utf-8")
    except OSError as exc:
        raise PolyhullError(f"{out}: cannot write the HTML scene ({exc})") from exc
    return out
