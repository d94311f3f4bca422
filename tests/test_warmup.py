"""The monitor's warm-up (:mod:`polyhull.engine.warmup`): its synthetic cycles change no
verdict of the real cycles after them, and they load every compiled kernel a real cycle
calls, with the argument types it calls it with (else the first real cycle would load it)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from polyhull.cell import Cell
from polyhull.cellfile import default_cell_path
from polyhull.commands.demo import robot_motion
from polyhull.engine.warmup import warmup_frames
from polyhull.monitor import Monitor
from polyhull.person import make_person
from polyhull.simulator import SensorEffects, Simulator

DT = 0.1


def _inputs(cell: Cell, sim: Simulator, robot: object) -> list:  # type: ignore[type-arg]
    """Six cycles: a person walking past the robot (default sensor effects), then three of
    the empty cell as uint16 millimetres, the last with 12 px dropout patches (too wide to
    free whole at this cell's depths: the small gaps' residue and its test)."""
    q0 = np.asarray(cell.robot.q, dtype=np.float64)  # type: ignore[union-attr]
    base = np.asarray(cell.robot.base[:2], dtype=np.float64)  # type: ignore[union-attr]
    out = []
    for k in range(6):
        t = k * DT
        q = robot_motion(q0, robot.lower, robot.upper, t)  # type: ignore[attr-defined]
        if k < 3:
            person = make_person(pose="walking", position=tuple(base - [1.0, 1.05 - 0.1 * k]), yaw=0.8, phase=0.3 * k)
            frames = sim.render(q, targets=[person], seed=900 + k, stamp=t)
        else:
            effects = SensorEffects(uint16=True, dropout_cluster=12 if k == 5 else 4)
            frames = sim.render(q, seed=900 + k, stamp=t, effects=effects)
        out.append((frames, q, t))
    return out


def test_warm_up_changes_no_verdict(small_cell: Cell, small_sim: Simulator) -> None:
    refs = small_sim.reference()
    warm = Monitor(small_cell, references=refs)
    cold = Monitor(small_cell, references=refs, warm_up=False)
    kept = 0
    for frames, q, t in _inputs(small_cell, small_sim, warm.robot):
        a, b = warm.step(frames, q, stamp=t), cold.step(frames, q, stamp=t)
        assert a.faults == b.faults == ()
        assert a.min_distance == b.min_distance
        assert a.closest_link == b.closest_link
        np.testing.assert_array_equal(a.closest_points, b.closest_points)
        assert a.counts == b.counts
        assert [(r.rule, r.volume) for r in a.removed] == [(r.rule, r.volume) for r in b.removed]
        kept += a.counts.get("kept_pieces", 0)
    assert kept > 0, "the person should give dynamic pieces"


def test_warm_up_frames_have_work_for_every_stage(small_cell: Cell, small_sim: Simulator) -> None:
    monitor = Monitor(small_cell, references=small_sim.reference(), warm_up=False)
    monitor._always_refine = True  # as the warm-up runs them (the static region is nearer here)
    q = np.asarray(small_cell.robot.q, dtype=np.float64)  # type: ignore[union-attr]
    points = np.array([T[:3, 3] for T in monitor.robot.link_transforms(q).values()])  # type: ignore[union-attr]
    counts = []
    for k, frames in enumerate(warmup_frames(small_cell, small_sim.reference(), [0.0, DT], points)):
        v = monitor.step(frames, q, stamp=k * DT)
        assert v.faults == ()
        counts.append(v.counts)
    assert all(c["kept_pieces"] > 0 and c["refine_rounds"] > 0 for c in counts)
    assert all(c["small_gap_pixels"] > 0 for c in counts), "the dropout patches should be filled"
    assert counts[1]["memory_pieces"] > 0, "the second cycle should have a shadow memory"


SIGNATURES = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    import numpy as np
    from numba.core.registry import CPUDispatcher
    from polyhull.cellfile import load_cell
    from polyhull.monitor import Monitor
    from polyhull.simulator import Simulator
    from test_warmup import _inputs

    def loaded():
        return {{
            (m.__name__, n): len(o.signatures)
            for m in list(sys.modules.values()) if getattr(m, "__name__", "").startswith("polyhull")
            for n, o in vars(m).items() if isinstance(o, CPUDispatcher)
        }}

    cell = load_cell({cell!r})
    sim = Simulator(cell)
    monitor = Monitor(cell, references=sim.reference())
    before = loaded()
    for frames, q, t in _inputs(cell, sim, monitor.robot):
        monitor.step(frames, q, stamp=t)
    after = loaded()
    print(sorted(k for k in after if after[k] > before.get(k, 0)))
    """
)


@pytest.mark.parametrize("which", ["small", "paper"])
def test_warm_up_loads_every_kernel_a_cycle_calls(which: str) -> None:
    """In a fresh process (the loaded kernels are the process's): no compiled kernel gains a
    signature in the real cycles after the warm-up, in the small cell and in the paper cell
    (whose far dropout patches leave small gaps' residue: its test once compiled in the
    first cycle of a fresh machine's demo, 155 ms)."""
    from conftest import ROOT, SMALL_CELL

    cell = SMALL_CELL if which == "small" else default_cell_path()
    script = SIGNATURES.format(tests=str(ROOT / "tests"), cell=str(cell))
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=600)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
