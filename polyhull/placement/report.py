"""Reports of a placement run: JSON, Markdown, a convergence plot and the optimised cell.

- :func:`build_report` gathers the before and after values of every objective, their
  distance to f_opt and the camera parameters into one JSON-ready dictionary;
- :func:`write_json` and :func:`write_markdown` write it;
- :func:`plot_convergence` draws the objective of every evaluation and the best so far,
  with f_opt, per camera count (PNG, matplotlib, headless);
- :func:`write_cell_toml` writes the cell with the optimised cameras as a cell file that
  :func:`polyhull.load_cell` reads back (camera poses as quaternions).
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..cell import Cell
from ..errors import CellError, MissingExtraError
from ..typed import ArrayF64
from .objectives import OBJECTIVES, Objectives, PlacementProblem
from .optimizer import OptimizationResult

__all__ = [
    "rotation_to_quaternion",
    "camera_entry",
    "camera_summary",
    "build_report",
    "write_json",
    "write_markdown",
    "markdown_report",
    "plot_convergence",
    "cell_mapping",
    "toml_text",
    "write_cell_toml",
]


def rotation_to_quaternion(R: ArrayF64) -> tuple[float, float, float, float]:
    """Unit quaternion ``(w, x, y, z)`` of a rotation matrix (w >= 0)."""
    R = np.asarray(R, dtype=np.float64)
    trace = float(np.trace(R))
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    qa = np.asarray(q)
    qa /= np.linalg.norm(qa)
    if qa[0] < 0:
        qa = -qa
    return (float(qa[0]), float(qa[1]), float(qa[2]), float(qa[3]))


def camera_entry(camera: Camera) -> dict[str, Any]:
    """The ``[[cameras]]`` entry of a camera (pose as a quaternion)."""
    k = camera.intrinsics
    return {
        "name": camera.name,
        "type": camera.kind,
        "resolution": [int(k.width), int(k.height)],
        "intrinsics": [float(k.fx), float(k.fy), float(k.cx), float(k.cy)],
        "position": [round(float(x), 6) for x in camera.center],
        "quaternion": [round(x, 9) for x in rotation_to_quaternion(camera.T_world_camera[:3, :3])],
        "range": [float(camera.near), float(camera.far)],
        "noise": float(camera.noise),
        "tolerance_sigmas": float(camera.tolerance_sigmas),
        "tolerance_min": float(camera.tolerance_min),
    }


def camera_summary(camera: Camera) -> dict[str, Any]:
    """Readable parameters of a camera: position, look direction, pan and tilt, focal length."""
    forward = camera.T_world_camera[:3, 2]
    k = camera.intrinsics
    return {
        "name": camera.name,
        "type": camera.kind,
        "position": [round(float(x), 4) for x in camera.center],
        "look_direction": [round(float(x), 4) for x in forward],
        "pan_deg": round(math.degrees(math.atan2(forward[1], forward[0])), 2),
        "tilt_deg": round(math.degrees(math.asin(max(-1.0, min(1.0, -forward[2])))), 2),
        "fx": round(float(k.fx), 3),
        "fov_deg": [
            round(math.degrees(2 * math.atan(k.width / 2 / k.fx)), 2),
            round(math.degrees(2 * math.atan(k.height / 2 / k.fy)), 2),
        ],
        "quaternion": [round(x, 6) for x in rotation_to_quaternion(camera.T_world_camera[:3, :3])],
    }


def _values(obj: Objectives, optimum: Objectives) -> dict[str, Any]:
    return {
        name: {"value": obj[name], "f_opt": optimum[name], "gap": obj[name] - optimum[name]}
        for name in OBJECTIVES
    } | {
        "volumes_m3": {
            "free": obj.free,
            "changed": obj.changed,
            "undetectable": obj.undetectable,
            "free_k": obj.free_k,
            "changed_k": obj.changed_k,
            "undetectable_k": obj.undetectable_k,
        }
    }


def build_report(
    cell: Cell,
    problem: PlacementProblem,
    before: Objectives,
    chosen: OptimizationResult,
    results: Sequence[OptimizationResult],
    settings: Mapping[str, Any],
) -> dict[str, Any]:
    """The report of a placement run as a JSON-ready dictionary.

    Args:
        cell: The cell as given (its cameras are the "before" placement).
        problem: The placement problem.
        before: Objective values of the cell's own cameras.
        chosen: The chosen result (see :func:`~polyhull.placement.optimizer.optimize_counts`).
        results: The results of every camera count.
        settings: Run settings to record (budget, seed, workers, scenes...).
    """
    optimum = chosen.optimum
    grid = problem.grid
    return {
        "cell": cell.name,
        "cell_file": str(cell.path) if cell.path else None,
        "objective": chosen.objective,
        "units": "f1: m^3; f2: m^3 x importance weight; f3, f4: m^3 x (w1 | w2)",
        "weights": {"w1": problem.params.w1, "w2": problem.params.w2, "k_of_n": problem.params.k},
        "grid": {
            "shape": list(grid.shape),
            "voxel_size_m": [float(x) for x in grid.spacing],
            "voxel_volume_m3": grid.voxel_volume,
            "zone_volume_m3": grid.volume,
        },
        "target_scenes": len(problem.target_scenes),
        "pixel_step": problem.step,
        "settings": dict(settings),
        "before": _values(before, optimum),
        "after": _values(chosen.best, optimum),
        "f_opt": {name: optimum[name] for name in OBJECTIVES},
        "improvement": {
            "absolute": before[chosen.objective] - chosen.best_value,
            "relative": (before[chosen.objective] - chosen.best_value) / before[chosen.objective]
            if before[chosen.objective] > 0
            else 0.0,
        },
        "cameras_before": [camera_summary(c) for c in cell.cameras],
        "cameras_after": [camera_summary(c) for c in chosen.cameras],
        "mounting_after": [
            {
                "name": cam.name,
                "surface": s.surface,
                "a": round(s.a, 6),
                "b": round(s.b, 6),
                "focal_scale": round(s.focal_scale, 6),
            }
            for cam, s in zip(chosen.cameras, chosen.parameterisation.settings(chosen.best_x), strict=True)
        ],
        "runs": [
            {
                "cameras": len(r.cameras),
                "method": r.method,
                "best": r.best_value,
                "gap_to_f_opt": r.gap,
                "evaluations": r.evaluations,
                "seconds": r.seconds,
                "evaluations_per_second": r.evaluations / r.seconds if r.seconds > 0 else None,
                "stop_reason": r.stop_reason,
                "restarts": r.restarts,
            }
            for r in results
        ],
    }


def write_json(report: Mapping[str, Any], path: str | os.PathLike[str]) -> Path:
    """Write the report as indented JSON; return the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return out


