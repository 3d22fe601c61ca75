"""RecentValues: the statistics of a list while it holds every value; the last `capacity` values after, with the
whole run's count, mean and max."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.recent_values import RecentValues


def _values(n: int) -> list[float]:
    return np.random.default_rng(0).gamma(2.0, 10.0, n).tolist()


def test_while_every_value_is_kept_it_gives_what_the_list_gives_bit_for_bit() -> None:
    values = _values(1000)
    recent = RecentValues(1000)
    for v in values:
        recent.append(v)
    a = np.asarray(values)
    assert len(recent) == 1000 and list(recent) == values and np.asarray(recent).tolist() == values
    assert recent.summary() == {
        "count": 1000.0, "mean": float(a.mean()), "p50": float(np.percentile(a, 50)),
        "p90": float(np.percentile(a, 90)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
    }  # fmt: skip
    assert recent.median() == float(np.median(a)) and recent.percentile(90) == float(np.percentile(a, 90))
    assert recent.mean() == float(np.mean(values)) and recent.max() == max(values)
    assert recent[:2].tolist() == values[:2] and recent[-1] == values[-1]


def test_past_the_capacity_it_keeps_the_last_values_and_the_whole_runs_count_mean_and_max() -> None:
    values = _values(1000)
    values[10] = 1e6  # the largest, long gone from the ring
    recent = RecentValues(256)
    for v in values:
        recent.append(v)
    assert len(recent) == 1000 and list(recent) == values[-256:]
    assert recent.max() == 1e6 and recent.mean() == pytest.approx(np.mean(values), rel=1e-12)
    assert recent.median() == float(np.median(values[-256:]))
    s = recent.summary()
    assert s["count"] == 1000.0 and s["max"] == 1e6 and s["p99"] == float(np.percentile(values[-256:], 99))
    assert len(recent._buf) == 256  # noqa: SLF001 - the memory stays at the capacity


def test_empty() -> None:
    recent = RecentValues()
    assert not recent and len(recent) == 0 and list(recent) == [] and recent.summary() == {}
    assert recent.median() is None and recent.percentile(90) is None and recent.mean() is None and recent.max() is None
    with pytest.raises(ValueError, match="capacity"):
        RecentValues(0)
