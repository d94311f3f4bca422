"""Matching the frames of several cameras by time into monitor cycles.

The first camera (the *lead*, the cell's first camera present in the recording) clocks the
cycles: every lead frame starts one. Each other camera contributes the frame nearest in
time to the lead frame, if one lies within ``max_age`` (``safety.max_frame_age``) of it
and was not used by an earlier cycle; otherwise that camera is absent from the cycle,
and the monitor reports it missing. The frames of a cycle span at most ``max_age`` (the
ones farthest from the lead frame are dropped until they do), so none reaches the monitor
stale. The joint state of a cycle is the newest sample
measured at or before the cycle's stamp (the newest frame's), else the first one after.

Streaming: frames are held only until the recording's clock has passed the lead frame by
``max_age``, so memory stays bounded by the frames of that window.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator

from ..errors import PolyhullError
from ..frames import DepthFrame
from .base import Cycle, Event, JointSample

__all__ = ["cycles"]


def cycles(events: Iterable[Event], cameras: tuple[str, ...], max_age: float) -> Iterator[Cycle]:
    """Match a time-ordered stream of frames and joint samples into cycles.

    Args:
        events: Frames and joint samples in recorded order (stamps may be slightly out of
            order: anything within ``max_age`` is matched correctly).
        cameras: Camera names; the first one is the lead.
        max_age: Largest time difference [s] between a lead frame and a matched frame.

    Yields:
        One :class:`Cycle` per lead frame, in order.
    """
    if not cameras:
        raise PolyhullError("cycles: no cameras to match")
    if not max_age > 0:
        raise PolyhullError(f"cycles: max_age must be > 0 s, got {max_age!r}")
    lead = cameras[0]
    pending: dict[str, deque[DepthFrame]] = {c: deque() for c in cameras}
    joints: deque[JointSample] = deque(maxlen=4096)
    clock = -float("inf")

    def finish(lead_frame: DepthFrame) -> Cycle:
        t = lead_frame.stamp
        frames = {lead: lead_frame}
        for name in cameras[1:]:
            queue = pending[name]
            while queue and queue[0].stamp < t - max_age:
                queue.popleft()  # too old for this and every later lead frame
            best = None
            for i, f in enumerate(queue):
                if abs(f.stamp - t) <= max_age and (best is None or abs(f.stamp - t) < abs(queue[best].stamp - t)):
                    best = i
            if best is not None:
                frames[name] = queue[best]
                for _ in range(best + 1):
                    queue.popleft()  # used, or older than the one used
        # The cycle's stamp is its newest frame: keep every frame within max_age of it (a
        # set spanning more would reach the monitor with a stale frame), dropping the
        # frames farthest from the lead first.
        while max(f.stamp for f in frames.values()) - min(f.stamp for f in frames.values()) > max_age:
            far = max((n for n in frames if n != lead), key=lambda n: abs(frames[n].stamp - t))
            del frames[far]
        stamp = max(f.stamp for f in frames.values())
        sample = None
        for s in joints:
            if s.stamp <= stamp:
                sample = s
            elif sample is None:
                sample = s
                break
            else:
                break
        return Cycle(stamp, frames, None if sample is None else sample.q, None if sample is None else sample.stamp)

    for event in events:
        if isinstance(event, JointSample):
            if joints and event.stamp < joints[-1].stamp:
                continue  # out of order: an older sample than one already held is dropped
            joints.append(event)
            clock = max(clock, event.stamp)
        else:
            if event.camera not in pending:
                continue
            pending[event.camera].append(event)
            clock = max(clock, event.stamp)
        lead_queue = pending[lead]
        while lead_queue and clock > lead_queue[0].stamp + max_age:
            yield finish(lead_queue.popleft())
        if not lead_queue:
            for name in cameras[1:]:  # bounded memory while the lead camera is silent
                queue = pending[name]
                while queue and queue[0].stamp < clock - 2 * max_age:
                    queue.popleft()
        while len(joints) > 1 and lead_queue and joints[1].stamp <= lead_queue[0].stamp - max_age:
            joints.popleft()  # a newer sample is also before every pending cycle
    while pending[lead]:
        yield finish(pending[lead].popleft())
