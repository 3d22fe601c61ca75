"""Starting a map: the view's texture is judged on the whole image, the dynamic stage's filtered keypoints aside."""

from __future__ import annotations

import numpy as np
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.io.dataset import open_dataset


def test_a_map_starts_beside_a_filtered_mover_when_the_view_has_texture() -> None:
    target = list(open_dataset(require(FR1_XYZ_10), "tum_fr1"))[0]
    cfg = TrackingConfig()
    for kept, in_image, starts in ((200, 400, True), (120, 400, False), (200, -1, False), (200, 250, False)):
        system = SlamSystem(SystemConfig(tracking=cfg))
        feats = system._extractor_for(target.camera).extract(target.rgb, target.depth_m)
        with_depth = np.flatnonzero(feats.depths_m > 0)
        keep = np.zeros(len(feats), bool)
        keep[with_depth[:kept]] = True
        frame = Frame(target.stamp_ns, 0, target.camera, feats.subset(keep), n_depth_extracted=in_image)
        res = system.tracker.track(frame)
        assert (res.state == TrackingState.OK) == starts, (kept, in_image)
        assert (res.new_keyframe is not None) == starts
