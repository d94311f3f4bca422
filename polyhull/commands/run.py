"""``polyhull run CELL --frames FRAMES.npz [--json] [--export DIR]``: one cycle from recorded frames."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

from ..errors import PolyhullError

__all__ = ["register", "export_regions"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``run`` sub-command."""
    p = subparsers.add_parser(
        "run",
        help="run one surveillance cycle on recorded frames",
        description=(
            "Run one surveillance cycle of CELL on a frames file (.npz: one float32 (H, W) "
            "depth array [m] per camera name, plus q and stamp) and print the verdict."
        ),
    )
    p.add_argument("cell", type=Path, help="cell file (TOML)")
    p.add_argument("--frames", type=Path, required=True, help="frames file (.npz)")
    p.add_argument("--json", action="store_true", help="print one JSON object (SPEC section 6)")
    p.add_argument("--export", type=Path, metavar="DIR", help="write hull.ply, robot_occlusion.ply, region.ply")
    p.set_defaults(func=_run)


def export_regions(verdict: object, directory: Path) -> list[Path]:
    """Write C, M and R of a verdict as watertight PLY files (world frame) into ``directory``."""
    import numpy as np
    import trimesh

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name in ("hull", "robot_occlusion", "region"):
        manifold = getattr(verdict, name)
        mesh = manifold.to_mesh64()
        tm = trimesh.Trimesh(
            vertices=np.asarray(mesh.vert_properties)[:, :3], faces=np.asarray(mesh.tri_verts), process=False
        )
        path = directory / f"{name}.ply"
        tm.export(path)
        written.append(path)
    return written


def _run(args: argparse.Namespace) -> int:
    from ..cellfile import load_cell
    from ..frames import load_frames
    from ..monitor import Monitor

    cell = load_cell(args.cell)
    recorded = load_frames(args.frames)
    missing = [c.name for c in cell.cameras if c.name not in recorded.frames]
    monitor = Monitor(cell)
    verdict = monitor.step(recorded.frames, recorded.q, stamp=recorded.stamp)
    if args.export is not None:
        try:
            paths = export_regions(verdict, args.export)
        except OSError as exc:
            raise PolyhullError(f"--export {args.export}: cannot write ({exc})") from exc
    if args.json:
        print(json.dumps(verdict.to_json(), indent=2))
    else:
        vols = verdict.volumes()
        d = verdict.min_distance
        print(f"cell            {cell.name} ({args.cell})")
        print(f"frames          {args.frames} ({len(recorded.frames)} cameras, stamp {recorded.stamp:.3f} s)")
        if missing:
            print(f"missing frames  {', '.join(missing)}")
        print(f"hull C          {vols['volume_hull']:.3f} m^3")
        print(f"occlusion M     {vols['volume_robot_occlusion']:.3f} m^3")
        print(f"region R2 / R3  {vols['volume_r2']:.3f} / {vols['volume_region']:.3f} m^3")
        print(f"min distance    {'none' if not math.isfinite(d) else f'{d:.3f} m'} ({verdict.closest_link})")
        print(f"speed scale     {verdict.speed_scale:.3f}")
        # one line per rule: how many parts it removed and their volume
        by_rule: dict[str, list[float]] = defaultdict(list)
        for r in verdict.removed:
            by_rule[r.rule].append(r.volume)
        for rule, volumes in by_rule.items():
            parts = "part" if len(volumes) == 1 else "parts"
            print(f"removed         {rule}: {len(volumes)} {parts}, {sum(volumes):.4f} m^3")
        for f in verdict.faults:
            print(f"FAULT           {f}")
        for w in verdict.warnings:
            print(f"warning         {w}")
        print("timings [ms]    " + ", ".join(f"{k} {v:.1f}" for k, v in verdict.timings.items()))
    if args.export is not None:
        # with --json, stdout holds the JSON object only
        print(f"wrote {', '.join(str(p) for p in paths)}", file=sys.stderr if args.json else sys.stdout, flush=True)
    return 0
