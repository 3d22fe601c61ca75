"""Exclusive thread-CPU time per stage for the CPU benchmarks (`bench_tracking_cpu.py`, `bench_local_mapping_cpu.py`).

Wrap functions from outside with `StageClock.wrap(fn, label)` (or replace an attribute in place with
`StageClock.patch(obj, name, label)`); time goes to the innermost open stage, in thread CPU
time (`time.thread_time_ns`), so a shared machine changes it less than wall time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


class StageClock:
    """Exclusive thread-CPU time per label: a stack of open stages, time goes to the innermost."""

    def __init__(self) -> None:
        self.ns: dict[str, int] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[str] = []
        self._t = 0

    def _switch(self) -> None:
        now = time.thread_time_ns()
        if self._stack:
            top = self._stack[-1]
            self.ns[top] = self.ns.get(top, 0) + now - self._t
        self._t = now

    def wrap(self, fn: Callable[..., Any], label: str) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            self._switch()
            self._stack.append(label)
            self.calls[label] = self.calls.get(label, 0) + 1
            try:
                return fn(*args, **kwargs)
            finally:
                self._switch()
                self._stack.pop()

        return timed

    def patch(self, obj: Any, name: str, label: str) -> None:
        """Replace `obj.name` (a method, a class attribute or a module-level function) by its timed wrapper;
        nothing when `obj` is None or has no such attribute (a stage this configuration does not run)."""
        if obj is not None and hasattr(obj, name):
            setattr(obj, name, self.wrap(getattr(obj, name), label))
