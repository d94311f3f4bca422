"""``polyhull render``: simulate the depth frames of a cell and write a frames file.

Example::

    polyhull render fixtures/cells/paper_cell.toml --q=0,-0.6,1.2,0,0.8,0 \\
        --target person:walking@2.0,2.5,0,0.5 --target box.stl@4,4,0 --out frames.npz
"""

from __future__ import annotations

import argparse
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import GeometryError, PolyhullError, RobotError

if TYPE_CHECKING:
    import trimesh

    from ..cell import Cell
    from ..person import PersonPose

__all__ = ["register", "TargetSpec", "parse_target", "parse_q"]

_TARGET_HELP = (
    "a target to place in the cell, repeatable: MESH[@x,y[,z[,yaw]]]. MESH is a mesh file "
    "(anything trimesh reads) or the built-in person: person[:POSE[:HEIGHT[:PHASE]]] with "
    "POSE standing, walking, reaching or crouching, HEIGHT in m (default 1.75) and the gait PHASE in "
    "rad. x, y, z [m] and yaw [rad, about +z] place it in the world; a mesh keeps its own "
    "frame (default 0,0,0,0); a person stands on the floor (z defaults to the floor "
    "height, x, y to the middle of the zone) facing +x at yaw 0."
)


@dataclass(frozen=True)
class TargetSpec:
    """A parsed ``--target`` value.

    Attributes:
        source: The mesh file, or ``"person"``.
        pose: Person pose (persons only).
        height: Person height [m] (persons only).
        phase: Person gait phase [rad] (persons only).
        xy: Position (x, y) [m], or None when not given.
        z: Height [m], or None when not given.
        yaw: Rotation about world +z [rad].
    """

    source: str
    pose: str = "standing"
    height: float = 1.75
    phase: float = 0.0
    xy: tuple[float, float] | None = None
    z: float | None = None
    yaw: float = 0.0

    @property
    def is_person(self) -> bool:
        """True for the built-in person."""
        return self.source == "person"


def _numbers(text: str, what: str) -> list[float]:
    try:
        values = [float(part) for part in text.split(",") if part.strip() != ""]
    except ValueError as exc:
        raise PolyhullError(f"{what}: expected comma-separated numbers, got {text!r}") from exc
    if not all(np.isfinite(values)):
        raise PolyhullError(f"{what}: numbers must be finite, got {text!r}")
    return values


def parse_q(values: list[str] | None) -> np.ndarray | None:
    """Joint positions [rad] from ``--q`` values (comma- and/or space-separated)."""
    if values is None:
        return None
    numbers: list[float] = []
    for value in values:
        numbers.extend(_numbers(value, "--q"))
    if not numbers:
        raise RobotError("--q: give at least one joint position [rad]")
    return np.asarray(numbers, dtype=np.float64)


def parse_target(text: str) -> TargetSpec:
    """Parse ``MESH[@x,y[,z[,yaw]]]`` (see ``polyhull render --help``)."""
    what = f"--target {text!r}"
    source, _, placement = _split_at(text)
    if not source:
        raise PolyhullError(f"{what}: the mesh (a file or 'person') is missing")
    xy: tuple[float, float] | None = None
    z: float | None = None
    yaw = 0.0
    if placement:
        numbers = _numbers(placement, what)
        if not 2 <= len(numbers) <= 4:
            raise PolyhullError(
                f"{what}: the placement after '@' must be x,y or x,y,z or x,y,z,yaw, "
                f"got {len(numbers)} numbers"
            )
        xy = (numbers[0], numbers[1])
        if len(numbers) >= 3:
            z = numbers[2]
        if len(numbers) == 4:
            yaw = numbers[3]
    if source == "person" or source.startswith("person:"):
        fields = source.split(":")
        if len(fields) > 4:
            raise PolyhullError(f"{what}: person takes at most person:POSE:HEIGHT:PHASE")
        pose = fields[1] if len(fields) > 1 and fields[1] else "standing"
        from ..person import HEIGHTS, POSES

        if pose not in POSES:
            raise PolyhullError(f"{what}: person pose must be one of {list(POSES)}, got {pose!r}")
        height = _numbers(fields[2], f"{what} height")[0] if len(fields) > 2 and fields[2] else 1.75
        if not HEIGHTS[0] <= height <= HEIGHTS[1]:  # make_person's range, checked here to name the flag
            raise PolyhullError(f"{what}: person height must be in [{HEIGHTS[0]}, {HEIGHTS[1]}] m, got {height}")
        phase = _numbers(fields[3], f"{what} phase")[0] if len(fields) > 3 and fields[3] else 0.0
        return TargetSpec("person", pose, height, phase, xy, z, yaw)
    return TargetSpec(source, xy=xy, z=z, yaw=yaw)


def _split_at(text: str) -> tuple[str, str, str]:
    """Split a mesh file target at its last '@' (a file name may contain one)."""
    source, sep, placement = text.rpartition("@")
    if not sep:
        return text, "", ""
    return source, sep, placement