def _fmt(x: float) -> str:
    return f"{x:.4g}" if abs(x) < 1e4 else f"{x:.1f}"


def markdown_report(report: Mapping[str, Any]) -> str:
    """The report as Markdown text."""
    lines = [
        f"# Sensor placement: {report['cell']}",
        "",
        f"Objective minimised: **{report['objective']}** ({report['units']}).",
        f"Weights w1 = {report['weights']['w1']}, w2 = {report['weights']['w2']}, "
        f"k-of-n k = {report['weights']['k_of_n']}. Grid {' x '.join(map(str, report['grid']['shape']))} "
        f"voxels of {report['grid']['voxel_volume_m3']:.3g} m^3 over "
        f"{report['grid']['zone_volume_m3']:.4g} m^3; {report['target_scenes']} target scenes "
        f"(values are means over them); pixel step {report['pixel_step']}.",
        "",
        "## Objectives",
        "",
        "| objective | before | after | f_opt | before - f_opt | after - f_opt |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in OBJECTIVES:
        b, a = report["before"][name], report["after"][name]
        lines.append(
            f"| {name} | {_fmt(b['value'])} | {_fmt(a['value'])} | {_fmt(a['f_opt'])} | "
            f"{_fmt(b['gap'])} | {_fmt(a['gap'])} |"
        )
    lines += [
        "",
        "Volumes [m^3] (plain rule / k-of-n rule):",
        "",
        "| section | before | after |",
        "|---|---:|---:|",
    ]
    for key in ("free", "changed", "undetectable"):
        b = report["before"]["volumes_m3"]
        a = report["after"]["volumes_m3"]
        lines.append(
            f"| {key} | {_fmt(b[key])} / {_fmt(b[key + '_k'])} | {_fmt(a[key])} / {_fmt(a[key + '_k'])} |"
        )
    lines += ["", "## Runs", "", "| cameras | best | best - f_opt | evaluations | s | eval/s | stop |", "|---:|---:|---:|---:|---:|---:|---|"]
    for r in report["runs"]:
        eps = r["evaluations_per_second"]
        lines.append(
            f"| {r['cameras']} | {_fmt(r['best'])} | {_fmt(r['gap_to_f_opt'])} | {r['evaluations']} | "
            f"{r['seconds']:.1f} | {eps:.3g} | {r['stop_reason']} |"
            if eps is not None
            else f"| {r['cameras']} | {_fmt(r['best'])} | {_fmt(r['gap_to_f_opt'])} | {r['evaluations']} | "
            f"{r['seconds']:.1f} | - | {r['stop_reason']} |"
        )
    for title, key in (("Cameras before", "cameras_before"), ("Cameras after", "cameras_after")):
        lines += [
            "",
            f"## {title}",
            "",
            "| name | position [m] | pan [deg] | tilt [deg] | fx [px] | fov [deg] |",
            "|---|---|---:|---:|---:|---|",
        ]
        for c in report[key]:
            pos = ", ".join(f"{x:.3f}" for x in c["position"])
            fov = " x ".join(f"{x:.1f}" for x in c["fov_deg"])
            lines.append(
                f"| {c['name']} | ({pos}) | {c['pan_deg']:.1f} | {c['tilt_deg']:.1f} | {c['fx']:.1f} | {fov} |"
            )
    lines += ["", "Mounting of the optimised cameras:", ""]
    for m in report["mounting_after"]:
        lines.append(f"- {m['name']}: {m['surface']} at (a, b) = ({m['a']:.3f}, {m['b']:.3f})")
    return "\n".join(lines) + "\n"


def write_markdown(report: Mapping[str, Any], path: str | os.PathLike[str]) -> Path:
    """Write the report as Markdown; return the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(markdown_report(report), encoding="utf-8")
    return out


def plot_convergence(
    results: Sequence[OptimizationResult],
    path: str | os.PathLike[str],
    before: float | None = None,
    title: str | None = None,
) -> Path:
    """Convergence plot (PNG): every evaluation and the best so far, per camera count.

    Args:
        results: Optimisation results (one per camera count) of the same objective.
        path: Output PNG file.
        before: Objective value of the start placement (drawn as a dotted line).
        title: Plot title.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise MissingExtraError("the convergence plot", "placement") from exc
    if not results:
        raise CellError("no optimisation result to plot")
    objective = results[0].objective
    fig, ax = plt.subplots(figsize=(7.5, 4.5), dpi=120)
    for n, r in enumerate(results):
        color = f"C{n}"
        evals = np.arange(1, r.evaluations + 1)
        label = f"{len(r.cameras)} cameras"
        ax.scatter(evals, r.values, s=6, color=color, alpha=0.35)
        ax.step(evals, r.best_so_far, where="post", color=color, label=f"best, {label}")
    ax.axhline(results[0].optimum[objective], color="k", linestyle="--", label="f_opt")
    if before is not None:
        ax.axhline(before, color="gray", linestyle=":", label="before")
    ax.set_xlabel("evaluation")
    ax.set_ylabel(f"{objective} [m^3, weighted]")
    ax.set_title(title or f"placement convergence ({objective})")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def _relative_path(value: str, source_dir: Path, target_dir: Path) -> str:
    p = Path(value)
    if not p.is_absolute():
        p = (source_dir / p).resolve()
    try:
        return os.path.relpath(p, target_dir)
    except ValueError:  # another drive (Windows)
        return str(p)


def cell_mapping(cell: Cell, cameras: Sequence[Camera], target_dir: Path) -> dict[str, Any]:
    """The cell file mapping of ``cell`` with ``cameras`` instead of its own.

    The cell's own file is read again and only its ``cameras`` are replaced, so every other
    entry (comments aside) is kept; relative paths (robot URDF, obstacle meshes) are
    rewritten relative to ``target_dir``.

    Raises:
        CellError: The cell was not read from a file.
    """
    if cell.path is None:
        raise CellError(
            f"cell '{cell.name}' was not read from a cell file, so it cannot be written back; "
            "load it with polyhull.load_cell"
        )
    source = Path(cell.path)
    try:
        data = tomllib.loads(source.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CellError(f"{source}: cannot read the cell file again: {exc}") from None
    src_dir = source.parent
    if isinstance(data.get("robot"), dict) and "urdf" in data["robot"]:
        data["robot"]["urdf"] = _relative_path(data["robot"]["urdf"], src_dir, target_dir)
    for obstacle in data.get("obstacles", []):
        if isinstance(obstacle, dict) and "mesh" in obstacle:
            obstacle["mesh"] = _relative_path(obstacle["mesh"], src_dir, target_dir)
    data["cameras"] = [camera_entry(c) for c in cameras]
    k = data.get("reconstruction", {}).get("k_of_n")
    if isinstance(k, int) and k > len(cameras):
        data["reconstruction"]["k_of_n"] = len(cameras)
    return data


def _toml_key(key: str) -> str:
    if key and all(c.isalnum() or c in "_-" for c in key):
        return key
    return json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        v = float(value)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, Mapping):
        inner = ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items())
        return "{ " + inner + " }" if inner else "{}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise CellError(f"cannot write a {type(value).__name__} value to TOML: {value!r}")


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, Mapping) for v in value)


