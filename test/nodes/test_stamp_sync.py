"""Approximate-time colour/depth pairing (nodes/stamp_sync.py) against brute-force nearest-stamp association."""

from __future__ import annotations

import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.nodes.stamp_sync import ApproximatePairer

MS = 1_000_000


def _stamps(path) -> list[int]:  # noqa: ANN001
    return [round(float(ln.split()[0]) * 1e9) for ln in path.read_text().splitlines() if ln and ln[0] != "#"]


def _feed(colour: list[int], depth: list[int], slop_ns: int) -> tuple[list[tuple[int, int]], ApproximatePairer]:
    """Feed both streams merged in stamp order, as a bag player would publish them."""
    pairer: ApproximatePairer[int, int] = ApproximatePairer(slop_ns)
    events = sorted([(t, 0) for t in colour] + [(t, 1) for t in depth])
    pairs = []
    for t, kind in events:
        made = pairer.add_first(t, t) if kind == 0 else pairer.add_second(t, t)
        pairs += [(a, b) for a, _, b, _ in made]
    return pairs, pairer


def test_fr1_colour_frames_pair_with_their_nearest_depth_frame():
    root = require(FR1_XYZ_10)
    colour, depth = _stamps(root / "rgb.txt"), _stamps(root / "depth.txt")
    pairs, pairer = _feed(colour, depth, slop_ns=20 * MS)
    # Offline: each colour frame takes the nearest depth frame not used by an earlier colour frame (one to one,
    # in order), when within the slop and a depth frame at or after it exists.
    expected, free = [], list(depth)
    for c in colour:
        if not free:
            break
        d = min(free, key=lambda x: abs(x - c))
        if abs(d - c) <= 20 * MS and max(depth) >= c:
            expected.append((c, d))
            free = [x for x in free if x > d]
    assert pairs == expected and len(pairs) >= 8
    assert all(abs(c - d) <= 20 * MS for c, d in pairs)


def test_streams_that_never_come_within_the_slop_do_not_pair_and_are_counted():
    colour = [i * 100 * MS for i in range(10)]
    depth = [t + 50 * MS for t in colour]  # half-way between colour frames: 50 ms from either
    pairs, pairer = _feed(colour, depth, slop_ns=20 * MS)
    assert pairs == [] and pairer.stats.dropped_first >= 8


def test_a_dropped_depth_frame_leaves_its_colour_frame_unpaired_but_the_next_ones_pair():
    colour = [i * 33 * MS for i in range(6)]
    depth = [t + 5 * MS for i, t in enumerate(colour) if i != 2]
    pairs, pairer = _feed(colour, depth, slop_ns=15 * MS)
    assert [c for c, _ in pairs] == [0, 33 * MS, 99 * MS, 132 * MS, 165 * MS]
    assert pairer.stats.dropped_first == 1 and pairer.stats.pairs == 5


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="slop_ns must be >= 0"):
        ApproximatePairer(-1)
