"""Per-cycle buffers reused across cycles (fresh allocations every cycle cost page faults,
which serialise the two threads).

:class:`Pool` hands a cycle its buffers with a lease; whatever reads them later (the
verdict's lazy geometry, ``Monitor.last_images``) holds the lease, and the buffers go back
to the spares once nobody does. :class:`CycleBuffers` is one cycle's images: every
camera's free depth, segment ends and their pyramids.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Generic, TypeVar

import numpy as np

from .pieces import CameraStack, ImageStack, PyramidStack
from .pixels import PixelBuffers, StaticClasses

__all__ = ["CycleBuffers", "Lease", "Pool"]

_T = TypeVar("_T")


class CycleBuffers:
    """One cycle's images: every camera's free depth, segment ends and pyramids."""

    def __init__(self, stack: CameraStack, statics: list[StaticClasses], free_static: list[np.ndarray]) -> None:
        self.free = ImageStack(stack, fill=None)
        self.end = ImageStack(stack, fill=None)
        # the static images, and their pyramids: each cycle restores and updates only
        # what the last one changed
        self.pixels = [
            PixelBuffers(st, fs, self.free.image(i), self.end.image(i))
            for i, (st, fs) in enumerate(zip(statics, free_static, strict=True))
        ]
        self.pyramids = PyramidStack.allocate(self.free)
        # the segment ends' pyramids: outside them is the padded robot's occlusion M
        # (what the shadow memory holds, :mod:`polyhull.engine.memory`)
        self.end_pyramids = PyramidStack.allocate(self.end)
        for i in range(len(statics)):
            self.pyramids.build_camera(i)
            self.end_pyramids.build_camera(i)


class Lease:
    """What a cycle's readers hold while buffers of a :class:`Pool` are in use."""


class Pool(Generic[_T]):
    """Buffers reused once nobody holds their lease.

    A cycle takes buffers with a lease (:meth:`take`); whatever reads them later (the
    verdict's lazy geometry, ``last_images``) holds the lease, and when the lease is gone
    the buffers go back to the spares. Buffers whose lease is kept for long stay as they
    are; the pool then makes new ones.
    """

    def __init__(self, make: Callable[[], _T]) -> None:
        self._make = make
        self._spare: list[_T] = []

    def take(self) -> tuple[_T, Lease]:
        item = self._spare.pop() if self._spare else self._make()
        lease = Lease()
        weakref.finalize(lease, self._spare.append, item)
        return item, lease

