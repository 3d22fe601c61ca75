"""System test of the multi-session target: run `static`, save the map, run `shift` from the saved map.

The test renders both scenarios itself (seed 0, 320x240, 15 fps, their full 101 s: the same world frame and
nearly the same robot loop; at 7.5 fps the `static` run itself drifts to 18 cm ATE, so the frame rate stays at
the bench's), runs the engine with oracle detections, loop closing, the dynamic filter and the object layer on
`static`, saves the map (`io.map_file`), loads it into a fresh system and runs `shift` from it. It asserts that
the second session relocalises within the first 2 s, that its trajectory lies in the saved map's frame (errors
against ground truth under the first session's alignment, not re-aligned, within 1.5x the first session's own
ATE + 2 cm), that the old places of the moved
objects hold only low-belief, inactive objects and that the new places of the monitors and the suitcase hold a
new object (bounds measured on this configuration, with margin; bench/multi_session.py prints the figures).
Several minutes on an idle 2-core machine.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.eval.object_alignment import trajectory_alignment
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicFilter
from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.map.map_point import PointStore
from changing_slam_ros.core.objects.object_layer import ObjectLayer, ObjectLayerConfig, SavedObjectMap
from changing_slam_ros.core.system import SlamSystem, SystemConfig
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.features.vocabulary import Vocabulary
from changing_slam_ros.eval.ate import ate
from changing_slam_ros.eval.multi_session import map_frame_errors_m, moved_places
from changing_slam_ros.eval.object_metrics import load_ground_truth_objects
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
from changing_slam_ros.io.map_file import load_map, save_map

FPS, SECONDS = 15.0, 101.0
# the second session's error in the saved map's frame against the first session's own ATE: measured 3.7 / 3.6 cm
# (morning rendering) and 10.5 / 12.7 cm (rendering and engine at 12:07); a relocalisation that left the saved
# map's frame would add an offset of its own
MAP_FRAME_VS_FIRST_ATE = 1.5
MAP_FRAME_SLACK_M = 0.02
# moved objects whose old place the robot sees again after the move (the cup on the suitcase is too small to be
# expected: `min_projected_area_px`) and whose new place it sees (the chair's new place is only seen at the border)
OLD_PLACES = ("chair", "teddy_bear", "monitor", "suitcase", "monitor_2")
NEW_PLACES = ("monitor", "suitcase", "monitor_2")


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.errors import SimError
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    root = tmp_path_factory.mktemp("multi_session")
    for name in ("static", "shift"):
        try:
            simulate(build_scenario(name, 0), root / name,
                     RenderOptions(width=320, height=240, frames=int(SECONDS * FPS), fps=FPS), 0)
        except SimError as err:
            pytest.skip(f"no offscreen rendering here: {err}")
    return root


def _system() -> SlamSystem:
    closing = SlamMapLoopClosing(LoopCloser(LoopConfig(), Vocabulary.load()))
    return SlamSystem(loop_closer=closing, keyframe_index=closing, dynamic_filter=DynamicFilter(),
                      object_layer=ObjectLayer())


def _run(system: SlamSystem, folder: Path) -> None:
    oracle = read_detections_file(find_detections_file(folder))
    for rgbd in open_dataset(folder, "sim"):
        system.process(rgbd, oracle.for_stamp(rgbd.stamp_ns))


def test_loaded_objects_start_with_decayed_beliefs_and_their_points_follow() -> None:
    """`ObjectLayer.load_objects`: beliefs pulled halfway to 0.5 (default `session_belief_decay`), objects below the
    threshold start inactive with their map points; a point last associated with another object is left alone;
    every object counts as long unseen in the new session."""
    points = PointStore()
    points.add(np.zeros((4, 3)), np.zeros((4, 32), np.uint8), 0, np.arange(4), np.zeros(3), np.zeros(4, np.int64),
               np.ones(8))
    points.object_id[:4] = [1, 1, 2, 1]  # point 2 was last associated with object 2
    strong = MapObject(1, 56, (0, 0, 9, 9), (0, 0, 9, 9), 0, 30, belief=0.9, active=True,
                       point_ids=np.array([0, 1, 2, -5]), points_w=np.zeros((4, 3)))
    weak = MapObject(2, 62, (0, 0, 9, 9), (0, 0, 9, 9), 0, 30, belief=0.7, active=True,
                     point_ids=np.array([2, 3]), points_w=np.ones((2, 3)))
    saved = SavedObjectMap([strong, weak], np.array([-5]), np.array([0]), np.array([[0.0, 0.0, 1.0]]), -6)
    layer = ObjectLayer()
    layer.load_objects(0, saved, first_keyframe_id=40, points=points)
    a, b = layer.objects(0)
    assert a.belief == pytest.approx(0.7) and a.active
    assert b.belief == pytest.approx(0.6) and b.active  # exactly at the 0.6 threshold
    layer2 = ObjectLayer(dataclasses.replace(ObjectLayerConfig(), session_belief_decay=0.8))
    strong.belief, weak.belief = 0.9, 0.7
    layer2.load_objects(0, saved, first_keyframe_id=40, points=points)
    a, b = layer2.objects(0)
    assert a.belief == pytest.approx(0.58) and not a.active and b.belief == pytest.approx(0.54) and not b.active
    assert points.active[:4].tolist() == [False, False, False, True]  # point 2 followed object 2, point 3 is not b's
    assert a.last_seen_keyframe < 40 - layer2.config.association.n_keyframes_unseen


@pytest.mark.slow
def test_shift_from_the_static_map(scenes: Path, tmp_path: Path) -> None:
    first = _system()
    _run(first, scenes / "static")
    gt1 = open_dataset(scenes / "static", "sim").groundtruth
    assert gt1 is not None
    T_gt_map = trajectory_alignment(gt1, first.final_trajectory())
    assert T_gt_map is not None
    first_ate_m = float(np.sqrt(np.mean(ate(gt1, first.final_trajectory()).errors_m ** 2)))
    path = tmp_path / "map.npz"
    save_map(path, first.atlas, first.object_layer, first.tracker.next_kf_id)
    n_saved = first.atlas.n_keyframes

    loaded = load_map(path)
    second = _system()
    second.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects)
    _run(second, scenes / "shift")

    # 1. relocalised in the saved map within the first 2 s; no new map; saved keyframes kept
    i = second.tracker.loaded_map_relocalised_index
    assert 0 <= i and (second.records[i].stamp_ns - second.records[0].stamp_ns) * 1e-9 <= 2.0
    assert len(second.atlas.maps) == 1 and second.atlas.n_keyframes > n_saved
    assert sum(r.state == TrackingState.OK for r in second.records) >= 0.98 * len(second.records)

    # 2. the trajectory is in the saved map's frame: errors under the first session's alignment
    gt2 = open_dataset(scenes / "shift", "sim").groundtruth
    assert gt2 is not None
    errors = map_frame_errors_m(gt2, second.final_trajectory(), T_gt_map)
    assert len(errors) >= 0.98 * len(second.records)
    rmse_m = float(np.sqrt(np.mean(errors**2)))
    assert rmse_m < MAP_FRAME_VS_FIRST_ATE * first_ate_m + MAP_FRAME_SLACK_M, (rmse_m, first_ate_m)

    # 3. moved objects: old places hold only low-belief, inactive objects; new places hold a new object (belief
    #    0.5: each new place is seen in one pass only, and beliefs move on long-term re-observations only)
    assert second.object_layer is not None
    places = {(p.name, p.place): p for p in moved_places(second.object_layer.objects(0), T_gt_map,
                                                           load_ground_truth_objects(scenes / "shift" / "objects.json"))}
    threshold = second.object_layer.config.association.belief_threshold
    for name in OLD_PLACES:
        old = places[(name, "old")]
        assert old.n_objects >= 1 and old.belief is not None and old.belief < threshold and not old.active, old
    for name in NEW_PLACES:
        new = places[(name, "new")]
        assert new.n_objects >= 1 and new.belief is not None and new.belief >= 0.5, new


def test_no_relocalisation_in_the_loaded_map_starts_a_new_map_after_the_grace_period() -> None:
    """A saved map the frames cannot relocalise in (its keyframes' descriptors scrambled): tracking stays LOST for
    `loaded_map_grace_s`, then starts a new map of the Atlas; the saved map is kept."""
    source = open_dataset(require(FR1_XYZ_10), "tum_fr1")
    frames = list(source)
    first = SlamSystem()
    for rgbd in frames:
        first.process(rgbd)
    rng = np.random.default_rng(0)
    for kf in first.atlas.maps[0].keyframes.values():
        kf.descriptors[:] = rng.integers(0, 256, kf.descriptors.shape, dtype=np.uint8)
    grace_s = 0.1
    second = SlamSystem(SystemConfig(tracking=TrackingConfig(loaded_map_grace_s=grace_s)))
    second.start_from_map(first.atlas, first.tracker.next_kf_id)
    states = [second.process(rgbd).state for rgbd in frames]
    t0 = frames[0].stamp_ns
    lost = [(f.stamp_ns - t0) * 1e-9 < grace_s for f in frames]
    assert any(lost) and not all(lost)
    assert all(s == TrackingState.LOST for s, early in zip(states, lost) if early)
    assert all(s == TrackingState.OK for s, early in zip(states, lost) if not early)
    assert second.tracker.loaded_map_relocalised_index == -1
    assert len(second.atlas.maps) == 2 and second.atlas.current.id == 1 and len(second.atlas.maps[0].keyframes) >= 1
