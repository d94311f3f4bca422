"""``polyhull teach CELL RECORDING [--seconds 10]``: learn the empty cell's background."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import tomllib
from pathlib import Path

from ..errors import CellError, PolyhullError

__all__ = ["register", "reference_in_cell_file"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``teach`` sub-command."""
    p = subparsers.add_parser(
        "teach",
        help="learn the empty cell's background from a recording",
        description=(
            "Learn, per camera and per pixel, the background of the empty cell from the first "
            "SECONDS of RECORDING (a ROS bag or a folder of depth images): the share of valid "
            "readings, the median depth, the noise (MAD) and the min/max band. Pixels the "
            "sensor loses in the empty cell become static-invalid (never a change); the robot "
            "is left out at its recorded joint state. Writes <cell>.background.npz and one "
            "disagreement-with-CAD heat map per camera beside the cell, and references the "
            "background from the cell file. Fails, naming the camera, when something moves."
        ),
    )
    p.add_argument("cell", type=Path, help="cell file (TOML)")
    p.add_argument("recording", type=Path, help="ROS bag (.mcap, .db3, .bag or bag directory) or image folder")
    p.add_argument("--seconds", type=float, default=10.0, help="teaching window from the first frame [s] (default 10)")
    p.add_argument("--joints", type=Path, metavar="CSV", help="joint states from this CSV instead of the recording")
    p.add_argument("--out", type=Path, metavar="NPZ", help="taught background file (default: <cell>.background.npz beside the cell)")
    p.add_argument(
        "--no-update-cell", action="store_true", help="do not add background = \"...\" to the cell file"
    )
    p.add_argument(
        "--min-valid-share",
        type=float,
        default=None,
        help="a pixel valid in fewer of the taught frames is static-invalid (default 0.8)",
    )
    p.add_argument(
        "--max-moving-share",
        type=float,
        default=0.01,
        help="fail when more of a camera's pixels vary beyond the noise (default 0.01)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (everything else on stderr)")
    p.set_defaults(func=_run)


def reference_in_cell_file(cell_path: Path, background: Path) -> str:
    """Set the top-level ``background`` key of a cell file to ``background`` (written
    relative to the cell file when it lies below the cell's directory). The new text is
    checked (TOML and the whole cell) before the file is replaced, so a failure changes
    nothing. Returns the value written."""
    from ..cellfile import cell_from_mapping

    text = cell_path.read_text(encoding="utf-8")
    try:
        value = os.path.relpath(background.resolve(), cell_path.resolve().parent)
    except ValueError:  # another drive
        value = str(background.resolve())
    value = Path(value).as_posix()
    line = f"background = {json.dumps(value)}                # taught background (polyhull teach)"
    header = re.search(r"^[ \t]*\[", text, flags=re.MULTILINE)
    top, rest = (text[: header.start()], text[header.start() :]) if header else (text, "")
    existing = re.compile(r"^background\s*=.*$", flags=re.MULTILINE)
    if existing.search(top):
        top = existing.sub(lambda _m: line, top, count=1)
    else:
        top = top.rstrip("\n") + ("\n" if top.strip() else "") + line + "\n\n"
    new = top + rest
    try:
        data = tomllib.loads(new)
    except tomllib.TOMLDecodeError as exc:
        raise CellError(f"{cell_path}: cannot add the background key ({exc}); add background = {json.dumps(value)} by hand") from None
    cell_from_mapping(data, cell_path)
    tmp = cell_path.with_name(f".{cell_path.name}.{os.getpid()}.tmp")
    tmp.write_text(new, encoding="utf-8")
    os.replace(tmp, cell_path)
    return value


def _run(args: argparse.Namespace) -> int:
    import dataclasses

    import imageio.v3 as iio

    from ..background import MIN_VALID_SHARE, save_background
    from ..cellfile import load_cell
    from ..recordings import open_recording
    from ..teaching import teach

    log = sys.stderr if args.json else sys.stdout
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        raise PolyhullError(f"--seconds must be a time > 0 s, got {args.seconds}")
    min_valid = MIN_VALID_SHARE if args.min_valid_share is None else args.min_valid_share
    cell = load_cell(args.cell)
    if cell.background is not None:
        # Teach against the CAD reference: the previous taught background is replaced.
        cell = dataclasses.replace(cell, background=None)
    recording = open_recording(args.recording, cell, joints_csv=args.joints)
    result = teach(
        cell,
        recording,
        args.seconds,
        min_valid_share=min_valid,
        max_moving_share=args.max_moving_share,
        progress=True,
    )
    out = args.out if args.out is not None else args.cell.with_name(f"{args.cell.stem}.background.npz")
    try:
        save_background(out, result.background)
        maps = {}
        for c in result.cameras:
            path = out.with_name(f"{out.name.removesuffix('.npz')}.{c.camera}.png")
            iio.imwrite(path, c.heat_map())
            maps[c.camera] = str(path)
    except OSError as exc:
        raise PolyhullError(f"--out {out}: cannot write ({exc})") from None
    referenced = None
    if not args.no_update_cell:
        referenced = reference_in_cell_file(args.cell, out)
    summary = {
        "cell": str(args.cell),
        "recording": str(args.recording),
        "start": result.start,
        "seconds": result.seconds,
        "background": str(out),
        "cell_updated": referenced is not None,
        "cameras": {c.camera: {**c.summary(), "heat_map": maps[c.camera]} for c in result.cameras},
    }
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"taught {len(result.cameras)} cameras from {args.recording} ({result.seconds:g} s)", file=log)
        print(f"{'camera':<10} {'frames':>6} {'taught':>7} {'invalid':>8} {'moving':>7} {'CAD off':>8} {'noise@1m':>14}", file=log)
        for c in result.cameras:
            cam = cell.camera(c.camera)
            dis = "-" if c.disagree_share is None else f"{100 * c.disagree_share:.1f} %"
            noise = f"{1000 * c.noise_at_1m:.2f}/{1000 * cam.noise:.2f} mm" if math.isfinite(c.noise_at_1m) else "-"
            print(
                f"{c.camera:<10} {c.taught.frames:>6} {100 * c.taught_share:>5.1f} % {100 * c.static_invalid_share:>6.1f} % "
                f"{100 * c.moving_share:>5.2f} % {dis:>8} {noise:>14}",
                file=log,
            )
        print("  (taught: share of pixels; invalid: static-invalid share; moving: varied beyond the noise;", file=log)
        print("   CAD off: taught depth outside the CAD reference's band; noise@1m: taught/declared)", file=log)
        for c in result.cameras:
            if c.disagree_share is not None and c.disagree_share > 0.05:
                print(
                    f"warning: camera '{c.camera}': {100 * c.disagree_share:.1f} % of its pixels disagree with "
                    "the CAD model (moved camera or wrong CAD?): see its heat map",
                    file=log,
                )
        print(f"wrote {out} and heat maps {', '.join(maps.values())}", file=log)
        if referenced is not None:
            print(f"cell file {args.cell}: background = \"{referenced}\"", file=log)
    return 0
