"""`nodes.heap_trim.HeapTrim`: glibc's malloc_trim at most once per interval, and a no-op without it."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from changing_slam_ros.nodes.heap_trim import HeapTrim


def test_trims_at_most_once_per_interval() -> None:
    now = [0.0]
    calls: list[int] = []
    heap = HeapTrim(10.0, clock=lambda: now[0], trim=lambda pad: calls.append(pad) or 1)
    for t in (1.0, 9.9, 10.0, 15.0, 20.1, 20.2):
        now[0] = t
        heap.maybe_trim()
    assert calls == [0, 0] and heap.n_trims == 2  # at 10.0 and 20.1


def test_without_malloc_trim_or_with_interval_zero_it_does_nothing() -> None:
    assert not HeapTrim(10.0, trim=None).available
    assert not HeapTrim(10.0, trim=None).maybe_trim()
    assert not HeapTrim(0.0, trim=lambda pad: 1).maybe_trim()


def rss_mib() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc and /proc")
def test_freed_small_blocks_go_back_to_the_system() -> None:
    heap = HeapTrim(1e-9)
    if not heap.available:
        pytest.skip("no glibc malloc_trim here")
    # many small arrays (below mmap's threshold: they live on the heap), then all but every 64th freed: the
    # survivors pin the heap's top, so glibc keeps the freed pages until a trim hands them back
    blocks = [np.ones(2000) for _ in range(40000)]
    keep = blocks[::64]
    del blocks
    before = rss_mib()
    heap._last = -1.0  # noqa: SLF001 - due now
    assert heap.maybe_trim()
    assert before - rss_mib() > 100.0  # ~600 MiB allocated, ~98 % freed
    assert len(keep) == 625


def test_the_interval_comes_from_the_environment() -> None:
    from changing_slam_ros.errors import ConfigError
    from changing_slam_ros.nodes.heap_trim import DEFAULT_INTERVAL_S, interval_from_env

    assert interval_from_env({}) == DEFAULT_INTERVAL_S
    assert interval_from_env({"CHANGING_SLAM_HEAP_TRIM_S": "0"}) == 0.0
    assert interval_from_env({"CHANGING_SLAM_HEAP_TRIM_S": " 2.5 "}) == 2.5
    for bad in ("abc", "-1", "nan", "inf"):
        with pytest.raises(ConfigError, match="CHANGING_SLAM_HEAP_TRIM_S"):
            interval_from_env({"CHANGING_SLAM_HEAP_TRIM_S": bad})
