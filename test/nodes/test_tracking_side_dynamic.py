"""The real-time graph's tracking runs the same dynamic stage as `changing-slam run`: segmentation included."""

from __future__ import annotations

import pytest

from changing_slam_ros.nodes.slam_backend import load_backend_config
from changing_slam_ros.nodes.split_backend import TrackingSide


@pytest.mark.parametrize("config", ["", "sim", "tum_fr3"])
@pytest.mark.parametrize("provisional", [False, True])
def test_the_graphs_tracking_segments_movers_by_default(config: str, provisional: bool) -> None:
    side = TrackingSide.build(load_backend_config(config), loop=False, provisional=provisional)
    flt = side.system.dynamic_filter
    assert flt is not None
    assert flt.config.segmentation and flt.config.segmentation_method == "edge_test"
    assert flt.config.min_kept_keypoints == 300
    assert not side.system.owns_map  # the replica never forgets points itself (dynamic.forget_moving_points)
