"""Dynamic object classification (Changing-SLAM §4.5) end to end on a rendered scene: a static chair, a pushed
chair and a person standing still, seen by a camera sliding sideways in front of a wall."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, PERSON_CLASS_ID, Detection
from changing_slam_ros.core.dynamic.dynamic_objects import DynamicObjectsConfig, DynamicObjectTracker, ObjectMotion
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.core.geometry.se3 import make_pose

CAM = CameraIntrinsics(640, 480, 535.4, 539.2, 320.1, 247.6)
DT_NS = 33_333_333
WALL_M = 4.0


@dataclass
class Billboard:
    """A fronto-parallel rectangle: centre (3,) in the world at t = 0, size (w, h) m, velocity (3,) m/s."""

    class_id: int
    centre: np.ndarray
    size: tuple[float, float]
    velocity: np.ndarray

    def centre_at(self, t_s: float) -> np.ndarray:
        return self.centre + self.velocity * t_s


SCENE = [
    Billboard(CHAIR_CLASS_ID, np.array([-0.7, 0.3, 2.0]), (0.5, 0.7), np.zeros(3)),  # static chair
    Billboard(CHAIR_CLASS_ID, np.array([0.55, 0.3, 2.2]), (0.5, 0.7), np.array([0.4, 0.0, 0.0])),  # pushed chair
    Billboard(PERSON_CLASS_ID, np.array([0.0, 0.0, 1.6]), (0.45, 1.5), np.zeros(3)),  # person standing still
]


def camera_pose(k: int) -> np.ndarray:
    """Camera-to-world: sliding along x at 0.2 m/s, looking down +z at the wall."""
    return make_pose(np.eye(3), np.array([0.2 * k * DT_NS * 1e-9, 0.0, 0.0]))


def render(k: int, rng: np.random.Generator) -> tuple[np.ndarray, list[Detection], np.ndarray, list[np.ndarray]]:
    """Depth image (H, W), detections (boxes 10 % larger than the objects), 800 random keypoints (N, 2),
    and each object's pixel rectangle."""
    t = k * DT_NS * 1e-9
    cam_x = camera_pose(k)[0, 3]
    depth = np.full((CAM.height, CAM.width), WALL_M, np.float32)
    dets, rects = [], []
    for obj in sorted(SCENE, key=lambda o: -o.centre[2]):  # far to near
        c = obj.centre_at(t) - np.array([cam_x, 0.0, 0.0])
        w, h = obj.size
        u0, u1 = CAM.fx * (c[0] - w / 2) / c[2] + CAM.cx, CAM.fx * (c[0] + w / 2) / c[2] + CAM.cx
        v0, v1 = CAM.fy * (c[1] - h / 2) / c[2] + CAM.cy, CAM.fy * (c[1] + h / 2) / c[2] + CAM.cy
        depth[max(int(v0), 0) : int(v1), max(int(u0), 0) : int(u1)] = c[2]
        mu, mv = 0.1 * (u1 - u0), 0.1 * (v1 - v0)
        box = (max(u0 - mu, 0.0), max(v0 - mv, 0.0), min(u1 + mu, CAM.width - 1.0), min(v1 + mv, CAM.height - 1.0))
        dets.append(Detection(box, obj.class_id, 0.9))
        rects.append(np.array([u0, v0, u1, v1]))
    depth += rng.normal(0.0, 0.005, depth.shape).astype(np.float32)
    kps = rng.uniform([0, 0], [CAM.width - 1, CAM.height - 1], (800, 2))
    order = {id(o): i for i, o in enumerate(SCENE)}
    by_scene = sorted(range(len(SCENE)), key=lambda i: -SCENE[i].centre[2])
    dets_scene_order = [dets[by_scene.index(order[id(o)])] for o in SCENE]
    rects_scene_order = [rects[by_scene.index(order[id(o)])] for o in SCENE]
    return depth, dets_scene_order, kps, rects_scene_order


