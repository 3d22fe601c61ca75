"""`edge_test.match_nearby`: mutual best matches around predicted positions, and no match at all."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.movers.edge_test import match_nearby


def _desc(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.integers(0, 256, size=(n, 32), dtype=np.uint8)


def test_keypoints_moved_by_a_known_shift_match_their_own_earlier_keypoints():
    rng = np.random.default_rng(3)
    past = rng.uniform(0, 300, size=(40, 2))
    desc = _desc(rng, 40)
    now = past + [4.0, -2.0]
    q, t = match_nearby(now, desc, past, desc, now - [4.0, -2.0], radius_px=20.0, max_hamming=50)
    assert len(q) == 40 and np.array_equal(q, t)


def test_no_descriptor_within_reach_gives_no_match_instead_of_an_error():
    rng = np.random.default_rng(4)
    past = rng.uniform(0, 300, size=(10, 2))
    now = past.copy()
    desc_past = np.zeros((10, 32), np.uint8)
    desc_now = np.full((10, 32), 255, np.uint8)  # 256 bits away from every earlier descriptor
    q, t = match_nearby(now, desc_now, past, desc_past, now, radius_px=20.0, max_hamming=50)
    assert q.shape == (0,) and t.shape == (0,)
