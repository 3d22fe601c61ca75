"""Time association follows evo's rule: nearest stamp of the longer trajectory, offset, max diff."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.association import associate, nearest_stamp_indices


def _traj(stamps: list[float] | np.ndarray, x0: float = 0.0) -> Trajectory:
    s = np.asarray(stamps, dtype=np.float64)
    pos = np.zeros((len(s), 3))
    pos[:, 0] = x0 + np.arange(len(s))  # x encodes the row index, to check which rows paired
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(s), 1))
    return Trajectory(s, pos, quats)


def _evo_rule(short: np.ndarray, long_: np.ndarray, offset: float, max_diff: float) -> tuple:
    """The reference rule written as plainly as possible: argmin over all stamps, first on ties."""
    shifted = long_ + offset
    pairs = []
    for i, s in enumerate(short):
        d = np.abs(shifted - s)
        j = int(np.argmin(d))
        if d[j] <= max_diff:
            pairs.append((i, j))
    return tuple(pairs)


def test_each_estimate_pose_takes_the_nearest_ground_truth_within_max_diff() -> None:
    gt = _traj([0.00, 0.01, 0.02, 0.03, 0.04, 0.05, 0.10, 0.20])
    est = _traj([0.012, 0.049, 0.15, 0.31])
    a = associate(gt, est, max_diff_s=0.02)
    # 0.012 -> 0.01; 0.049 -> 0.05; 0.15 is 0.05 from 0.10 and 0.20 (too far); 0.31 too far.
    assert a.gt_indices.tolist() == [1, 5]
    assert a.est_indices.tolist() == [0, 1]
    np.testing.assert_allclose(a.stamp_diffs_s, [0.002, 0.001], atol=1e-12)
    assert a.est.stamps_s.tolist() == [0.012, 0.049]


def test_offset_is_added_to_the_estimate_stamps() -> None:
    gt = _traj(np.arange(0.0, 10.0, 0.1))
    est = _traj(np.arange(0.0, 5.0, 0.5) - 0.3)  # estimate clock runs 0.3 s behind
    assert len(associate(gt, est, max_diff_s=0.02, offset_s=0.0)) == 9  # -0.3 has no partner
    a = associate(gt, est, max_diff_s=0.02, offset_s=0.3)
    assert len(a) == 10
    np.testing.assert_allclose(a.gt.stamps_s, est.stamps_s + 0.3, atol=1e-12)
    assert a.offset_s == 0.3


def test_offset_is_applied_the_same_way_when_the_estimate_is_the_longer_trajectory() -> None:
    gt = _traj(np.arange(0.0, 5.0, 0.5))
    est = _traj(np.arange(0.0, 10.0, 0.1) - 0.3)
    a = associate(gt, est, max_diff_s=0.02, offset_s=0.3)
    assert len(a) == 10
    np.testing.assert_allclose(a.est.stamps_s + 0.3, a.gt.stamps_s, atol=1e-12)
    # Pairs follow the short (ground-truth) order.
    assert a.gt_indices.tolist() == list(range(10))


def test_duplicate_stamps_pair_with_the_first_of_equal_candidates_and_may_share_a_partner() -> None:
    gt = _traj([1.0, 1.0, 1.0, 2.0, 3.0, 4.0])  # duplicate ground-truth stamps
    est = _traj([1.0, 3.0, 3.0])  # duplicate estimate stamps
    a = associate(gt, est, max_diff_s=0.01)
    assert a.gt_indices.tolist() == [0, 4, 4]  # first of the run of 1.0; 3.0 used twice
    assert a.est_indices.tolist() == [0, 1, 2]


def test_a_tie_between_two_neighbours_goes_to_the_earlier_stamp() -> None:
    gt = _traj([0.0, 0.5, 1.0, 1.5])
    est = _traj([0.25])
    assert associate(gt, est, max_diff_s=0.3).gt_indices.tolist() == [0]


def test_nothing_within_max_diff_raises_an_error_naming_both_trajectories() -> None:
    gt = _traj(np.arange(0.0, 1.0, 0.1))
    est = _traj(np.arange(100.0, 101.0, 0.1))
    with pytest.raises(EvalError, match=r"no associated stamps between gt\.txt .* and est\.txt"):
        associate(gt, est, max_diff_s=0.02, gt_name="gt.txt", est_name="est.txt")


def test_an_empty_trajectory_raises_an_error_naming_it() -> None:
    with pytest.raises(EvalError, match=r"est\.txt: trajectory is empty"):
        associate(_traj([0.0, 1.0]), _traj([]), gt_name="gt.txt", est_name="est.txt")


def test_a_negative_max_diff_is_rejected() -> None:
    with pytest.raises(EvalError, match="max time difference"):
        associate(_traj([0.0]), _traj([0.0]), max_diff_s=-1.0)


@pytest.mark.parametrize("seed", range(20))
def test_fast_search_equals_the_plain_argmin_rule_on_random_stamps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    long_ = np.sort(np.round(rng.uniform(0, 10, size=rng.integers(1, 400)), 2))  # many duplicates
    short = np.round(rng.uniform(-1, 11, size=rng.integers(1, 100)), 3)
    offset = float(rng.choice([0.0, 0.005, -0.013]))
    idx, dist = nearest_stamp_indices(short, long_, offset)
    expected = _evo_rule(short, long_, offset, np.inf)
    assert [(i, int(j)) for i, j in enumerate(idx)] == list(expected)
    np.testing.assert_array_equal(dist, np.abs(long_[idx] + offset - short))


def test_unsorted_stamps_fall_back_to_the_plain_rule() -> None:
    long_ = np.array([3.0, 1.0, 2.0, 1.0])
    idx, _ = nearest_stamp_indices(np.array([1.1, 2.9]), long_)
    assert idx.tolist() == [1, 0]
