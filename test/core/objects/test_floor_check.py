"""The floor check: a detection whose points are mostly floor is no object; a suitcase standing on it is."""

from __future__ import annotations

import numpy as np

from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.map.floor_plane import FloorEstimate
from changing_slam_ros.core.map.grid_scan import GridScan
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.objects.floor_check import floor_as_plane, floor_fraction, is_floor_patch, scans_floor
from changing_slam_ros.core.objects.long_term_association import LongTermAssociation, ObjectCandidate
from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.object_layer import ObjectLayer, ObjectLayerConfig
from object_maps import static_keyframe

CAM = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
PLANT, SUITCASE, BOOK = 58, 28, 73
FLOOR_Y_M, WALL_Z_M = 1.0, 4.0  # camera frame = map frame: x right, y down, z forward; the floor 1 m below
FLOOR = FloorEstimate(np.array([0.0, -1.0, 0.0]), -FLOOR_Y_M, 1000)  # {x : up . x = height}
FLOOR_ROWS = int(np.ceil(CAM.cy + CAM.fy * FLOOR_Y_M / WALL_Z_M))  # the rows below the wall's foot
PATCH_BOX = (60.0, 200.0, 140.0, 236.0)  # a box in the floor's rows: nothing stands there
SUITCASE_BOX = (180.0, 100.0, 240.0, 190.0)  # reaches the floor at 2 m: the suitcase stands on it


def _chair(rng: np.random.Generator) -> np.ndarray:
    """A chair's points 2.5 m ahead on the floor: seat, back, four legs, and a fifth of floor samples between."""
    seat = np.c_[rng.uniform(-0.25, 0.25, 60), np.full(60, FLOOR_Y_M - 0.45), rng.uniform(2.25, 2.75, 60)]
    back = np.c_[rng.uniform(-0.25, 0.25, 60), rng.uniform(FLOOR_Y_M - 0.9, FLOOR_Y_M - 0.45, 60), np.full(60, 2.75)]
    legs = np.c_[np.repeat([-0.23, 0.23, -0.23, 0.23], 10), np.tile(np.linspace(FLOOR_Y_M - 0.45, FLOOR_Y_M - 0.05, 10), 4),
                 np.repeat([2.27, 2.27, 2.73, 2.73], 10)]
    floor = np.c_[rng.uniform(-0.3, 0.3, 40), np.full(40, FLOOR_Y_M), rng.uniform(2.2, 2.8, 40)]
    return np.vstack([seat, back, legs, floor])


def test_mostly_floor_is_a_floor_patch_and_a_chair_is_not() -> None:
    rng = np.random.default_rng(0)
    cfg = ObjectMapConfig()
    chair = _chair(rng)
    assert 0.15 < floor_fraction(chair, FLOOR, cfg.floor_patch_dist_m) < 0.25
    assert not is_floor_patch(PLANT, chair, FLOOR, cfg)
    patch = np.vstack([np.c_[rng.uniform(-0.4, 0.4, 70), FLOOR_Y_M + rng.normal(0, 0.01, 70), rng.uniform(2, 3, 70)],
                       np.c_[rng.uniform(-0.4, 0.4, 30), rng.uniform(0.3, 0.9, 30), rng.uniform(2, 3, 30)]])
    assert is_floor_patch(PLANT, patch, FLOOR, cfg)
    assert not is_floor_patch(BOOK, patch, FLOOR, cfg)  # a book may lie flat on the floor
    assert not is_floor_patch(PLANT, patch, None, cfg)  # no floor known: no verdict
    assert not is_floor_patch(PLANT, patch, FLOOR, ObjectMapConfig(floor_patch_min_fraction=0.0))  # off


