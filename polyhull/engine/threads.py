"""Work shared between the calling thread and one of a pool's.

The engine's parallel stages (each camera's raster and pixels, the two halves of a carve)
run on the calling thread and one pool thread, each taking the next item when it is done:
the calling thread works instead of waiting, and only one sleeping thread has to wake
(on this machine a wake-up costs 0.1 to 0.4 ms in the median, several ms at worst).
Work that a later stage needs only late runs on a pool thread :class:`Beside` the stages
in between.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future, wait
from typing import Generic, TypeVar

__all__ = ["Beside", "share"]

_I = TypeVar("_I")
_R = TypeVar("_R")


def share(pool: Executor | None, fn: Callable[[_I], _R], items: Sequence[_I]) -> list[_R]:
    """``[fn(x) for x in items]``, computed on this thread and one of ``pool``'s (in this
    thread alone without a pool or with fewer than two items). ``fn`` must be safe to run
    on two items at once. When ``fn`` raises, the other thread finishes its item first
    (nothing runs on after the call returns or raises), then the error is raised. Call it
    from a thread outside ``pool`` (the engine calls it from the monitor's thread): from
    inside a pool with no free thread it would wait forever."""
    if pool is None or len(items) < 2:
        return [fn(x) for x in items]
    out: list[_R | None] = [None] * len(items)
    order = iter(range(len(items)))
    lock = threading.Lock()

    def work() -> None:
        while True:
            with lock:
                i = next(order, None)
            if i is None:
                return
            out[i] = fn(items[i])

    other = pool.submit(work)
    try:
        work()
    finally:
        # wait for the other thread in any case; its error, if this one had none
        error = other.exception()
    if error is not None:
        raise error
    return out  # type: ignore[return-value]


class Beside(Generic[_R]):
    """``fn()`` run on one of ``pool``'s threads while the calling thread goes on (at once
    on the calling thread without a pool): :meth:`result` waits for its value or raises
    its error. Whoever starts one waits for it (:meth:`wait`) before returning, also on
    an error, so that nothing runs on after a call returns. Keep at most one running
    beside a stage that calls :func:`share` (whose second thread must find a free one)."""

    def __init__(self, pool: Executor | None, fn: Callable[[], _R]) -> None:
        self._future: Future[_R] | None = None
        self._value: _R | None = None
        self._error: BaseException | None = None
        if pool is None:
            try:
                self._value = fn()
            except Exception as exc:  # noqa: BLE001 - raised by result(), as from a thread
                self._error = exc
        else:
            self._future = pool.submit(fn)

    def result(self) -> _R:
        """Its value (waiting for it), or its error raised."""
        if self._future is not None:
            return self._future.result()
        if self._error is not None:
            raise self._error
        return self._value  # type: ignore[return-value]

    def wait(self) -> None:
        """Wait until it has finished (its error is kept for :meth:`result`)."""
        if self._future is not None:
            wait([self._future])
