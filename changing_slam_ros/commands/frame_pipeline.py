"""The frames of an offline run, each with its own detections, in order (a helper of `commands/run.py`).

    with FramePipeline(frames, n, detect, overlap=True, lookahead=2) as pipeline:
        for frame, detections in pipeline:
            ...

A reader thread decodes frames ahead of use in both modes. Serial: `detect(frame)` runs on the caller's thread
just before the frame is handed out, so detection and tracking take turns. Overlapped: a detector thread runs
`detect` on the next frames (at most `lookahead` finished ones waiting) while the caller tracks the current one;
onnxruntime and image decoding release the GIL, so the threads use both cores. Either way frame k is paired
with `detect(frame k)` and nothing else, in frame order, so what SLAM computes does not depend on timing.
An exception on a worker thread is raised on the caller's thread when it reaches that frame; leaving the `with`
block (the end, an error, Ctrl-C) stops the workers and joins them.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from typing import Any, Generic, TypeVar

from changing_slam_ros.core.dynamic.detector import Detection
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame

T = TypeVar("T")
U = TypeVar("U")
Detections = tuple[Detection, ...] | None
Detect = Callable[[RgbdFrame], Detections]

READ_AHEAD = 8  # decoded frames the reader keeps ready
JOIN_TIMEOUT_S = 10.0  # longest wait for a worker to finish the item in hand when the pipeline closes
_POLL_S = 0.05


@dataclass(frozen=True)
class _Failed:
    """An exception raised on a worker thread, carried to the consumer."""

    error: BaseException


_DONE = object()


class _Worker(Generic[T, U]):
    """A daemon thread that applies `fn` to each of `items` in order into a bounded queue; iterating the worker
    (on one consumer thread) yields the results and raises the exception that stopped the thread, if any."""

    def __init__(self, name: str, items: Iterable[T], fn: Callable[[T], U], depth: int) -> None:
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._main, args=(items, fn), name=name, daemon=True)
        self.thread.start()

    def _put(self, item: Any) -> bool:
        """Queue `item`, waiting for room; False when the worker was stopped meanwhile."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _main(self, items: Iterable[T], fn: Callable[[T], U]) -> None:
        try:
            for item in items:
                if self._stop.is_set() or not self._put(fn(item)):
                    return
        except BaseException as err:  # noqa: BLE001 - raised again on the consumer's thread
            self._put(_Failed(err))
            return
        self._put(_DONE)

    def __iter__(self) -> Iterator[U]:
        while True:
            try:
                item = self._queue.get(timeout=_POLL_S)
            except queue.Empty:
                if self.thread.is_alive() or not self._queue.empty():
                    continue
                return  # stopped before the end: nothing more will come
            if item is _DONE:
                return
            if isinstance(item, _Failed):
                raise item.error
            yield item

    def stop(self) -> None:
        """Ask the thread to stop after the item in hand (it drops what it has not queued)."""
        self._stop.set()

    def join(self) -> None:
        self.thread.join(JOIN_TIMEOUT_S)


class FramePipeline:
    """The first `n` frames of `frames`, each paired with `detect(frame)`; see the module docstring."""

    def __init__(self, frames: Iterable[RgbdFrame], n: int, detect: Detect, overlap: bool = True,
                 lookahead: int = 2) -> None:  # fmt: skip
        if lookahead < 1:
            raise ValueError(f"lookahead: expected >= 1, got {lookahead}")
        self._frames = islice(frames, max(n, 0))
        self._detect = detect
        self.overlap = overlap
        self.lookahead = lookahead
        self._workers: list[_Worker[Any, Any]] = []

    def __enter__(self) -> FramePipeline:
        reader: _Worker[RgbdFrame, RgbdFrame] = _Worker("frame-reader", self._frames, _same, READ_AHEAD)
        self._workers.append(reader)
        if self.overlap:
            self._workers.append(_Worker("frame-detector", reader, self._paired, self.lookahead))
        return self

    def _paired(self, frame: RgbdFrame) -> tuple[RgbdFrame, Detections]:
        return frame, self._detect(frame)

    def __iter__(self) -> Iterator[tuple[RgbdFrame, Detections]]:
        if not self._workers:
            raise RuntimeError("FramePipeline: iterate inside `with`")
        if self.overlap:
            yield from self._workers[-1]
        else:
            for frame in self._workers[0]:
                yield self._paired(frame)

    def __exit__(self, *exc: object) -> None:
        for worker in self._workers:
            worker.stop()
        for worker in self._workers:
            worker.join()

    def threads_alive(self) -> list[str]:
        """Names of this pipeline's worker threads still running (none once the `with` block is left)."""
        return [w.thread.name for w in self._workers if w.thread.is_alive()]


def _same(frame: RgbdFrame) -> RgbdFrame:
    return frame
