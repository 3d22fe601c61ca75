"""`FramePipeline`: every frame paired with its own detections in order, whatever the timing; the detector runs
ahead on its own thread only when overlapped; a worker's exception reaches the consumer at its frame; leaving
the `with` block stops the threads even when they are blocked."""

from __future__ import annotations

import itertools
import random
import threading
import time
from collections.abc import Iterator

import pytest

from changing_slam_ros.commands.frame_pipeline import FramePipeline


def _jittery_detect(seed: int):
    rng = random.Random(seed)

    def detect(frame: int) -> tuple[str, ...]:
        time.sleep(rng.uniform(0.0, 0.004))
        return (f"boxes of {frame}",)

    return detect


@pytest.mark.parametrize("overlap", [True, False])
@pytest.mark.parametrize("lookahead", [1, 2, 5])
def test_each_frame_gets_its_own_detections_in_order(overlap: bool, lookahead: int) -> None:
    rng = random.Random(lookahead)
    got = []
    with FramePipeline(range(100), 60, _jittery_detect(lookahead), overlap, lookahead) as pipeline:  # type: ignore[arg-type]
        for frame, detections in pipeline:
            time.sleep(rng.uniform(0.0, 0.004))  # the consumer's work, of varying length
            got.append((frame, detections))
    assert got == [(k, (f"boxes of {k}",)) for k in range(60)]


def _recording_detect(calls: list[int]):
    def detect(frame: int) -> tuple[()]:
        calls.append(frame)
        return ()

    return detect


def test_overlapped_detection_runs_ahead_by_the_lookahead_only() -> None:
    calls: list[int] = []
    with FramePipeline(range(50), 50, _recording_detect(calls), overlap=True, lookahead=2) as pipeline:  # type: ignore[arg-type]
        frames = iter(pipeline)
        assert next(frames)[0] == 0
        deadline = time.monotonic() + 5.0
        while len(calls) < 4 and time.monotonic() < deadline:  # 1 and 2 queued, 3 detected and waiting for room
            time.sleep(0.01)
        time.sleep(0.2)
        assert calls == [0, 1, 2, 3]  # detected while frame 0 is "tracked", and no further
        assert [next(frames)[0] for _ in range(3)] == [1, 2, 3]


def test_serial_detection_runs_on_the_consumers_thread_in_turn() -> None:
    threads: list[str] = []

    def detect(frame: int) -> tuple[()]:
        threads.append(threading.current_thread().name)
        return ()

    with FramePipeline(range(50), 50, detect, overlap=False) as pipeline:  # type: ignore[arg-type]
        frames = iter(pipeline)
        next(frames)
        time.sleep(0.2)
        assert len(threads) == 1  # frame 1 is not detected before it is asked for
        next(frames)
    assert threads == [threading.current_thread().name] * 2


class Corrupt(Exception):
    pass


@pytest.mark.parametrize("overlap", [True, False])
def test_a_detector_error_is_raised_at_its_frame_and_the_threads_stop(overlap: bool) -> None:
    def detect(frame: int) -> tuple[()]:
        if frame == 3:
            raise Corrupt("frame 3: corrupt image")
        return ()

    got = []
    with pytest.raises(Corrupt, match="frame 3: corrupt image"):
        with FramePipeline(range(100), 100, detect, overlap) as pipeline:  # type: ignore[arg-type]
            for frame, _ in pipeline:
                got.append(frame)
    assert got == [0, 1, 2]
    assert pipeline.threads_alive() == []


@pytest.mark.parametrize("overlap", [True, False])
def test_a_reader_error_is_raised_at_its_frame_and_the_threads_stop(overlap: bool) -> None:
    def frames() -> Iterator[int]:
        yield from range(5)
        raise Corrupt("frame 5: cannot decode")

    got = []
    with pytest.raises(Corrupt, match="frame 5: cannot decode"):
        with FramePipeline(frames(), 100, _recording_detect([]), overlap) as pipeline:  # type: ignore[arg-type]
            for frame, _ in pipeline:
                got.append(frame)
    assert got == [0, 1, 2, 3, 4]
    assert pipeline.threads_alive() == []


@pytest.mark.parametrize("overlap", [True, False])
def test_an_interrupt_in_the_consumer_stops_blocked_workers_promptly(overlap: bool) -> None:
    """An endless source: the reader and the detector are blocked on their full queues when the consumer stops."""
    with pytest.raises(KeyboardInterrupt):
        with FramePipeline(itertools.count(), 10**9, _recording_detect([]), overlap) as pipeline:  # type: ignore[arg-type]
            for frame, _ in pipeline:
                if frame == 2:
                    time.sleep(0.3)  # let the workers fill their queues
                    t0 = time.monotonic()
                    raise KeyboardInterrupt
    assert pipeline.threads_alive() == []
    assert time.monotonic() - t0 < 1.0


def test_a_lookahead_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="lookahead"):
        FramePipeline(range(3), 3, _recording_detect([]), lookahead=0)  # type: ignore[arg-type]
