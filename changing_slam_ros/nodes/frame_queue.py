"""The tracking node's paired colour/depth frames waiting for their detections: order, deadlines, frame policy.

ROS-free (the messages are carried, never read). A frame is *ready* when its detections are settled (in, or known not
to come) or its deadline (steady-clock seconds) has passed. The node tracks ready frames from the head, in stamp
order; with policy `latest` (real time) the frames older than the newest ready one are dropped first, so no queue
builds up behind a slow frame, except those whose deadline has not passed yet: a frame still within its wait for its
own detections is not given up for a later frame that is ready at once (one the detector announced it skips), so no
frame waits past its deadline. `next_deadline_s` tells the node when to wake up for a frame whose detections do not
come.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from changing_slam_ros.errors import SlamError

POLICIES = ("all", "latest")


@dataclass
class PendingFrame:
    """A colour/depth pair waiting for its detections (or its deadline, steady-clock seconds)."""

    stamp_ns: int
    rgb_msg: Any
    depth_msg: Any
    received_s: float
    deadline_s: float


class FrameQueue:
    """Frames in arrival (stamp) order. `has_detections(stamp_ns)` says whether a frame's detections are settled:
    in, or known not to come (the detector announced it skips the image, or it has detected a later one)."""

    def __init__(self, policy: str, has_detections: Callable[[int], bool]) -> None:
        if policy not in POLICIES:
            raise SlamError(f"tracking: parameter frame_policy: '{policy}' unknown; expected all or latest")
        self.policy = policy
        self._has_detections = has_detections
        self._frames: deque[PendingFrame] = deque()

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self) -> Iterator[PendingFrame]:
        return iter(self._frames)

    def push(self, frame: PendingFrame) -> None:
        self._frames.append(frame)

    def _ready(self, frame: PendingFrame, now_s: float) -> bool:
        return self._has_detections(frame.stamp_ns) or now_s >= frame.deadline_s

    def take_stale(self, now_s: float) -> list[PendingFrame]:
        """Policy `latest`: remove and return the frames older than the newest ready one whose deadline has passed
        (none with `all`). Deadlines follow arrival order, so the dropped ones are a prefix."""
        if self.policy != "latest" or len(self._frames) < 2:
            return []
        newest = max((i for i, f in enumerate(self._frames) if self._ready(f, now_s)), default=0)
        old = 0
        while old < newest and self._frames[old].deadline_s <= now_s:
            old += 1
        return [self._frames.popleft() for _ in range(old)]

    def pop_ready(self, now_s: float) -> PendingFrame | None:
        """The head frame when it is ready (removed), else None (it waits, and so do the ones behind it)."""
        if self._frames and self._ready(self._frames[0], now_s):
            return self._frames.popleft()
        return None

    def pop(self) -> PendingFrame:
        """The head frame, ready or not (shutting down: track what is left)."""
        return self._frames.popleft()

    def next_deadline_s(self) -> float | None:
        """The earliest deadline of a waiting frame, or None when none waits."""
        return min((f.deadline_s for f in self._frames), default=None)

    def received_s(self, stamp_ns: int) -> float | None:
        """When the waiting frame with this stamp was received, if one waits."""
        return next((f.received_s for f in self._frames if f.stamp_ns == stamp_ns), None)
