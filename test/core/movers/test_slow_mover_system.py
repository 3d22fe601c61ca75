"""System test of the local-mapping segmentation (slow movers) on the simulator's slow_mover.

Renders the first 330 frames of slow_mover (seed 0, 640x480, 30 fps: the box rests for 4 s, then is pushed
at 3 cm/s) and runs the engine with `mapping.segmentation` on (its defaults), no detector. Counting per keyframe window:
the window's map points; positive = the instance mask under the point's keypoint (newest window keyframe
measuring it) is the box's and the box moved > 1 cm between the point's first and last measurement in the
window; flagged = culled as moving (as bench/eval_slow_movers_sim.py counts).
The whole 720-frame run's figures: docs/results.md ("Dynamic scenes").
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import changing_slam_ros.core.slam.local_mapping as local_mapping
from changing_slam_ros.core.movers.keyframe_segmentation import KeyframeSegmentationConfig, window_keyframes
from changing_slam_ros.core.slam.local_mapping import MappingConfig
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.eval.moving_objects import camera_alignment, read_sim_movers
from changing_slam_ros.io.dataset import open_dataset

pytestmark = pytest.mark.slow

FRAMES = 330


@pytest.fixture(scope="module")
def slow_mover(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    out = tmp_path_factory.mktemp("slow_mover")
    simulate(build_scenario("slow_mover", 0), out, RenderOptions(width=640, height=480, frames=FRAMES), 0)
    return out


def test_points_of_the_slowly_pushed_box_are_culled_in_local_mapping(slow_mover: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    truth = read_sim_movers(slow_mover)[0]
    masks = sorted((slow_mover / "masks").glob("*.png"))
    frame_of = {int(s): i for i, s in enumerate(truth.stamps_ns)}
    tally = np.zeros(3, int)  # TP, FP, FN over every window
    real = local_mapping.segment_keyframe_window

    def counted(slam_map, kf_id, cfg):  # type: ignore[no-untyped-def]
        kf_ids = window_keyframes(slam_map, kf_id, cfg.window_keyframes)
        before = {k: (slam_map.keyframes[k].point_ids.copy(), frame_of[int(slam_map.keyframes[k].stamp_ns)]) for k in kf_ids}
        res = real(slam_map, kf_id, cfg)
        if res is None:
            return res
        m = len(res.point_ids)
        on_box = np.zeros(m, bool)
        first = np.full(m, -1)
        last = np.full(m, -1)
        for k in kf_ids:  # oldest first: later keyframes overwrite, the newest measurement decides the mask
            ids, frame = before[k]
            kf = slam_map.keyframes[k]
            rows = np.flatnonzero(np.isin(ids, res.point_ids) & (kf.depths_m > 0) & (kf.depths_m <= cfg.max_depth_m))
            col = np.searchsorted(res.point_ids, ids[rows])
            mask = cv2.imread(str(masks[frame]), cv2.IMREAD_UNCHANGED)
            c, r = np.rint(kf.keypoints_px[rows]).astype(int).T
            on_box[col] = mask[np.clip(r, 0, mask.shape[0] - 1), np.clip(c, 0, mask.shape[1] - 1)] == truth.mask_id
            first[col] = np.where(first[col] < 0, frame, first[col])
            last[col] = frame
        seen = first >= 0
        travel = np.zeros(m)
        travel[seen] = np.linalg.norm(truth.T_world_obj[last[seen], :3, 3] - truth.T_world_obj[first[seen], :3, 3], axis=1)
        positive = on_box & (travel > 0.01)  # the box moved > 1 cm while the point was measured in the window
        flagged = (res.labels > 0) if res.trusted else np.zeros(m, bool)
        tally[:] += [np.sum(flagged & positive), np.sum(flagged & ~positive), np.sum(positive & ~flagged)]
        return res

    monkeypatch.setattr(local_mapping, "segment_keyframe_window", counted)
    seg = KeyframeSegmentationConfig(enabled=True)
    system = SlamSystem(SystemConfig(mapping=MappingConfig(segmentation=seg)))
    source = open_dataset(slow_mover, "sim")
    for rgbd in source:
        system.process(rgbd, None)
    tp, fp, fn = tally.tolist()
    assert tp >= 20 and tp / (tp + fp) >= 0.9, (tp, fp, fn)
    assert source.groundtruth is not None
    _, ate = camera_alignment(source.groundtruth, system.online_trajectory())
    assert system.n_tracked() == FRAMES and ate < 0.005
