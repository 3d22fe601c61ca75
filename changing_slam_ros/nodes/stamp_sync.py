"""Approximate-time pairing of two streams (colour and depth) by header stamp, ROS-free.

message_filters is not on PyPI; this is the small part of it tracking needs. A colour item is paired with
the depth item of nearest stamp once that choice is final: the best candidate is within `slop_ns` and some
depth item at or after the colour stamp has arrived (later ones can only be farther away). Items that can no
longer be paired are dropped and counted, so the node can warn once that the streams do not pair.
Streams are assumed in stamp order each (as a camera driver or a bag publishes them).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

A = TypeVar("A")
B = TypeVar("B")


@dataclass
class PairStats:
    pairs: int = 0
    dropped_first: int = 0
    dropped_second: int = 0


class ApproximatePairer(Generic[A, B]):
    """Pairs `first` (colour) items with `second` (depth) items; `add_*` return the pairs made final."""

    def __init__(self, slop_ns: int, max_queue: int = 30) -> None:
        if slop_ns < 0 or max_queue < 1:
            raise ValueError(f"slop_ns must be >= 0 and max_queue >= 1, got {slop_ns}, {max_queue}")
        self.slop_ns = slop_ns
        self.max_queue = max_queue
        self._first: deque[tuple[int, A]] = deque()
        self._second: deque[tuple[int, B]] = deque()
        self.stats = PairStats()

    @property
    def waiting_first(self) -> int:
        """First-stream (colour) items still waiting for their pair."""
        return len(self._first)

    def add_first(self, stamp_ns: int, item: A) -> list[tuple[int, A, int, B]]:
        self._first.append((stamp_ns, item))
        return self._match()

    def add_second(self, stamp_ns: int, item: B) -> list[tuple[int, A, int, B]]:
        self._second.append((stamp_ns, item))
        return self._match()

    def _match(self) -> list[tuple[int, A, int, B]]:
        out: list[tuple[int, A, int, B]] = []
        while self._first and self._second:
            t_a, a = self._first[0]
            best = min(range(len(self._second)), key=lambda i: abs(self._second[i][0] - t_a))
            t_b, b = self._second[best]
            newest_b = self._second[-1][0]
            if abs(t_b - t_a) <= self.slop_ns and newest_b >= t_a:
                out.append((t_a, a, t_b, b))
                self.stats.pairs += 1
                self._first.popleft()
                for _ in range(best + 1):  # depth items before the chosen one can no longer pair
                    self._second.popleft()
                self.stats.dropped_second += best
                continue
            if newest_b > t_a + self.slop_ns:  # no future depth can come close enough
                self._first.popleft()
                self.stats.dropped_first += 1
                continue
            if self._second[0][0] < t_a - self.slop_ns:  # too old for this and every later colour item
                self._second.popleft()
                self.stats.dropped_second += 1
                continue
            break
        while len(self._first) > self.max_queue:
            self._first.popleft()
            self.stats.dropped_first += 1
        while len(self._second) > self.max_queue:
            self._second.popleft()
            self.stats.dropped_second += 1
        return out
