"""`dynamic.map_view_min_matches`: the keypoints of undecided objects are given to tracking when the kept ones
cannot see the map at the predicted pose and they can (`SlamSystem._withheld_seeing_map`), on real TUM frames."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.commands.keypoint_log import KeypointLog
from changing_slam_ros.core.dynamic.detector import Detection
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter, DynamicFrame
from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.features.orb_features import Features
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.dataset import open_dataset

NEED = 50


def _verdict(keep: np.ndarray, withheld: np.ndarray, since_ns: int) -> DynamicFrame:
    """The filter's verdict: `withheld` keypoints belong to an object first detected at `since_ns`."""
    n = len(keep)
    return DynamicFrame(keep, np.zeros(n, np.int8), np.full(n, -1, np.int64), np.zeros(n, bool), (), 0.0, (), withheld,
                        np.where(withheld, since_ns, 0).astype(np.int64))


@pytest.fixture(scope="module")
def tracked() -> tuple[SlamSystem, object, Features]:
    """A system tracking the first 6 frames of fr1/xyz (no detections: nothing withheld), and the 7th frame's
    keypoints."""
    frames = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))
    system = SlamSystem(dynamic_filter=DynamicFilter(DynamicConfig(map_view_min_matches=NEED)))
    for f in frames[:6]:
        assert system.process(f).state == TrackingState.OK
    target = frames[6]
    return system, target, system._extractor_for(target.camera).extract(target.rgb, target.depth_m)


def test_the_full_frame_sees_the_map_and_a_thin_strip_does_not(tracked) -> None:  # noqa: ANN001
    system, target, feats = tracked
    strip = feats.keypoints_px[:, 0] > target.camera.width - 40
    kp, ids = system.tracker.matches_at_prediction(Frame(target.stamp_ns, 6, target.camera, feats))
    thin, _ = system.tracker.matches_at_prediction(Frame(target.stamp_ns, 6, target.camera, feats.subset(strip)))
    assert len(kp) == len(ids) == len(set(ids.tolist())) >= 4 * NEED and len(thin) < NEED


def test_withheld_keypoints_that_see_the_map_are_used(tracked) -> None:  # noqa: ANN001
    """A box first detected on this frame over all but a strip of the view, on a room mapped before."""
    system, target, feats = tracked
    strip = feats.keypoints_px[:, 0] > target.camera.width - 40  # what an object over the rest of the view leaves
    before = system.n_withheld_used
    out = system._withheld_seeing_map(target, feats, _verdict(strip, ~strip, target.stamp_ns))
    assert out.keep.all() and system.n_withheld_used == before + 1


def test_withheld_keypoints_that_see_only_points_mapped_since_their_box_came_stay_out(tracked) -> None:  # noqa: ANN001
    """The same box detected since before the first frame: every map point its keypoints match was mapped while
    it was in view and may lie on the object (a person the detector calls a chair, mapped while kept)."""
    system, target, feats = tracked
    strip = feats.keypoints_px[:, 0] > target.camera.width - 40
    out = system._withheld_seeing_map(target, feats, _verdict(strip, ~strip, 0))
    assert (out.keep == strip).all()


def test_withheld_keypoints_that_match_no_map_point_stay_out(tracked) -> None:  # noqa: ANN001
    """The same object's keypoints with descriptors of nothing in the map, as a mover in front of the room has."""
    system, target, feats = tracked
    strip = feats.keypoints_px[:, 0] > target.camera.width - 40
    rng = np.random.default_rng(0)
    scrambled = feats.descriptors.copy()
    scrambled[~strip] = rng.integers(0, 256, scrambled[~strip].shape, dtype=np.uint8)
    mover = dataclasses.replace(feats, descriptors=scrambled)
    out = system._withheld_seeing_map(target, mover, _verdict(strip, ~strip, target.stamp_ns))
    assert (out.keep == strip).all()


def test_kept_keypoints_that_see_the_map_are_enough(tracked) -> None:  # noqa: ANN001
    system, target, feats = tracked
    left = feats.keypoints_px[:, 0] < target.camera.width / 2  # half the view sees plenty of the map
    out = system._withheld_seeing_map(target, feats, _verdict(left, ~left, target.stamp_ns))
    assert (out.keep == left).all()


def test_the_check_is_off_at_zero_and_refuses_a_negative_count() -> None:
    assert DynamicConfig().map_view_min_matches == 0
    with pytest.raises(ConfigError, match="map_view_min_matches"):
        DynamicConfig(map_view_min_matches=-1)


def test_an_undecided_box_is_withheld_and_the_keypoint_log_records_its_use(tracked, tmp_path) -> None:  # noqa: ANN001
    """A "clock" over all but the right 40 px of a new frame: its keypoints (those the classification puts on the
    object, not the background behind it) are withheld, with no EKF verdict yet; once tracking uses them, the
    run's keypoint log (`--keypoint-log`) counts them as kept."""
    _, target, feats = tracked
    log = KeypointLog(DynamicFilter(DynamicConfig(min_kept_keypoints=0, map_view_min_matches=NEED)))
    clock = Detection((0.0, 0.0, float(target.camera.width - 40), float(target.camera.height)), 74, 0.6)
    out = log.before_tracking(target, feats, (clock,))
    inside = feats.keypoints_px[:, 0] < target.camera.width - 45
    assert out.withheld is not None and out.withheld[inside].mean() > 0.5
    assert not (out.withheld & out.keep).any() and not out.withheld[~inside].any()
    log.withheld_used(out)
    log.write(tmp_path / "log.npz")
    assert (np.load(tmp_path / "log.npz")["keep"] == out.keep | out.withheld).all()
