"""ATE and RPE equal evo 1.31.0's figures on the TUM reference trajectories (fixture from evo's CLI)."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import pytest
from helpers import TUM_REFERENCE, require

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.eval.ate import ate
from changing_slam_ros.eval.rpe import DeltaUnit, rpe
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

FIXTURE = json.loads((Path(__file__).parent / "evo_reference.json").read_text())
TOL = 1e-6  # metres (ATE, RPE translation) and degrees (RPE rotation)


@lru_cache(maxsize=None)
def _read(name: str) -> Trajectory:
    return read_tum_trajectory(require(TUM_REFERENCE) / name)


def _row_id(row: dict) -> str:
    return row["command"].replace("evo_", "").replace(" tum ", " ")


def test_fixture_was_made_by_evo_1_31_0_and_covers_every_pair_at_two_max_diffs() -> None:
    assert FIXTURE["evo_version"] == "1.31.0"
    pairs = {(r["gt"], r["est"]) for r in FIXTURE["ape"]
             if r["max_diff_s"] == 0.02 and not r.get("swapped") and not r.get("self_comparison")}
    assert len(pairs) == 6
    for gt, est in pairs:
        diffs = {r["max_diff_s"] for r in FIXTURE["ape"] if (r["gt"], r["est"]) == (gt, est)}
        assert {0.02, 0.01} <= diffs
    # The estimate-longer branch of the association (with an offset) is covered too.
    assert any(r.get("swapped") and r["offset_s"] != 0.0 for r in FIXTURE["ape"])


@pytest.mark.parametrize("row", FIXTURE["ape"], ids=_row_id)
def test_ate_equals_evo_ape(row: dict) -> None:
    res = ate(_read(row["gt"]), _read(row["est"]), max_diff_s=row["max_diff_s"],
              offset_s=row["offset_s"], sim3=row["sim3"])
    assert res.stats.count == row["count"]
    ours = res.stats.to_dict()
    for key, value in row["stats"].items():
        assert ours[key] == pytest.approx(value, abs=TOL), key


@pytest.mark.parametrize("row", FIXTURE["rpe"], ids=_row_id)
def test_rpe_in_frames_equals_evo_rpe(row: dict) -> None:
    res = rpe(_read(row["gt"]), _read(row["est"]), delta=row["delta_frames"],
              delta_unit=DeltaUnit.FRAMES, all_pairs=row["all_pairs"],
              max_diff_s=row["max_diff_s"], sim3=row["sim3"])
    stats = res.trans if row["relation"] == "translation_m" else res.rot
    assert stats.count == row["count"]
    ours = stats.to_dict()
    for key, value in row["stats"].items():
        assert ours[key] == pytest.approx(value, abs=TOL), key


def test_a_duplicated_ground_truth_stamp_pairs_like_evo_so_self_comparison_is_not_zero() -> None:
    gt = _read("fr2_desk_groundtruth.txt")
    assert len(gt) - len(set(gt.stamps_s.tolist())) == 1
    row = next(r for r in FIXTURE["ape"] if r.get("self_comparison"))
    res = ate(gt, gt)
    assert res.stats.max == pytest.approx(row["stats"]["max"], abs=TOL)
    assert res.stats.max > 1e-3  # the second pose of the duplicated stamp meets the first one