def _room(kf_id: int) -> tuple[SlamMap, Keyframe, np.ndarray]:
    """One keyframe at the origin facing a wall 4 m away above a floor 1 m below the camera, with the wall's
    static map points, a depth image (the suitcase's box 2 m away down to the floor) and the keyframe's depth
    scan of wall and floor (what the occupancy grid keeps)."""
    rng = np.random.default_rng(kf_id)
    wall = np.c_[rng.uniform(-2.0, 2.0, 400), rng.uniform(-1.0, 0.95, 400), np.full(400, WALL_Z_M)]
    m, kf = static_keyframe(kf_id, wall, CAM)
    depth = np.full((240, 320), WALL_Z_M, np.float32)
    depth[FLOOR_ROWS:, :] = FLOOR_Y_M * CAM.fy / (np.arange(FLOOR_ROWS, 240)[:, None] - CAM.cy)
    x0, y0, x1, y1 = (int(v) for v in SUITCASE_BOX)
    depth[y0:y1, x0:x1] = 2.0
    vv, uu = (a.ravel() for a in np.mgrid[2:240:8, 2:320:8])
    d = depth[vv, uu].astype(np.float64)
    scan = np.c_[(uu - CAM.cx) * d / CAM.fx, (vv - CAM.cy) * d / CAM.fy, d]
    kf.grid_scan = GridScan(scan, np.zeros(len(scan), bool), np.full(len(scan), -1, np.int64))
    m.add_keyframe(kf)
    return m, kf, depth


def test_the_floor_is_found_in_the_keyframes_depth_scans() -> None:
    m, _, _ = _room(0)
    floor = scans_floor(m.keyframes.values())
    assert floor is not None and floor.n_support > 100
    assert np.degrees(np.arccos(floor.up @ np.array([0.0, -1.0, 0.0]))) < 1.0
    assert abs(floor.height + FLOOR_Y_M) < 0.01


def test_the_object_layer_drops_a_detection_on_the_floor_and_keeps_the_suitcase_standing_on_it() -> None:
    layer = ObjectLayer(ObjectLayerConfig(association=ObjectMapConfig(structure_refit_keyframes=1)))
    nan3 = np.full(3, np.nan)
    states = [ObjectState(1, PLANT, PATCH_BOX, nan3, nan3, 0.0, ObjectMotion.STATIC, 3, False),
              ObjectState(2, SUITCASE, SUITCASE_BOX, nan3, nan3, 0.0, ObjectMotion.STATIC, 3, False)]
    m, kf, depth = _room(0)
    first = layer.after_keyframe(kf, m, depth, states)
    # the floor is only known after this keyframe's fit: the patch was mapped, then dropped
    assert len(first.association.new_object_ids) == 2
    assert sorted(o.class_id for o in layer.objects(m.id)) == [SUITCASE]
    kf2 = Keyframe(1, 10**9, kf.T_world_cam, CAM, kf.keypoints_px, kf.octaves, kf.descriptors, kf.depths_m,
                   kf.point_ids.copy())
    kf2.grid_scan = kf.grid_scan
    m.add_keyframe(kf2)
    second = layer.after_keyframe(kf2, m, depth, states)
    # now the patch is refused at once, and the suitcase is seen again
    assert second.association.floor_patches == (0,)
    assert sorted(o.class_id for o in layer.objects(m.id)) == [SUITCASE]


def test_a_candidate_with_floor_in_its_box_joins_the_object_its_own_points_lie_on() -> None:
    """The candidate's centroid leaves the structure planes out, as the mapped object's does: a second view whose box
    holds a metre of floor in front of the chair merges into the chair instead of making a second one."""
    rng = np.random.default_rng(1)
    chair = _chair(rng)[:180]  # seat, back and legs: no floor
    floor_before = np.c_[rng.uniform(-0.5, 0.5, 220), np.full(220, FLOOR_Y_M), rng.uniform(1.0, 2.0, 220)]
    second = np.vstack([chair, floor_before])
    assert np.linalg.norm(second.mean(axis=0) - chair.mean(axis=0)) > 0.5  # beyond the association gate
    outcomes = []
    for structure in ([], [floor_as_plane(FLOOR)]):
        lta = LongTermAssociation(ObjectMapConfig(n_keyframes_unseen=5))
        ids = np.arange(len(chair), dtype=np.int64)
        lta.process_keyframe(0, [ObjectCandidate(PLANT, (100.0, 60.0, 200.0, 200.0), ids, chair)], np.eye(4), CAM,
                             None, structure=structure)
        ids2 = np.arange(1000, 1000 + len(second), dtype=np.int64)
        lta.process_keyframe(1, [ObjectCandidate(PLANT, (100.0, 60.0, 200.0, 236.0), ids2, second)], np.eye(4), CAM,
                             None, structure=structure)
        outcomes.append(len(lta.objects))
    assert outcomes == [2, 1]
