"""``polyhull run CELL --frames F.npz [F.npz ...] [--json] [--export DIR] [--plot OUT.png]``.

One cycle per frames file, in the order given, through one monitor (a directory stands for
its ``*.npz`` files in name order: a recording). With one file the verdict is printed in
full (``--json``: one JSON object, :meth:`polyhull.verdict.Verdict.to_json`); with several,
one line per cycle (``--json``: ``{"cycles": [...]}`` with one timeline record per file) and
the last cycle's verdict in full in text mode. ``--plot`` writes the timeline plot of the
cycles.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

from ..errors import PolyhullError

__all__ = ["register", "export_regions", "frames_files"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``run`` sub-command."""
    p = subparsers.add_parser(
        "run",
        help="run surveillance cycles on recorded frames",
        description=(
            "Run one surveillance cycle of CELL per frames file (.npz: one float32 (H, W) "
            "depth array [m] per camera name, plus q and stamp), in the order given, through "
            "one monitor, and print the verdict (several files: a line per cycle, then the "
            "last verdict). A directory stands for its *.npz files in name order."
        ),
        epilog=(
            "Exit status: 0 when every cycle ran (a cycle's faults, such as a missing camera or "
            "a contact, are reported in its output, not in the exit status); 2 on bad input (a "
            "cell or frames file, a flag, or a missing optional extra); 130 when interrupted "
            "(Ctrl-C); 141 when the reader of the output went away (a closed pipe); 1, with a "
            "traceback, is a bug in polyhull."
        ),
    )
    p.add_argument("cell", type=Path, help="cell file (TOML)")
    p.add_argument(
        "--frames", type=Path, nargs="+", action="extend", required=True, metavar="F.npz",
        help="frames files (.npz), or directories of them; one cycle each, in this order",
    )
    p.add_argument(
        "--json", action="store_true",
        help="print JSON only: for one file, the verdict object (volumes [m^3], the distance, closest link "
        "and points, speed scale, allowed speed, S_p, faults, warnings, removals, counts, timings, stamp); "
        'for several, {"cycles": [...]} with one timeline record per file',
    )
    p.add_argument(
        "--export", type=Path, metavar="DIR",
        help="write hull.ply, robot_occlusion.ply, region.ply of the last cycle",
    )
    p.add_argument(
        "--plot", type=Path, metavar="OUT.png",
        help="write the timeline plot (distance, S_p: the protective separation distance of ISO/TS 15066, "
        "speed scale, cycle time against time)",
    )
    p.set_defaults(func=_run)


def frames_files(paths: list[Path]) -> list[Path]:
    """The frames files named by ``--frames``: files as given, directories as their ``*.npz``.

    Raises:
        PolyhullError: A path does not exist, or a directory holds no ``.npz`` file.
    """
    out: list[Path] = []
    for path in paths:
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix == ".npz" and p.is_file())
            if not found:
                raise PolyhullError(f"--frames {path}: the directory holds no .npz frames file")
            out.extend(found)
        elif path.is_file():
            out.append(path)
        else:
            raise PolyhullError(f"--frames {path}: no such frames file or directory")
    return out


_EXPORTED = ("hull", "robot_occlusion", "region")
"""The verdict's manifolds ``--export`` writes (C, M, R3)."""

_VOLUMES = ("hull", "robot_occlusion", "region_r2", "region", "region_dynamic")
"""The verdict's manifolds that :meth:`polyhull.Verdict.volumes` measures."""


def export_regions(verdict: object, directory: Path) -> list[Path]:
    """Write C, M and R of a verdict as watertight PLY files (world frame) into ``directory``."""
    import numpy as np
    import trimesh

    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for name in _EXPORTED:
        manifold = getattr(verdict, name)
        mesh = manifold.to_mesh64()
        tm = trimesh.Trimesh(
            vertices=np.asarray(mesh.vert_properties)[:, :3], faces=np.asarray(mesh.tri_verts), process=False
        )
        path = directory / f"{name}.ply"
        tm.export(path)
        written.append(path)
    return written




