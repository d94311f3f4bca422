"""A randomised search for misses over whole walks in a cell (the default one unless
``--cell``; its robot's base at the zone's centre; not run by pytest).

Each walk (one seed): a person walks a random track across the floor at 0.8 to 1.8 m/s and
then stands or reaches, while the robot moves between two random joint positions; 12 cycles
of 0.1 s with every sensor effect on (without flying pixels in about a third of the walks).
Most such tracks are longer than the 1.2 s walked; with ``--arrive`` the person walks
towards the robot's base from 0.2 to 0.8 m away and stops 0.6 to 1.6 m from it, within the
first second, then stands, reaches or crouches there for the rest of the walk. With
``--people 2`` a second person (1.5 to 1.95 m tall) walks a track of the same kind, never
within 0.7 m of the first (drawn after everything else, so a seed's first person, robot
motion and sensor effects are those of the one-person walk).
Every cycle that does not stop for a contact is checked by the same oracles as the tests:

- 6,000 points (half in the zone, half around the person): each that the exact
  per-pixel free depth ``min(D, B) - tau(D)`` leaves possibly occupied lies in the
  engine's R2, in a solid, or in the padded robot's occlusion M by its definition; those
  M holds only with the engine's declared static band or flying-pixel tolerances are
  counted apart ("excused"), the rest are misses;
- 300 points of the person's body: in R3, in M, in a solid, or freed by the exact free
  depth (a reading between two pixels' rays).

    python tests/search_walks.py --seeds 3000 --walks 60
    python tests/search_walks.py --cell fixtures/cells/color8_cell.toml --walks 20
    python tests/search_walks.py --arrive --seeds 10000 --walks 30
    python tests/search_walks.py --arrive --people 2 --seeds 13000 --walks 20

prints one line per finding and a summary; exits 1 on a miss or a lost body point. About
20 s a walk on a 2-core machine.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import (  # noqa: E402
    exactly_possibly_occupied,
    in_declared_occlusion,
    in_robot_occlusion,
    manifold_contains,
    outside_r2,
    zone_and_person_points,
)

from polyhull.cellfile import default_cell_path, load_cell  # noqa: E402
from polyhull.distance import points_in_hexahedra  # noqa: E402
from polyhull.monitor import Monitor  # noqa: E402
from polyhull.oracles import in_solids  # noqa: E402
from polyhull.person import PersonTrack, sample_points_inside  # noqa: E402
from polyhull.simulator import SensorEffects, Simulator  # noqa: E402

CYCLES = 12
DT = 0.1  # [s]


def walk(
    monitor: Monitor, rng: np.random.Generator, arrive: bool = False
) -> tuple[PersonTrack, np.ndarray, np.ndarray, SensorEffects]:
    """A walk drawn from ``rng``: the person's track, the robot's two joint positions, the
    sensor effects (``arrive``: a short track that ends near the robot, see above)."""
    cell, robot = monitor.cell, monitor.robot
    assert robot is not None

    lo, hi = np.asarray(cell.zone.min)[:2] + 0.3, np.asarray(cell.zone.max)[:2] - 0.3
    base = np.asarray(cell.robot.base)[:2] if cell.robot is not None else 0.5 * (lo + hi)

    def free_spot(x: float, y: float) -> bool:  # on the floor, off the obstacles and the robot's base
        inside = bool(np.all((lo <= (x, y)) & ((x, y) <= hi)))
        return inside and np.hypot(x - base[0], y - base[1]) > 0.6 and not in_solids(cell, np.array([[x, y, 0.3], [x, y, 1.0]])).any()

    def spot() -> tuple[float, float]:
        while True:
            x, y = rng.uniform(lo, hi)
            if free_spot(x, y):
                return float(x), float(y)

    def arrival() -> tuple[tuple[float, float], tuple[float, float]]:
        while True:  # the end 0.6 to 1.6 m from the base, the start farther out, facing it
            a, r, back = rng.uniform(-np.pi, np.pi), rng.uniform(0.6, 1.6), rng.uniform(0.2, 0.8)
            turn = a + rng.uniform(-0.5, 0.5)
            end = base + r * np.array([np.cos(a), np.sin(a)])
            start = end + back * np.array([np.cos(turn), np.sin(turn)])
            if free_spot(*end) and free_spot(*start):
                return (float(start[0]), float(start[1])), (float(end[0]), float(end[1]))

    start, end = arrival() if arrive else (spot(), spot())
    speed = float(rng.uniform(0.8, 1.8))
    pose = str(rng.choice(["standing", "reaching", "crouching"] if arrive else ["standing", "reaching"]))
    track = PersonTrack(start=start, end=end, speed=speed, t0=0.0, end_pose=pose)  # type: ignore[arg-type]
    q0 = robot.lower + rng.uniform(0.2, 0.8, 6) * (robot.upper - robot.lower)
    q1 = robot.lower + rng.uniform(0.2, 0.8, 6) * (robot.upper - robot.lower)
    effects = SensorEffects() if rng.random() < 0.7 else SensorEffects(flying_pixels=False)
    return track, q0, q1, effects


SEPARATION = 0.7
"""[m] Least distance between two people's floor positions over a walk (their bodies,
reaching included, do not overlap)."""


def second_walker(monitor: Monitor, rng: np.random.Generator, first: PersonTrack, arrive: bool) -> PersonTrack:
    """A second person's track of the same kind as ``first``'s (:func:`walk`), never within
    ``SEPARATION`` of it over the walk, with a stature drawn from 1.5 to 1.95 m."""
    times = np.arange(0.0, CYCLES * DT + 1e-9, 0.05)
    while True:
        track, _, _, _ = walk(monitor, rng, arrive)
        gaps = [np.linalg.norm(track.position(t)[:2] - first.position(t)[:2]) for t in times]
        if min(gaps) >= SEPARATION:
            height = float(rng.uniform(1.5, 1.95))
            return replace(track, height=height)


def check_walk(
    monitor: Monitor, sim: Simulator, seed: int, arrive: bool = False, people: int = 1
) -> list[dict[str, object]]:
    """Run one walk; a finding (dict) per cycle with a contact, an excused point, a miss or
    a lost body point."""
    cell = monitor.cell
    rng = np.random.default_rng(seed)  # the walk, then the cycles' points
    track, q0, q1, effects = walk(monitor, rng, arrive)
    tracks = [track] + [second_walker(monitor, rng, track, arrive) for _ in range(people - 1)]
    findings: list[dict[str, object]] = []
    monitor.reset()
    for c in range(CYCLES):
        t = DT * c
        q = q0 + (q1 - q0) * min(1.0, t / 1.5)
        persons = [tr.mesh(t) for tr in tracks]
        frames = sim.render(q, targets=persons, seed=seed * 100 + c, stamp=t, effects=effects)
        v = monitor.step(frames, q, stamp=t)
        if v.faults:
            findings.append({"seed": seed, "cycle": c, "stop": list(v.faults)})
            continue
        points = np.concatenate([zone_and_person_points(cell, p, rng, n=3000 // people) for p in persons])
        _, out = outside_r2(monitor, frames, v, points)
        declared = in_declared_occlusion(monitor, frames, out)
        body = np.concatenate([sample_points_inside(p, 300, seed=seed + c + 7919 * i) for i, p in enumerate(persons)])
        body = body[cell.zone.contains(body)]
        in_r3 = manifold_contains(monitor.static.region, body) | points_in_hexahedra(body, v._geometry.kept)  # type: ignore[union-attr]
        ok = in_r3 | in_robot_occlusion(monitor, body) | in_solids(cell, body)
        ok |= ~exactly_possibly_occupied(monitor, frames, body)
        if len(out) or not ok.all():
            findings.append({
                "seed": seed, "cycle": c, "excused": int(declared.sum()), "misses": out[~declared].round(3).tolist(),
                "lost_body": body[~ok].round(3).tolist(),
            })
    return findings


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cell", type=Path, default=None, help="cell file (default: the embedded paper cell)")
    parser.add_argument("--seeds", type=int, default=3000, help="first walk's seed (default 3000)")
    parser.add_argument("--walks", type=int, default=10, help="walks, seeds in a row (default 10)")
    parser.add_argument(
        "--arrive", action="store_true",
        help="short walks towards the robot that end 0.6 to 1.6 m from its base, standing, reaching or crouching",
    )
    parser.add_argument("--people", type=int, choices=(1, 2), default=1, help="people walking at once (default 1)")
    args = parser.parse_args()
    cell = load_cell(args.cell or default_cell_path())
    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    cycles = stops = excused = misses = lost = 0
    for seed in tqdm(range(args.seeds, args.seeds + args.walks), desc="walks", unit="walk"):
        findings = check_walk(monitor, sim, seed, args.arrive, args.people)
        cycles += CYCLES
        for f in findings:
            if "stop" in f:
                stops += 1
                continue
            tqdm.write(str(f))
            excused += int(f["excused"])  # type: ignore[call-overload]
            misses += len(f["misses"])  # type: ignore[arg-type]
            lost += len(f["lost_body"])  # type: ignore[arg-type]
    print(
        f"{args.walks} walks, {cycles - stops} cycles checked ({stops} stopped for a contact): "
        f"{misses} misses, {lost} body points lost, {excused} points excused by the declared tolerances"
    )
    return 1 if misses or lost else 0


if __name__ == "__main__":
    sys.exit(main())
