"""``polyhull place``: optimise where the cameras of a cell hang (paper section 4).

Example::

    polyhull place fixtures/cells/paper_cell.toml --budget-evals 300 --objective f3 \\
        --grid 63,45,33 --workers 2 --out placement

writes ``report.json``, ``report.md``, ``convergence.png``, ``<cell>_placed.toml`` and, when
the viewer package is installed, ``scene.html`` (the best placement) to ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

from ..errors import PolyhullError
from . import counted

__all__ = ["register", "parse_grid", "parse_counts", "parse_importance"]

_DEFAULT_EVALS = 200


def parse_grid(text: str) -> tuple[int, int, int]:
    """Voxel counts ``nx,ny,nz`` from ``--grid``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        raise PolyhullError(f"--grid: expected three integers nx,ny,nz, got {text!r}") from None
    if len(values) != 3 or min(values) < 1:
        raise PolyhullError(f"--grid: expected three positive integers nx,ny,nz, got {text!r}")
    return values  # type: ignore[return-value]


def parse_counts(text: str) -> list[int]:
    """Camera counts from ``--cameras``: ``N``, ``A-B`` (inclusive) or ``A,B,C``."""
    try:
        if "-" in text:
            a, b = (int(p) for p in text.split("-", 1))
            if b < a:
                raise PolyhullError(f"--cameras: expected a range A-B with A <= B, got {text!r}")
            counts = list(range(a, b + 1))
        else:
            counts = [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise PolyhullError(f"--cameras: expected N, A-B or A,B,C (integers), got {text!r}") from None
    if not counts or min(counts) < 1:
        raise PolyhullError(f"--cameras: expected camera counts >= 1, got {text!r}")
    return counts


def parse_importance(values: list[str]) -> Any:
    """Importance regions from ``--importance X0,Y0,Z0,X1,Y1,Z1:WEIGHT`` values."""
    from ..placement.objectives import Importance, ImportanceRegion

    regions = []
    for text in values:
        box, sep, weight = text.partition(":")
        try:
            numbers = [float(p) for p in box.split(",")]
            w = float(weight)
        except ValueError:
            numbers, w = [], float("nan")
        if not sep or len(numbers) != 6:
            raise PolyhullError(
                f"--importance: expected X0,Y0,Z0,X1,Y1,Z1:WEIGHT (box corners [m] and a weight), got {text!r}"
            )
        regions.append(ImportanceRegion(lo=tuple(numbers[:3]), hi=tuple(numbers[3:]), weight=w))  # type: ignore[arg-type]
    return Importance(regions=tuple(regions)) if regions else None


def _check_flags(args: argparse.Namespace) -> None:
    """Reject flag values the optimiser would refuse later (or silently replace), naming
    the flag, before anything is loaded."""
    if args.workers < 1:
        raise PolyhullError(f"--workers must be an integer >= 1, got {args.workers}")
    if args.seed < 0:
        raise PolyhullError(f"--seed must be >= 0, got {args.seed}")
    if args.k_of_n is not None and args.k_of_n < 1:
        raise PolyhullError(f"--k-of-n must be an integer >= 1, got {args.k_of_n}")
    if args.eps is not None and not (math.isfinite(args.eps) and args.eps >= 0):
        raise PolyhullError(f"--eps must be finite and >= 0 (units of the objective), got {args.eps}")
    for flag, value in (("--w1", args.w1), ("--w2", args.w2)):
        if not (math.isfinite(value) and value >= 0):
            raise PolyhullError(f"{flag} must be a finite weight >= 0, got {value}")
    if not (0 < args.sigma0 <= 1):
        raise PolyhullError(f"--sigma0 must be in (0, 1] (parameters normalised to [0, 1]), got {args.sigma0}")
    if args.pixel_step < 1:
        raise PolyhullError(f"--pixel-step must be an integer >= 1 [px], got {args.pixel_step}")


def _argument(parse: Any) -> Any:
    """An argparse ``type`` that reports a :class:`PolyhullError` as a usage error (without
    the message's leading ``--flag:``, as argparse names the flag itself)."""

    def convert(text: str) -> Any:
        try:
            return parse(text)
        except PolyhullError as exc:
            flag, sep, reason = str(exc).partition(": ")
            raise argparse.ArgumentTypeError(reason if sep and flag.startswith("--") else str(exc)) from None

    convert.__name__ = parse.__name__
    return convert


def register(subparsers: Any) -> None:
    """Add the ``place`` sub-command."""
    p = subparsers.add_parser(
        "place",
        help="optimise the camera placement of a cell (objectives f1 to f4, CMA-ES)",
        description=(
            "Score the cell's camera placement with the objectives of paper section 4 (f1 "
            "undetectable volume, f2 weighted, f3 = w1 changed + w2 undetectable, f4 = f3 "
            "under the k-of-n rule) over people sampled on the walkable floor, optimise the "
            "cameras on the cell's [[mounting]] surfaces with CMA-ES, and write a report, a "
            "convergence plot and the optimised cell."
        ),
    )
    p.add_argument("cell", help="cell file (TOML) with [[mounting]] surfaces")
    p.add_argument("--budget-evals", type=int, default=None, metavar="N",
                   help=f"evaluations per camera count (default {_DEFAULT_EVALS} unless only "
                        "--budget-seconds is given)")
    p.add_argument("--budget-seconds", type=float, default=None, metavar="S",
                   help="wall-clock budget per camera count [s] (default: off)")
    p.add_argument("--eps", type=float, default=None, metavar="E",
                   help="stop when best - f_opt < E (f_opt: the objective's optimal value, a lower bound "
                        "from the static and target volumes; units of the objective; default: off)")
    p.add_argument("--objective", choices=("f1", "f2", "f3", "f4"), default="f3",
                   help="objective to minimise (default f3)")
    p.add_argument("--grid", type=_argument(parse_grid), default=(126, 90, 66), metavar="NX,NY,NZ",
                   help="voxel counts over the zone (default the paper's 126,90,66)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="local worker processes (default: CPU count; 1 evaluates in-process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask distributed scheduler address (tcp://host:8786): evaluate there")
    p.add_argument("--out", type=Path, default=Path("placement"), metavar="DIR",
                   help="output directory (default ./placement)")
    p.add_argument("--seed", type=int, default=0, help="seed of the people sampler and CMA-ES (default 0)")
    p.add_argument("--cameras", type=_argument(parse_counts), default=None, metavar="N|A-B|A,B",
                   help="camera counts to optimise (default: the cell's count)")
    p.add_argument("--vary-fov", action="store_true",
                   help="also optimise each camera's focal length (fx = fy scale 0.5 to 2)")
    p.add_argument("--scenes", type=int, default=6, metavar="N",
                   help="target scenes (one person each, standing and reaching; default 6)")
    p.add_argument("--w1", type=float, default=1.0, help="weight of the changed volume (default 1)")
    p.add_argument("--w2", type=float, default=2.0, help="weight of the undetectable volume (default 2)")
    p.add_argument("--k-of-n", type=int, default=None, metavar="K",
                   help="k of f4 (default: the cell's reconstruction.k_of_n if above 1, else 2)")
    p.add_argument("--importance", action="append", default=[], metavar="X0,Y0,Z0,X1,Y1,Z1:W",
                   help="importance box and weight for f2, repeatable (default weight 1)")
    p.add_argument("--pixel-step", type=int, default=1, metavar="S",
                   help="render every S-th pixel (default 1: full resolution, as the paper)")
    p.add_argument("--method", choices=("cma-es", "random"), default="cma-es",
                   help="optimiser (random: the uniform random search baseline; default %(default)s)")
    p.add_argument("--sigma0", type=float, default=0.15, metavar="S",
                   help="initial CMA-ES step size, parameters normalised to [0, 1] (default 0.15)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..cellfile import load_cell
    from ..placement.objectives import ObjectiveParams, PlacementProblem, evaluate_cameras
    from ..placement.optimizer import StopCriteria, make_executor, optimize_counts
    from ..placement.report import (
        build_report,
        plot_convergence,
        write_cell_toml,
        write_json,
        write_markdown,
    )
    from ..placement.targets import sample_target_scenes

    _check_flags(args)
    cell = load_cell(args.cell)
    if not cell.mounting:
        raise PolyhullError(
            f"{args.cell}: the cell declares no [[mounting]] surfaces (origin, edge_u, edge_v) "
            "where cameras may hang"
        )
    if not cell.cameras:
        raise PolyhullError(f"{args.cell}: the cell has no camera to take the camera model from")
    if args.scenes < 1:
        raise PolyhullError(f"--scenes must be >= 1, got {args.scenes}")
    if args.budget_evals is not None and args.budget_evals < 1:
        raise PolyhullError(f"--budget-evals must be >= 1, got {args.budget_evals}")
    if args.budget_seconds is not None and not (math.isfinite(args.budget_seconds) and args.budget_seconds > 0):
        raise PolyhullError(f"--budget-seconds must be a time > 0 s, got {args.budget_seconds}")
    max_evals = args.budget_evals
    if max_evals is None and args.budget_seconds is None:
        max_evals = _DEFAULT_EVALS
    stop = StopCriteria(max_evals=max_evals, max_seconds=args.budget_seconds, eps=args.eps)
    counts = args.cameras or [len(cell.cameras)]
    k = args.k_of_n or (cell.reconstruction.k_of_n if cell.reconstruction.k_of_n > 1 else 2)
    params = ObjectiveParams(w1=args.w1, w2=args.w2, k=k, importance=parse_importance(args.importance))

    scenes = sample_target_scenes(cell, n_scenes=args.scenes, seed=args.seed)
    problem = PlacementProblem.from_cell(cell, scenes, args.grid, params, step=args.pixel_step)
    t0 = time.perf_counter()
    before = evaluate_cameras(problem, cell.cameras)
    t_before = time.perf_counter() - t0
    print(
        f"{cell.name}: {len(cell.cameras)} cameras, grid {'x'.join(map(str, args.grid))}, "
        f"{len(scenes)} target scenes; {args.objective} before = {before[args.objective]:.4g} "
        f"(one evaluation {t_before:.2f} s)"
    )

    total = None if max_evals is None else max_evals * len(counts)
    bar = tqdm(total=total, unit="eval", disable=args.no_progress, file=sys.stderr, dynamic_ncols=True)
    try:
        with make_executor(args.workers, args.scheduler) as executor:

            def progress(count: int, n: int, value: float, best: float) -> None:
                bar.update(1)
                bar.set_postfix_str(f"{count} cams, best {args.objective} = {best:.4g}")

            chosen, results = optimize_counts(
                problem,
                cell,
                counts,
                args.objective,
                stop,
                executor,
                seed=args.seed,
                vary_fov=args.vary_fov,
                callback=progress,
                method=args.method,
                sigma0=args.sigma0,
            )
    finally:
        bar.close()

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    settings = {
        "budget_evals": max_evals,
        "budget_seconds": args.budget_seconds,
        "eps": args.eps,
        "seed": args.seed,
        "workers": args.workers,
        "scheduler": args.scheduler,
        "camera_counts": counts,
        "vary_fov": args.vary_fov,
        "method": args.method,
        "sigma0": args.sigma0,
    }
    report = build_report(cell, problem, before, chosen, results, settings)
    stem = Path(args.cell).stem
    placed_path = out / f"{stem}_placed.toml"
    written = [
        write_json(report, out / "report.json"),
        write_markdown(report, out / "report.md"),
        plot_convergence(results, out / "convergence.png", before=before[args.objective],
                         title=f"{cell.name}: {args.objective}"),
        write_cell_toml(
            cell,
            chosen.cameras,
            placed_path,
            header=(
                f"{cell.name}: cameras placed by `polyhull place` ({args.objective} = "
                f"{chosen.best_value:.4g}, f_opt = {chosen.optimum[args.objective]:.4g}, "
                f"before {before[args.objective]:.4g})."
            ),
        ),
    ]
    html_note = _write_html(cell, chosen.cameras, out / "scene.html")
    if isinstance(html_note, Path):
        written.append(html_note)

    obj = args.objective
    print(
        f"{obj}: before {before[obj]:.4g}, after {chosen.best_value:.4g}, f_opt "
        f"{chosen.optimum[obj]:.4g} (after - f_opt = {chosen.gap:.4g}) with "
        f"{len(chosen.cameras)} cameras"
    )
    for r in results:
        rate = r.evaluations / r.seconds if r.seconds > 0 else float("nan")
        print(
            f"  {len(r.cameras)} cameras: best {r.best_value:.4g} in {counted(r.evaluations, 'evaluation')}, "
            f"{r.seconds:.1f} s ({rate:.2f} eval/s), stopped on {r.stop_reason}"
        )
    for path in written:
        print(f"wrote {path}")
    if isinstance(html_note, str):
        print(html_note)
    return 0


def _write_html(cell: Any, cameras: Any, path: Path) -> Path | str:
    """The HTML scene of the best placement, or a note saying why there is none."""
    try:
        import polyhull_viewer as pv
    except ImportError:
        return "no scene.html: the viewer is not installed (pip install 'polyhull[viewer]')"
    try:
        placed = dataclasses.replace(cell, cameras=tuple(cameras))
        vis = pv.StaticVisualizer()
        pv.draw_cell(vis, placed)
        return Path(pv.write_html(vis, path, title=f"{cell.name}: optimised placement"))
    except PolyhullError as exc:
        return f"no scene.html: the viewer could not draw the cell: {exc}"
