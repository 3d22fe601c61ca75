"""Per-frame figures (stage timings, latencies) kept for their statistics in bounded memory.

A run appends one value per frame (or per keyframe) for as long as it runs; a list of Python floats costs ~32
bytes a value and grows without end on a robot that runs for days. `RecentValues` keeps the newest `capacity`
values in a float64 ring and the count, sum and maximum of all of them. The ring is allocated at the first value
(8 bytes a value: 256 KiB at the default capacity, about 4 MiB for the tracking node's figures) and never grows:

- `len()`, `mean()`, `max()`: every value appended (the whole run);
- `median()`, `percentile(q)`, iteration, indexing and `np.asarray`: the values kept, oldest first, i.e. the
  last `capacity` ones (every value while fewer were appended; then exactly what a list would give).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]

# Values kept per figure: 256 KiB of float64; at 15-30 frames/s the last 18-36 minutes of a per-frame figure.
RECENT_CAPACITY = 32768


class RecentValues:
    """The newest `capacity` values appended (for median and percentiles), with the whole run's count, mean and max."""

    __slots__ = ("capacity", "_buf", "_n", "_sum", "_max")

    def __init__(self, capacity: int = RECENT_CAPACITY) -> None:
        if capacity < 1:
            raise ValueError(f"RecentValues: capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self._buf: F64 = np.empty(0, np.float64)
        self._n = 0  # values appended
        self._sum = 0.0
        self._max = -np.inf

    def append(self, value: float) -> None:
        v = float(value)
        if not len(self._buf):
            self._buf = np.zeros(self.capacity, np.float64)
        self._buf[self._n % self.capacity] = v
        self._n += 1
        self._sum += v
        self._max = max(self._max, v)

    def __len__(self) -> int:
        """Values appended over the whole run (more than are kept once `capacity` is passed)."""
        return self._n

    def kept(self) -> F64:
        """The values kept (the last `capacity` appended), oldest first, as a new array."""
        if self._n <= self.capacity:
            return self._buf[: self._n].copy()
        i = self._n % self.capacity
        return np.concatenate((self._buf[i:], self._buf[:i]))

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> F64:
        a = self.kept()
        return a if dtype is None else a.astype(dtype)

    def __iter__(self) -> Iterator[float]:
        return iter(self.kept().tolist())

    def __getitem__(self, key: Any) -> Any:
        return self.kept()[key]

    def __repr__(self) -> str:
        return f"RecentValues({self._n} appended, {min(self._n, self.capacity)} kept)"

    def mean(self) -> float | None:
        """Mean of every value appended; None before the first."""
        if self._n == 0:
            return None
        return float(np.mean(self.kept())) if self._n <= self.capacity else self._sum / self._n

    def max(self) -> float | None:
        """Largest value appended; None before the first."""
        return float(self._max) if self._n else None

    def median(self) -> float | None:
        """Median of the values kept; None before the first."""
        return float(np.median(self.kept())) if self._n else None

    def percentile(self, q: float) -> float | None:
        """Percentile `q` (0-100) of the values kept; None before the first."""
        return float(np.percentile(self.kept(), q)) if self._n else None

    def summary(self) -> dict[str, float]:
        """count and mean (whole run), p50 / p90 / p99 (values kept), max (whole run); {} before the first value."""
        if self._n == 0:
            return {}
        a = self.kept()
        mean = float(a.mean()) if self._n <= self.capacity else self._sum / self._n
        return {
            "count": float(self._n), "mean": mean, "p50": float(np.percentile(a, 50)),
            "p90": float(np.percentile(a, 90)), "p99": float(np.percentile(a, 99)), "max": float(self._max),
        }  # fmt: skip