def _write_table(lines: list[str], name: str, table: Mapping[str, Any], inline: bool = False) -> None:
    """Write ``table``; with ``inline``, its sub-tables become inline tables."""
    plain = {
        k: v
        for k, v in table.items()
        if not ((isinstance(v, Mapping) and not inline) or _is_table_array(v))
    }
    nested = {k: v for k, v in table.items() if k not in plain}
    for k, v in plain.items():
        lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in nested.items():
        full = f"{name}.{_toml_key(k)}" if name else _toml_key(k)
        if isinstance(v, Mapping):
            lines += ["", f"[{full}]"]
            _write_table(lines, full, v)
        else:
            for entry in v:
                lines += ["", f"[[{full}]]"]
                _write_table(lines, full, entry, inline=True)


def toml_text(data: Mapping[str, Any], header: str = "") -> str:
    """A TOML document of ``data`` (tables, arrays of tables, inline values)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    if lines:
        lines.append("")
    _write_table(lines, "", data)
    return "\n".join(lines).strip("\n") + "\n"


def write_cell_toml(
    cell: Cell, cameras: Sequence[Camera], path: str | os.PathLike[str], header: str = ""
) -> Path:
    """Write ``cell`` with ``cameras`` as a cell file that :func:`polyhull.load_cell` reads.

    Args:
        cell: The cell (read from a file).
        cameras: The cameras to write instead of the cell's.
        path: Output ``.toml`` file.
        header: Comment lines for the top of the file.
    """
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    data = cell_mapping(cell, cameras, out.resolve().parent)
    out.write_text(toml_text(data, header), encoding="utf-8")
    return out