def inside(kps: np.ndarray, r: np.ndarray, shrink_px: float = 2.0) -> np.ndarray:
    return (kps[:, 0] > r[0] + shrink_px) & (kps[:, 0] < r[2] - shrink_px) & (kps[:, 1] > r[1] + shrink_px) & (kps[:, 1] < r[3] - shrink_px)


def test_static_chair_is_used_pushed_chair_and_standing_person_are_filtered_within_fifteen_frames() -> None:
    rng = np.random.default_rng(3)
    tracker = DynamicObjectTracker(CAM)
    verdicts = []
    for k in range(30):
        depth, dets, kps, rects = render(k, rng)
        before = tracker.classify(k * DT_NS, kps, depth, dets)
        res = tracker.update(camera_pose(k))
        assert [o.object_id for o in res.objects] == [0, 1, 2]  # short-term association holds the ids
        verdicts.append([o.motion for o in res.objects])
        on = [inside(kps, r) for r in rects]
        in_person_box = inside(kps, np.array(dets[2].box_xyxy), 0.0)
        behind_person = in_person_box & ~inside(kps, rects[2], -4.0) & ~inside(kps, rects[0], -4.0) & ~inside(kps, rects[1], -4.0)
        # The person's keypoints are never used; the wall seen inside its box always is (repopulation).
        assert not res.use_for_tracking[on[2]].any()
        assert (res.classification.kp_classes[on[2]] == KeypointClass.DYNAMIC).all()
        assert behind_person.sum() > 5 and res.use_for_tracking[behind_person].all()
        assert (res.kp_object_ids[on[2]] == 2).all() and (res.kp_object_ids[behind_person] == -1).all()
        if k == 0:  # new objects are filtered a priori
            assert [o.is_new for o in res.objects] == [True, True, True]
            assert not res.use_for_tracking[on[0] | on[1]].any()
        if k >= 15:
            assert res.objects[0].motion == ObjectMotion.STATIC and res.use_for_tracking[on[0]].all()
            assert before.use_for_tracking[on[0]].all()  # the verdict from the previous frames is used before the update
            assert res.objects[1].motion == ObjectMotion.DYNAMIC and not res.use_for_tracking[on[1]].any()
            assert res.objects[1].speed_mps == pytest.approx(0.4, abs=0.12)
            assert res.objects[0].speed_mps < 0.1
        assert res.objects[2].motion == ObjectMotion.DYNAMIC  # a person is dynamic even standing still
    first_static = next(k for k, v in enumerate(verdicts) if v[0] == ObjectMotion.STATIC)
    first_dynamic = next(k for k, v in enumerate(verdicts) if v[1] == ObjectMotion.DYNAMIC)
    assert first_static <= 15 and first_dynamic <= 6
    np.testing.assert_allclose(tracker.filter_of(0).position_world, SCENE[0].centre, atol=0.05)


def test_without_repopulation_the_background_behind_the_person_is_lost() -> None:
    rng = np.random.default_rng(4)
    depth, dets, kps, rects = render(0, rng)
    cfg = DynamicObjectsConfig()
    plain = DynamicObjectsConfig(classification=type(cfg.classification)(repopulation=False))
    with_repop = DynamicObjectTracker(CAM, cfg).process(0, kps, depth, dets, camera_pose(0))
    without = DynamicObjectTracker(CAM, plain).process(0, kps, depth, dets, camera_pose(0))
    in_box = inside(kps, np.array(dets[2].box_xyxy), 0.0)
    assert not without.use_for_tracking[in_box].any()
    on_wall = in_box & ~inside(kps, rects[2], -4.0) & ~inside(kps, rects[1], -4.0)
    assert on_wall.sum() > 10 and with_repop.use_for_tracking[on_wall].all()
    assert not with_repop.use_for_tracking[inside(kps, rects[2])].any()
    assert with_repop.use_for_tracking.sum() > without.use_for_tracking.sum()