def _build_regions(verdict: object, names: tuple[str, ...]) -> None:
    """Build the verdict's manifolds ``names`` (manifold booleans: seconds to a minute on a
    large cell, off the cycle), with a progress bar on stderr when it is a terminal; the
    verdict keeps them for the volumes and the export."""
    from tqdm import tqdm

    with tqdm(names, desc="building the regions", unit="region", file=sys.stderr, disable=None, leave=False) as bar:
        for name in bar:
            bar.set_postfix_str(name)
            getattr(verdict, name).volume()


def _run(args: argparse.Namespace) -> int:
    from ..cellfile import load_cell
    from ..frames import check_cameras, load_frames
    from ..monitor import Monitor
    from ..timeline import plot_timeline, record_of

    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise PolyhullError(f"--plot {args.plot}: the timeline plot is a PNG; give a path ending in .png")
    cell = load_cell(args.cell)
    files = frames_files(args.frames)
    recordings = [load_frames(f) for f in files]  # every file is checked before the first cycle
    for path, recorded in zip(files, recordings, strict=True):
        check_cameras(path, recorded, (c.name for c in cell.cameras))
    monitor = Monitor(cell)
    records = []
    verdict = None
    several = len(files) > 1
    for path, recorded in zip(files, recordings, strict=True):
        verdict = monitor.step(recorded.frames, recorded.q, stamp=recorded.stamp)
        records.append({"file": str(path), **record_of(verdict)})
        if several and not args.json:
            rec = records[-1]
            dist = "none" if rec["min_distance"] is None else f"{rec['min_distance']:.3f} m"
            faults = "; ".join(rec["faults"]) or "-"
            print(
                f"{path.name:<24} stamp {rec['stamp']:8.3f} s  distance {dist:>9} ({rec['closest_link'] or '-'})  "
                f"speed {rec['speed_scale']:.2f}  cycle {rec['cycle_ms'] or math.nan:7.1f} ms  faults {faults}",
                flush=True,
            )
    assert verdict is not None  # frames_files never returns an empty list
    recorded = recordings[-1]
    missing = [c.name for c in cell.cameras if c.name not in recorded.frames]
    paths: list[Path] = []
    if not (args.json and several):
        _build_regions(verdict, _VOLUMES)  # the volumes printed below
    elif args.export is not None:
        _build_regions(verdict, _EXPORTED)
    if args.export is not None:
        try:
            paths = export_regions(verdict, args.export)
        except OSError as exc:
            raise PolyhullError(f"--export {args.export}: cannot write ({exc})") from exc
    if args.json:
        print(json.dumps({"cycles": records} if several else verdict.to_json(), indent=2))
    else:
        vols = verdict.volumes()
        d = verdict.min_distance
        if several:
            print(f"last cycle ({files[-1]}):")
        print(f"cell            {cell.name} ({args.cell})")
        print(f"frames          {files[-1]} ({len(recorded.frames)} cameras, stamp {recorded.stamp:.3f} s)")
        if missing:
            print(f"missing frames  {', '.join(missing)}")
        print(f"hull C          {vols['volume_hull']:.3f} m^3 (seen free by no camera)")
        print(f"occlusion M     {vols['volume_robot_occlusion']:.3f} m^3 (what the padded robot hides)")
        print(f"region R2       {vols['volume_r2']:.3f} m^3 (C less M and the solids)")
        print(f"region R3       {vols['volume_region']:.3f} m^3 (R2 less the plausibility rules' removals; the distance is R3's)")
        if verdict.closest_link is not None:
            where = f" to {verdict.closest_link}"
        elif verdict.faults and d == 0.0:
            where = " (a stop: the cycle measured nothing, see the faults)"
        else:
            where = ""
        print(f"min distance    {'none' if not math.isfinite(d) else f'{d:.3f} m'}{where}")
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
    # with --json, stdout holds the JSON document only
    info = sys.stderr if args.json else sys.stdout
    if args.export is not None:
        print(f"wrote {', '.join(str(p) for p in paths)}", file=info, flush=True)
    if args.plot is not None:
        out = plot_timeline(records, args.plot, title=f"polyhull run: {cell.name}, {len(files)} cycles")
        print(f"wrote {out} (timeline plot)", file=info, flush=True)
    return 0