def build_target(spec: TargetSpec, cell: Cell) -> trimesh.Trimesh:
    """The world-frame mesh of a parsed target in ``cell``."""
    import trimesh

    from ..person import make_person

    if spec.is_person:
        zone_mid = (np.asarray(cell.zone.min) + np.asarray(cell.zone.max)) / 2.0
        xy = spec.xy if spec.xy is not None else (float(zone_mid[0]), float(zone_mid[1]))
        floor_z = spec.z if spec.z is not None else cell.zone.floor_z
        pose = typing.cast("PersonPose", spec.pose)
        return make_person(
            spec.height, pose, position=xy, yaw=spec.yaw, phase=spec.phase, floor_z=floor_z
        )
    path = Path(spec.source)
    if not path.is_file():
        raise GeometryError(f"--target: mesh file '{path}' does not exist")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise GeometryError(f"--target: cannot read mesh file '{path}': {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise GeometryError(f"--target: mesh file '{path}' holds no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise GeometryError(f"--target: mesh file '{path}' has non-finite vertices")
    x, y = spec.xy if spec.xy is not None else (0.0, 0.0)
    c, s = np.cos(spec.yaw), np.sin(spec.yaw)
    T_world_mesh = np.array(
        [[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, spec.z or 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    mesh.apply_transform(T_world_mesh)
    return mesh


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``render`` sub-command."""
    p = subparsers.add_parser(
        "render",
        help="simulate the depth frames of a cell and write a frames file",
        description=(
            "Ray-cast the depth frame of every camera of CELL (floor, obstacles, the robot "
            "at --q and the --target meshes) with realistic, seeded sensor effects, and "
            "write them to a frames file (.npz: one float32 depth array [m] per camera, q, "
            "stamp)."
        ),
    )
    p.add_argument("cell", type=Path, help="the cell file (TOML)")
    p.add_argument(
        "--q",
        nargs="+",
        metavar="Q",
        help=(
            "joint positions [rad], URDF order, comma- or space-separated (write "
            "--q=-0.6,1.2 when the first is negative); default: the cell's robot.q"
        ),
    )
    p.add_argument("--target", action="append", default=[], metavar="MESH[@x,y[,z[,yaw]]]", help=_TARGET_HELP)
    p.add_argument("--out", type=Path, required=True, help="the frames file to write (.npz)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor effects (default 0)")
    p.add_argument("--stamp", type=float, default=0.0, help="acquisition time [s] (default 0)")
    effects = p.add_argument_group("sensor effects (all on by default)")
    effects.add_argument("--exact", action="store_true", help="no sensor effect at all: exact depth")
    effects.add_argument("--no-noise", action="store_true", help="no depth noise")
    effects.add_argument(
        "--dropout", type=float, default=0.002, metavar="SHARE",
        help="share of pixels dropped out as 0, in [0, 1] (default 0.002)",
    )
    effects.add_argument(
        "--no-out-of-range", action="store_true",
        help="keep depth outside the camera range instead of reporting 0",
    )
    effects.add_argument("--no-flying-pixels", action="store_true", help="no flying pixels at depth edges")
    effects.add_argument("--uint16", action="store_true", help="quantise to millimetres like a uint16 driver")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from ..cellfile import load_cell
    from ..frames import save_frames
    from ..simulator import SensorEffects, Simulator

    if args.out.suffix != ".npz":
        raise PolyhullError(f"--out must name a .npz frames file, got '{args.out}'")
    if not np.isfinite(args.stamp):
        raise PolyhullError(f"--stamp must be finite [s], got {args.stamp!r}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")
    if not 0.0 <= args.dropout <= 1.0:
        raise PolyhullError(f"--dropout must be a share in [0, 1], got {args.dropout}")
    if args.exact:
        effects = SensorEffects.none()
    else:
        effects = SensorEffects(
            noise=not args.no_noise,
            dropout=args.dropout,
            out_of_range=not args.no_out_of_range,
            flying_pixels=not args.no_flying_pixels,
            uint16=args.uint16,
        )
    q = parse_q(args.q)
    specs = [parse_target(text) for text in args.target]
    cell = load_cell(args.cell)
    targets = [build_target(spec, cell) for spec in specs]
    zlo, zhi = np.asarray(cell.zone.min), np.asarray(cell.zone.max)
    for text, mesh in zip(args.target, targets, strict=True):
        lo, hi = mesh.bounds
        if np.any(hi < zlo) or np.any(lo > zhi):
            print(
                f"polyhull render: warning: --target {text} lies outside the zone "
                f"{zlo.tolist()}..{zhi.tolist()} m: no camera region will hold it",
                file=sys.stderr,
            )
    simulator = Simulator(cell, effects=effects)
    if q is None:
        q = np.asarray(cell.robot.q if cell.robot is not None else (), dtype=np.float64)
    frames = simulator.render(q if q.size else None, targets=targets, seed=args.seed, stamp=args.stamp)
    path = save_frames(args.out, frames, q, args.stamp)
    print(f"wrote {path}: {len(frames)} cameras, q = {np.round(q, 4).tolist()} rad, stamp = {args.stamp} s")
    for name, frame in frames.items():
        depth = frame.depth
        valid = np.isfinite(depth) & (depth > 0)
        span = f"{depth[valid].min():.3f}..{depth[valid].max():.3f} m" if valid.any() else "no valid depth"
        height, width = frame.shape
        print(f"  {name:<12} {width}x{height}  valid {100.0 * valid.mean():5.1f} %  depth {span}")
    return 0
