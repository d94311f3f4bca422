"""Work shared between the calling thread and one pool thread."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from polyhull.engine.threads import Beside, share


def test_results_in_order_on_two_threads() -> None:
    seen: set[int] = set()

    def fn(x: int) -> int:
        seen.add(threading.get_ident())
        time.sleep(0.01)  # long enough for the pool's thread to take items too
        return x * x

    with ThreadPoolExecutor(2) as pool:
        assert share(pool, fn, list(range(10))) == [x * x for x in range(10)]
    assert len(seen) == 2  # this thread and one of the pool's
    assert share(None, fn, [3, 4]) == [9, 16]
    assert share(ThreadPoolExecutor(1), fn, [5]) == [25]


def test_an_error_waits_for_the_other_thread() -> None:
    """When one item raises, the call raises only after the other thread's item is done:
    nothing of the call still runs (on the caller's buffers) once it has raised."""
    done: list[int] = []

    def fn(x: int) -> int:
        if x == 0:
            raise ValueError("item 0")
        time.sleep(0.05)
        done.append(x)
        return x

    with ThreadPoolExecutor(2) as pool:
        with pytest.raises(ValueError, match="item 0"):
            share(pool, fn, [0, 1])
        assert done == [1]


def test_beside_runs_on_a_pool_thread_and_keeps_its_error_for_result() -> None:
    here = threading.get_ident()
    with ThreadPoolExecutor(1) as pool:
        job = Beside(pool, lambda: (time.sleep(0.02), threading.get_ident())[1])
        assert job.result() != here  # ran on the pool's thread
        assert job.result() == job.result()

        def fails() -> int:
            time.sleep(0.02)
            raise ValueError("beside")

        bad = Beside(pool, fails)
        bad.wait()  # waits, does not raise
        with pytest.raises(ValueError, match="beside"):
            bad.result()
    # without a pool: at once, on this thread, the error kept for result() likewise
    assert Beside(None, threading.get_ident).result() == here
    bad = Beside(None, fails)
    bad.wait()
    with pytest.raises(ValueError, match="beside"):
        bad.result()
