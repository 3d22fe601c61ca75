"""System test of the dynamic-scene half: the SLAM engine with the dynamic filter on a simulated walking sequence.

The test renders walking_xyz itself (seed 0, 320x240, 15 fps, the first 8 s: two people cross the view
and fill up to a fifth of the image) and runs the engine with the simulator's oracle detections and
without dynamic handling. Measured with the frontend of d150c23 (robuster local BA / pose optimiser):
dynamic 0.72 cm ATE with every frame tracked, 67 % of keypoints kept and no pose inlier on a person; plain
1.29 cm with 1.5 % of its pose inliers on the people. (Before d150c23 plain gave 19.5 cm here: on this
short sequence the frontend's outlier rejection now copes on its own, so the ATE gap is only 1.8x; the
10 s, 640x480 figures are in docs/results.md.) Bounds leave about 2x margin where possible.
The figures above are of the flat photo people; with the articulated people (ca0476d) the test passes
(re-run at 1c56f34) but the figures were not re-measured. `test_dynamic_system_ssd.py` is the same check
with the shipped detector instead of the oracle.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.eval.ate import ate
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def walking(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    out = tmp_path_factory.mktemp("walking_xyz")
    simulate(build_scenario("walking_xyz", 0), out, RenderOptions(width=320, height=240, frames=120, fps=15.0), 0)
    return out


def _run(folder: Path, flt: DynamicFilter | None) -> tuple[SlamSystem, list[TrackingState], float, float]:
    """States per frame, ATE (m) and the fraction of the used keypoints that lie on a moving person."""
    source = open_dataset(folder, "sim")
    oracle = read_detections_file(find_detections_file(folder))
    doc = json.loads((folder / "objects.json").read_text())
    moving_ids = np.array([False] + [bool(o["moving"]) for o in doc["objects"]])
    masks = sorted((folder / "masks").glob("*.png"))
    system = SlamSystem(dynamic_filter=flt)
    states, used, on_movers = [], 0, 0
    for k, rgbd in enumerate(source):
        states.append(system.process(rgbd, oracle.for_stamp(rgbd.stamp_ns)).state)
        frame = system.tracker.last_frame
        assert frame is not None
        mask = cv2.imread(str(masks[k]), cv2.IMREAD_UNCHANGED)
        px = np.rint(frame.features.raw_px).astype(int)
        ids = mask[np.clip(px[:, 1], 0, mask.shape[0] - 1), np.clip(px[:, 0], 0, mask.shape[1] - 1)]
        tracked = frame.tracked_mask()  # keypoints with a map point that survived the pose optimisation
        used += int(tracked.sum())
        on_movers += int((tracked & moving_ids[ids]).sum())
    assert source.groundtruth is not None
    rmse = ate(source.groundtruth, system.final_trajectory()).stats.rmse
    return system, states, rmse, on_movers / max(used, 1)


def test_dynamic_filter_tracks_walking_xyz_within_1_5_cm_and_plain_is_worse_and_tracks_on_people(walking: Path) -> None:
    flt = DynamicFilter(DynamicConfig())
    system, states, dyn_ate, dyn_leak = _run(walking, flt)
    assert len(states) == 120 and all(s == TrackingState.OK for s in states)
    assert len(system.atlas.maps) == 1
    assert dyn_ate <= 0.015
    assert dyn_leak <= 0.01  # pose inliers on the walking people
    assert 0.5 <= flt.kept_fraction() <= 0.9
    # Keyframes remember which class each of their (kept) keypoints had.
    kfs = list(system.atlas.current.keyframes.values())
    assert all(len(kf.kp_classes) == len(kf) for kf in kfs)

    _, _, plain_ate, plain_leak = _run(walking, None)
    assert plain_ate >= 1.3 * dyn_ate
    assert plain_leak >= 0.005  # the plain engine tracks on the people