def test_update_before_classify_is_an_error_and_a_second_update_uses_nothing_twice() -> None:
    with pytest.raises(RuntimeError, match="before classify"):
        DynamicObjectTracker(CAM).update(np.eye(4))
    tracker = DynamicObjectTracker(CAM)
    depth, dets, kps, _ = render(0, np.random.default_rng(1))
    first = tracker.process(0, kps, depth, dets, camera_pose(0))
    again = tracker.update(camera_pose(0))
    assert [o.n_updates for o in first.objects] == [o.n_updates for o in again.objects] == [1, 1, 1]


def test_every_threshold_is_read_from_a_yaml_section_with_the_papers_defaults(tmp_path) -> None:
    from changing_slam_ros.config import load_yaml, section
    from changing_slam_ros.core.dynamic.detector import DetectorConfig
    from changing_slam_ros.errors import ConfigError

    path = tmp_path / "dynamic.yaml"
    path.write_text(
        "detector:\n  score_threshold: 0.5\n  intra_op_threads: 1\n  providers: [CPUExecutionProvider]\n"
        "dynamic_objects:\n  doc_threshold_mps: {56: 0.2}\n  min_updates: 4\n"
        "  classification:\n    background_margin_m: {0: 0.7}\n    repopulation: true\n"
        "  ekf:\n    measurement_sigma_m: [0.02, 0.02, 0.04]\n"
        "  association:\n    min_iou: 0.4\n"
    )
    data = load_yaml(path)
    det = section(DetectorConfig, data["detector"], f"{path}: detector")
    dyn = section(DynamicObjectsConfig, data["dynamic_objects"], f"{path}: dynamic_objects")
    assert det.score_threshold == 0.5 and det.providers == ("CPUExecutionProvider",)
    assert dyn.doc_threshold(CHAIR_CLASS_ID) == 0.2 and dyn.min_updates == 4
    assert dyn.classification.margin_m(PERSON_CLASS_ID) == 0.7
    assert dyn.ekf.measurement_sigma_m == (0.02, 0.02, 0.04) and dyn.association.min_iou == 0.4
    # Defaults: the paper's sigma_a per class, persons always dynamic.
    assert (dyn.ekf.sigma_a(PERSON_CLASS_ID), dyn.ekf.sigma_a(CHAIR_CLASS_ID), dyn.ekf.sigma_a(62)) == (0.5, 0.02, 0.01)
    assert dyn.always_dynamic_class_ids == (PERSON_CLASS_ID,)
    with pytest.raises(ConfigError, match="dynamic_objects.classification: unknown key"):
        section(DynamicObjectsConfig, {"classification": {"margin": 1.0}}, f"{path}: dynamic_objects")


def test_segmentation_cues_filter_an_unknown_mover_and_make_a_static_chair_dynamic() -> None:
    rng = np.random.default_rng(5)
    tracker = DynamicObjectTracker(CAM)
    for k in range(25):
        depth, dets, kps, rects = render(k, rng)
        on_chair = inside(kps, rects[0])
        unknown = (kps[:, 0] < 60) & (kps[:, 1] < 120)  # an undetected mover the segmentation found
        flagged = unknown.copy()
        if k >= 20:
            flagged |= on_chair & (rng.uniform(size=len(kps)) < 0.8)  # the chair starts to move
        res = tracker.process(k * DT_NS, kps, depth, dets, camera_pose(k), moving_mask=flagged)
        assert unknown.sum() > 5 and not res.use_for_tracking[unknown].any()
        if 15 <= k < 20:
            assert res.objects[0].motion == ObjectMotion.STATIC and res.use_for_tracking[on_chair].all()
        if k >= 20:  # geometric evidence overrides the EKF that has not seen the motion yet
            assert res.objects[0].motion == ObjectMotion.DYNAMIC and not res.use_for_tracking[on_chair].any()
    with pytest.raises(ValueError, match="moving_mask"):
        tracker.classify(0, kps, depth, dets, moving_mask=np.zeros(3, bool))
