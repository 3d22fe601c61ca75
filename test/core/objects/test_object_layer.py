"""ObjectLayer on constructed maps: candidates from map points and box depth, point flags, anchors, the switch."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.point_flags import keep_enough_active
from changing_slam_ros.core.objects.object_layer import (
    ObjectLayer, ObjectLayerConfig, box_depth_band, box_depth_samples, object_layer_config,
)
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.errors import ConfigError

CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
CHAIR = 56
BOX = (100.0, 60.0, 180.0, 180.0)


def _depth(object_m: float = 2.0, background_m: float = 4.0) -> np.ndarray:
    """(240, 320) depth: background, with the box region at object_m except a 10-pixel column showing the wall."""
    d = np.full((240, 320), background_m, np.float32)
    d[60:180, 100:180] = object_m
    d[60:180, 170:180] = background_m
    return d


def _state(motion: ObjectMotion = ObjectMotion.STATIC, box: tuple[float, float, float, float] = BOX) -> ObjectState:
    nan3 = np.full(3, np.nan)
    return ObjectState(7, CHAIR, box, nan3, nan3, 0.0, motion, 3, False)


def _map_with_keyframe(kf_id: int, T_world_cam: np.ndarray, n_obj: int = 12, n_bg: int = 320) -> tuple[SlamMap, Keyframe]:
    """A map with one keyframe: n_obj keypoints on the object (short-term id 7) with map points at 2 m, n_bg on
    the background (at least the layer's `min_active_points`, as in a keyframe tracking can go on from)."""
    rng = np.random.default_rng(kf_id)
    px_obj = np.c_[rng.uniform(105, 165, n_obj), rng.uniform(65, 175, n_obj)]
    px_bg = np.c_[rng.uniform(0, 90, n_bg), rng.uniform(0, 240, n_bg)]
    px = np.vstack([px_obj, px_bg])
    depth = np.r_[np.full(n_obj, 2.0), np.full(n_bg, 4.0)]
    n = len(px)
    kf = Keyframe(kf_id, kf_id * 10**9, T_world_cam, CAM, px.astype(np.float32), np.zeros(n, np.int8),
                  np.zeros((n, 32), np.uint8), depth.astype(np.float32), np.full(n, -1, np.int64),
                  object_ids=np.r_[np.full(n_obj, 7), np.full(n_bg, -1)].astype(np.int64))
    m = SlamMap(0)
    pts_c = CAM.backproject(px, depth)
    pts_w = pts_c @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    ids = m.points.add(pts_w, kf.descriptors, kf_id, np.arange(n), T_world_cam[:3, 3], np.zeros(n, np.int64),
                       np.ones(8))
    kf.point_ids[:] = ids
    m.add_keyframe(kf)
    return m, kf


def test_box_depth_samples_keep_the_object_not_the_wall_behind() -> None:
    pts = box_depth_samples(_depth(), BOX, CAM, 100, 0.35)
    assert 50 <= len(pts) <= 110
    np.testing.assert_allclose(pts[:, 2], 2.0)
    u = CAM.fx * pts[:, 0] / pts[:, 2] + CAM.cx
    assert u.min() >= 100 and u.max() < 170  # the wall column (170-180) is left out
    assert len(box_depth_samples(np.zeros((240, 320), np.float32), BOX, CAM, 100, 0.35)) == 0


def test_new_object_is_created_inactive_and_its_map_points_leave_tracking() -> None:
    m, kf = _map_with_keyframe(0, np.eye(4))
    layer = ObjectLayer()
    out = layer.after_keyframe(kf, m, _depth(), [_state()])
    assert out.association is not None and len(out.association.new_object_ids) == 1
    (obj,) = layer.objects(0)
    assert obj.class_id == CHAIR and obj.belief == 0.5 and not obj.active
    # 12 map points plus the depth samples; centroid inside the object's slab at 2 m
    assert (obj.point_ids >= 0).sum() == 12 and (obj.point_ids < -1).sum() > 50
    assert abs(obj.centroid_w[2] - 2.0) < 1e-6
    usable = m.points.usable()
    assert not usable[:12].any() and usable[12:].all()  # object points inactive, background untouched
    assert (m.points.object_id[:12] == obj.id).all() and (m.points.class_id[:12] == CHAIR).all()
    assert out.n_deactivated == 12 and out.active_flags_changed


def test_a_keyframe_new_objects_would_leave_without_a_map_keeps_their_points_active() -> None:
    # 12 chair points and 8 of the background: the chair would take the keyframe below `min_active_points`
    m, kf = _map_with_keyframe(0, np.eye(4), n_bg=8)
    layer = ObjectLayer()
    out = layer.after_keyframe(kf, m, _depth(), [_state()])
    (obj,) = layer.objects(0)
    assert obj.belief == 0.5 and not obj.active  # the object itself is still undecided
    assert m.points.usable().all() and out.n_activated == 12
    # the paper's rule (no floor): the chair's points leave tracking
    m, kf = _map_with_keyframe(0, np.eye(4), n_bg=8)
    paper = ObjectLayer(ObjectLayerConfig(min_active_points=0))
    paper.after_keyframe(kf, m, _depth(), [_state()])
    assert not m.points.usable()[:12].any() and m.points.usable()[12:].all()
    # an object with evidence that it moved (belief below 0.5) stays out, floor or not
    m, kf = _map_with_keyframe(0, np.eye(4), n_bg=8)
    layer = ObjectLayer(ObjectLayerConfig(min_active_points=0))
    layer.after_keyframe(kf, m, _depth(), [_state()])
    (obj,) = layer.objects(0)
    obj.belief = 0.3
    assert keep_enough_active(layer.association(0).objects, kf, m.points, 300) == 0
    assert not m.points.usable()[:12].any()
    obj.belief = 0.5
    assert keep_enough_active(layer.association(0).objects, kf, m.points, 300) == 12
    assert m.points.usable().all()
    with pytest.raises(ConfigError, match="objects.min_active_points"):
        object_layer_config({"min_active_points": -1})


def test_dynamic_objects_are_ignored_and_switch_off_keeps_every_point_active() -> None:
    m, kf = _map_with_keyframe(0, np.eye(4))
    layer = ObjectLayer()
    layer.after_keyframe(kf, m, _depth(), [_state(ObjectMotion.DYNAMIC)])
    assert layer.objects() == [] and m.points.usable().all()
    off = ObjectLayer(ObjectLayerConfig(enabled=False))
    out = off.after_keyframe(kf, m, _depth(), [_state()])
    assert out.association is None and off.objects() == [] and m.points.usable().all()


def test_object_points_follow_their_keyframe_after_the_map_culled_them() -> None:
    m, kf = _map_with_keyframe(0, np.eye(4))
    layer = ObjectLayer(ObjectLayerConfig(depth_samples=0))
    layer.after_keyframe(kf, m, None, [_state()])
    (obj,) = layer.objects(0)
    before = obj.centroid_w.copy()
    for pid in range(12):  # recent-point culling removes the (inactive) object points
        m.erase_point(pid)
    shift = make_pose(np.eye(3), np.array([0.3, 0.0, 0.0]))
    kf.T_world_cam = shift @ kf.T_world_cam  # a loop correction moves the keyframe
    # a later keyframe without the object: refresh only
    kf2 = Keyframe(1, 10**9, np.eye(4), CAM, np.zeros((0, 2), np.float32), np.zeros(0, np.int8),
                   np.zeros((0, 32), np.uint8), np.zeros(0, np.float32), np.zeros(0, np.int64))
    m.add_keyframe(kf2)
    layer.after_keyframe(kf2, m, None, [])
    assert obj.n_points == 12  # kept, from the anchors
    np.testing.assert_allclose(obj.centroid_w, before + [0.3, 0.0, 0.0], atol=1e-9)


def test_returning_object_is_merged_and_missing_object_loses_belief() -> None:
    cfg = ObjectLayerConfig(association=ObjectMapConfig(n_keyframes_unseen=1))
    layer = ObjectLayer(cfg)
    m, kf = _map_with_keyframe(0, np.eye(4))
    layer.after_keyframe(kf, m, _depth(), [_state()])
    (obj,) = layer.objects(0)
    # keyframe 5, same pose, object seen again after more than N keyframes: merged, belief up
    kf5 = Keyframe(5, 5 * 10**9, np.eye(4), CAM, kf.keypoints_px, kf.octaves, kf.descriptors, kf.depths_m,
                   kf.point_ids.copy(), object_ids=kf.object_ids.copy())
    m.add_keyframe(kf5)
    layer.after_keyframe(kf5, m, _depth(), [_state()])
    assert len(layer.objects(0)) == 1 and obj.belief > 0.5
    # keyframe 9, same pose, the object is gone (depth shows the wall) and nothing is detected: belief down
    belief = obj.belief
    kf9 = Keyframe(9, 9 * 10**9, np.eye(4), CAM, np.zeros((0, 2), np.float32), np.zeros(0, np.int8),
                   np.zeros((0, 32), np.uint8), np.zeros(0, np.float32), np.zeros(0, np.int64))
    m.add_keyframe(kf9)
    layer.after_keyframe(kf9, m, np.full((240, 320), 4.0, np.float32), [])
    assert obj.belief < belief


def test_config_section() -> None:
    cfg = object_layer_config({"enabled": False, "depth_samples": 50, "belief_threshold": 0.7})
    assert not cfg.enabled and cfg.depth_samples == 50 and cfg.association.belief_threshold == 0.7
    assert object_layer_config(None) == ObjectLayerConfig()
    with pytest.raises(ConfigError, match="objects.enabled"):
        object_layer_config({"enabled": "yes"})
    with pytest.raises(ConfigError, match="bogus"):
        object_layer_config({"bogus": 1})
    with pytest.raises(ConfigError, match="depth_band_m"):
        object_layer_config({"depth_band_m": 0.0})


def test_small_box_uses_a_narrow_depth_band() -> None:
    """A 12-pixel cup at 2.5 m (11 cm) in front of a wall 0.2 m behind it: the wall is left out."""
    d = np.full((240, 320), 2.7, np.float32)
    d[100:112, 150:160] = 2.5  # the cup covers most of its box; the box's right part shows the wall
    pts = box_depth_samples(d, (150.0, 100.0, 164.0, 112.0), CAM, 100, 0.35)
    assert len(pts) == 30 and np.allclose(pts[:, 2], 2.5)  # a 7 x 6 grid, 5 x 6 on the cup


def _slanted_chair_depth() -> np.ndarray:
    """(240, 320) depth of a chair seen from the side in BOX (80 x 120 px): its backrest at 2.0 m fills the right
    part (55 x 80 px), its seat front and near leg at 1.55 m the lower left (25 x 50 px), and the wall at 2.6 m is
    seen through the frame everywhere else in the box (below the seat, above the near part): the median depth is
    the backrest's, half a metre behind the chair's near part."""
    d = np.full((240, 320), 2.6, np.float32)
    d[60:140, 125:180] = 2.0
    d[130:180, 100:125] = 1.55
    return d


def test_a_slanted_chair_keeps_its_near_part_with_the_near_quantile() -> None:
    """The centred band (median 2.0 m, half 0.3 m) cuts the near part off; with near_quantile 0.05 the band
    reaches the box's nearest depths (13 % of its pixels at 1.55 m) and the wall past the chair stays out."""
    centred = box_depth_samples(_slanted_chair_depth(), BOX, CAM, 100, 0.35)
    near = box_depth_samples(_slanted_chair_depth(), BOX, CAM, 100, 0.35, near_quantile=0.05)
    np.testing.assert_allclose(centred[:, 2], 2.0)  # backrest only
    is_near = np.abs(near[:, 2] - 1.55) < 1e-5
    np.testing.assert_allclose(near[~is_near, 2], 2.0)  # the rest is backrest: no wall
    n_near = int(is_near.sum())
    assert 8 <= n_near <= 16 and len(near) == len(centred) + n_near
    band = box_depth_band(_slanted_chair_depth(), BOX, CAM, 0.35, near_quantile=0.05)
    assert band is not None and band.median_m == pytest.approx(2.0) and band.half_m == pytest.approx(0.5 * 80 * 2.0 / 262.5)
    assert band.near_m == pytest.approx(1.55, abs=1e-5)
    np.testing.assert_array_equal(band.contains(np.array([1.5, 1.56, 2.0, 2.3, 2.31, 2.6])),
                                  [False, True, True, True, False, False])


def test_the_near_end_moves_at_most_one_box_width_in_front_of_the_median() -> None:
    """A cup (12 x 12 px at 2.5 m: 11 cm, band half-width 5.7 cm) whose box bottom shows a table's front edge
    0.6 m nearer (2 rows, 17 % of the box): the near end stops at median - 2 half-widths, the edge stays out."""
    d = np.full((240, 320), 3.0, np.float32)
    d[100:110, 150:162] = 2.5
    d[110:112, 150:162] = 1.9
    box = (150.0, 100.0, 162.0, 112.0)
    band = box_depth_band(d, box, CAM, 0.35, near_quantile=0.05)
    assert band is not None and band.median_m == pytest.approx(2.5)
    assert band.near_m == pytest.approx(2.5 - 2 * 0.5 * 12 * 2.5 / 262.5)
    pts = box_depth_samples(d, box, CAM, 100, 0.35, near_quantile=0.05)
    np.testing.assert_allclose(pts[:, 2], 2.5)
    assert len(pts) == 30  # a 6 x 6 grid: 5 rows on the cup, 1 on the edge


def test_the_near_quantile_changes_nothing_where_the_object_fills_its_box() -> None:
    """The object at 2 m covers 7/8 of its box, so its 5 % depth is its median: the same samples as centred."""
    np.testing.assert_array_equal(box_depth_samples(_depth(), BOX, CAM, 100, 0.35, near_quantile=0.05),
                                  box_depth_samples(_depth(), BOX, CAM, 100, 0.35))
    assert ObjectLayerConfig().depth_band_near_quantile == 0.05
    assert object_layer_config({"depth_band_near_quantile": 0.0}).depth_band_near_quantile == 0.0
    with pytest.raises(ConfigError, match="objects.depth_band_near_quantile"):
        object_layer_config({"depth_band_near_quantile": 0.5})


def test_map_points_of_the_wall_seen_past_the_object_stay_out_of_it() -> None:
    """Keypoints inside the box on the wall 2 m behind the object (the monitor in front of the wall) are not the
    object's: with `band_map_points` they are left out, without it they drag the centroid back by 2 m * 4/16."""
    m, kf = _map_with_keyframe(0, np.eye(4), n_bg=8)  # too few to fit the wall's plane
    # move 4 of the 12 object keypoints onto the wall behind (4 m), still inside the box
    pids = kf.point_ids[:4]
    px = kf.keypoints_px[:4].astype(float)
    m.points.positions[pids] = CAM.backproject(px, np.full(4, 4.0))
    banded = ObjectLayer()
    banded.after_keyframe(kf, m, _depth(), [_state()])
    (obj,) = banded.objects(0)
    assert set(obj.point_ids[obj.point_ids >= 0].tolist()) == set(kf.point_ids[4:12].tolist())
    assert abs(obj.centroid_w[2] - 2.0) < 1e-6 and obj.box_size_m[2] < 0.01
    m2, kf2 = _map_with_keyframe(0, np.eye(4), n_bg=8)
    m2.points.positions[kf2.point_ids[:4]] = CAM.backproject(px, np.full(4, 4.0))
    loose = ObjectLayer(ObjectLayerConfig(band_map_points=False))
    loose.after_keyframe(kf2, m2, _depth(), [_state()])
    (obj2,) = loose.objects(0)
    assert (obj2.point_ids >= 0).sum() == 12 and obj2.centroid_w[2] > 2.05 and obj2.box_size_m[2] > 1.5
    assert object_layer_config({"band_map_points": False}).band_map_points is False


def test_a_cut_box_gives_depth_samples_to_an_object_known_only_from_cut_views() -> None:
    """`cut_only_views_join` (with `truncated_views`): an object whose keypoints have no map point yet (the EKF
    has not called it static) and whose box is cut by the image border is made from the box's depth samples;
    once the object has been seen whole, a cut view's samples are neither in its points nor anchored."""
    cut_box = (0.0, 60.0, 80.0, 180.0)
    depth = np.full((240, 320), 4.0, np.float32)
    depth[60:180, 0:80] = 2.0
    on = ObjectLayer(object_layer_config({"truncated_views": True}))
    off = ObjectLayer(object_layer_config({"truncated_views": True, "cut_only_views_join": False}))
    for layer in (on, off):
        m, kf = _map_with_keyframe(0, np.eye(4), n_obj=0)
        layer.after_keyframe(kf, m, depth, [_state(ObjectMotion.UNKNOWN, cut_box)])
    assert off.objects() == []  # no map point, and no samples from a cut box
    (obj,) = on.objects(0)
    assert obj.n_observations == 0 and (obj.point_ids < -1).sum() > 30 and abs(obj.centroid_w[2] - 2.0) < 1e-6
    kf1 = _map_with_keyframe(1, np.eye(4), n_obj=0)[1]  # the same place seen whole (the camera turned a little)
    m.add_keyframe(kf1)
    whole = np.full((240, 320), 4.0, np.float32)
    whole[60:180, 4:84] = 2.0
    on.after_keyframe(kf1, m, whole, [_state(ObjectMotion.UNKNOWN, (4.0, 60.0, 84.0, 180.0))])
    assert obj.n_observations == 1
    n_points, n_anchors = obj.n_points, len(on.saved_objects(0).anchor_ids)
    kf2 = _map_with_keyframe(2, np.eye(4), n_obj=0)[1]
    m.add_keyframe(kf2)
    out = on.after_keyframe(kf2, m, depth, [_state(ObjectMotion.UNKNOWN, cut_box)])
    assert out.association is not None and out.association.assignments == (obj.id,)
    assert obj.n_points == n_points and len(on.saved_objects(0).anchor_ids) == n_anchors


def test_an_object_seen_only_cut_by_the_image_bottom_is_mapped_by_default() -> None:
    """A floor-standing object near a robot-height camera has its lower part below the image in every view: its
    box touches the image bottom each time and its EKF gets no measurement (verdict UNKNOWN, no map point). With
    the default configuration it is mapped from the boxes' depth samples and is in the semantic map; with cut
    views skipped it is not mapped at all."""
    cut_box = (120.0, 150.0, 200.0, 240.0)
    depth = np.full((240, 320), 4.0, np.float32)
    depth[150:240, 120:200] = 1.5
    default = ObjectLayer()
    skipped = ObjectLayer(object_layer_config({"truncated_views": False}))
    for layer in (default, skipped):
        m, kf = _map_with_keyframe(0, np.eye(4), n_obj=0)
        layer.after_keyframe(kf, m, depth, [_state(ObjectMotion.UNKNOWN, cut_box)])
        kf1 = _map_with_keyframe(1, np.eye(4), n_obj=0)[1]
        m.add_keyframe(kf1)
        layer.after_keyframe(kf1, m, depth, [_state(ObjectMotion.UNKNOWN, cut_box)])
    assert skipped.objects() == [] and skipped.semantic_map(0).objects == ()
    (obj,) = default.objects(0)
    assert obj.n_observations == 0 and abs(obj.centroid_w[2] - 1.5) < 1e-6
    assert [o.id for o in default.semantic_map(0).objects] == [obj.id]


def test_a_sliver_cut_by_the_border_gives_no_depth_samples() -> None:
    """`cut_min_side_m`: a cut box 3 px wide (2.3 cm at 2 m) holds mostly what lies behind the object; it makes
    no object, while the same box 20 px wide (15 cm) does."""
    depth = np.full((240, 320), 4.0, np.float32)
    depth[60:180, 0:20] = 2.0
    for width, expected in ((3.0, 0), (20.0, 1)):
        layer = ObjectLayer(object_layer_config({"truncated_views": True}))
        m, kf = _map_with_keyframe(0, np.eye(4), n_obj=0)
        layer.after_keyframe(kf, m, depth, [_state(ObjectMotion.UNKNOWN, (0.0, 60.0, width, 180.0))])
        assert len(layer.objects()) == expected
    with pytest.raises(ConfigError, match="cut_min_side_m"):
        object_layer_config({"cut_min_side_m": -0.1})
