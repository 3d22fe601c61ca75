"""Keypoint classification and feature repopulation (Changing-SLAM §4.1) on constructed depth scenes."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.dynamic.detector import CHAIR_CLASS_ID, PERSON_CLASS_ID, Detection
from changing_slam_ros.core.map.keyframe import KeypointClass
from changing_slam_ros.core.dynamic.keypoint_classification import (
    KeypointClassificationConfig,
    box_depth_stats,
    classify_keypoints,
    draw_keypoint_classes,
    median_1d,
    nearest_depth_around,
)

H, W = 480, 640
WALL_M = 3.0


def grid(x0: int, y0: int, x1: int, y1: int, step: int = 10) -> np.ndarray:
    """Keypoints (K, 2) on a regular grid inside [x0, x1) x [y0, y1)."""
    xs, ys = np.meshgrid(np.arange(x0 + step / 2, x1, step), np.arange(y0 + step / 2, y1, step))
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def person_scene() -> tuple[np.ndarray, Detection, np.ndarray, np.ndarray]:
    """Wall at 3 m; a person (torso x 260..380, y 100..440) at 1.5 m; its box x 230..410, y 80..460."""
    depth = np.full((H, W), WALL_M, np.float32)
    depth[100:440, 260:380] = 1.5
    box = Detection((230.0, 80.0, 410.0, 460.0), PERSON_CLASS_ID, 0.95)
    on_person = grid(262, 102, 378, 438, 12)
    behind = np.concatenate([grid(232, 82, 258, 458, 8), grid(382, 82, 408, 458, 8)])  # wall inside the box
    return depth, box, on_person, behind


def test_repopulation_keeps_background_keypoints_behind_a_person_box_and_drops_the_persons() -> None:
    depth, box, on_person, behind = person_scene()
    outside = grid(20, 20, 200, 460, 20)
    kps = np.concatenate([on_person, behind, outside])
    res = classify_keypoints(kps, depth, [box])
    n1, n2 = len(on_person), len(on_person) + len(behind)
    assert (res.kp_classes[:n1] == KeypointClass.DYNAMIC).all()
    assert (res.kp_object_class_ids[:n1] == PERSON_CLASS_ID).all() and (res.kp_box_index[:n1] == 0).all()
    assert (res.kp_classes[n1:n2] == KeypointClass.STATIC).all()  # repopulated background
    assert (res.kp_object_class_ids[n1:] == -1).all() and (res.kp_box_index[n1:] == -1).all()
    assert (res.kp_classes[n2:] == KeypointClass.STATIC).all()
    assert res.box_usable[0] and res.box_background_depth_m[0] == pytest.approx(1.5 + 0.8)
    assert res.static_mask().sum() == len(behind) + len(outside)
    # Without repopulation every keypoint in the box shares the person's class (paper Fig. 3a).
    plain = classify_keypoints(kps, depth, [box], KeypointClassificationConfig(repopulation=False))
    assert (plain.kp_classes[:n2] == KeypointClass.DYNAMIC).all() and (plain.kp_classes[n2:] == KeypointClass.STATIC).all()


def test_box_depth_statistics_match_the_constructed_scene() -> None:
    depth, box, _, _ = person_scene()
    st = box_depth_stats(depth, box.box_xyxy, np.zeros((0, 4)), KeypointClassificationConfig(stats_stride_px=1))
    assert st is not None
    frac = (120 * 340) / (180 * 380)  # person pixels / box pixels
    assert st.min_m == pytest.approx(1.5) and st.max_m == pytest.approx(3.0) and st.median_m == pytest.approx(1.5)
    assert st.mean_m == pytest.approx(1.5 * frac + 3.0 * (1 - frac), abs=1e-6)
    assert st.std_m == pytest.approx(1.5 * np.sqrt(frac * (1 - frac)), abs=1e-6)
    assert st.centre_m == pytest.approx(1.5) and st.valid_fraction == pytest.approx(1.0)


def chair_scene(with_occluder: bool) -> tuple[np.ndarray, Detection, np.ndarray, np.ndarray]:
    """Chair at 2 m filling most of its box (x 200..440, y 150..450) in front of the 3 m wall; optionally an
    undetected pole at 1 m across the box centre (x 300..340)."""
    depth = np.full((H, W), WALL_M, np.float32)
    depth[170:450, 215:425] = 2.0
    if with_occluder:
        depth[:, 300:340] = 1.0
    box = Detection((200.0, 150.0, 440.0, 450.0), CHAIR_CLASS_ID, 0.9)
    on_chair = np.concatenate([grid(217, 172, 297, 448, 12), grid(343, 172, 423, 448, 12)])
    behind = grid(202, 152, 440, 168, 6)  # wall strip above the chair, still inside the box
    return depth, box, on_chair, behind


def test_a_chair_in_the_open_is_movable_and_the_wall_behind_it_static() -> None:
    depth, box, on_chair, behind = chair_scene(with_occluder=False)
    res = classify_keypoints(np.concatenate([on_chair, behind]), depth, [box])
    assert res.box_usable[0]
    assert (res.kp_classes[: len(on_chair)] == KeypointClass.MOVABLE).all()
    assert (res.kp_object_class_ids[: len(on_chair)] == CHAIR_CLASS_ID).all()
    assert (res.kp_classes[len(on_chair) :] == KeypointClass.STATIC).all()


def test_occlusion_by_an_unlabelled_object_disables_the_objects_keypoints() -> None:
    depth, box, on_chair, behind = chair_scene(with_occluder=True)
    outside = grid(20, 20, 180, 460, 20)
    kps = np.concatenate([on_chair, behind, outside])
    res = classify_keypoints(kps, depth, [box])
    st = res.box_stats[0]
    assert st is not None and st.centre_m == pytest.approx(1.0) and st.median_m == pytest.approx(2.0)
    assert not res.box_usable[0]
    n2 = len(on_chair) + len(behind)
    # Nothing inside the box is used: not the chair, and not the wall seen through it either.
    assert (res.kp_classes[:n2] == KeypointClass.UNUSED).all()
    assert (res.kp_classes[n2:] == KeypointClass.STATIC).all()


def test_a_large_depth_spread_disables_the_objects_keypoints() -> None:
    depth, box, on_person, behind = person_scene()
    depth[depth == WALL_M] = 6.0  # same person, far background: std 2.2 m > 1.5 m
    paper = KeypointClassificationConfig(repopulate_occluded_class_ids=())
    res = classify_keypoints(np.concatenate([on_person, behind]), depth, [box], paper)
    assert res.box_stats[0] is not None and res.box_stats[0].std_m > 1.5
    assert not res.box_usable[0] and (res.kp_classes == KeypointClass.UNUSED).all()
    relaxed = classify_keypoints(np.concatenate([on_person, behind]), depth, [box],
                                 KeypointClassificationConfig(max_depth_std_m=3.0))  # fmt: skip
    assert (relaxed.kp_classes[: len(on_person)] == KeypointClass.DYNAMIC).all()
    assert (relaxed.kp_classes[len(on_person) :] == KeypointClass.STATIC).all()


def test_a_spread_box_can_keep_the_background_deeper_than_its_centre_and_still_drop_the_object() -> None:
    depth, box, on_person, behind = person_scene()
    depth[depth == WALL_M] = 6.0  # std 2.2 m: the box is left out, but its centre lies on the person at 1.5 m
    kps = np.concatenate([on_person, behind])
    cfg = KeypointClassificationConfig(repopulate_occluded_class_ids=(PERSON_CLASS_ID, CHAIR_CLASS_ID))
    res = classify_keypoints(kps, depth, [box], cfg)
    assert not res.box_usable[0] and res.box_background_depth_m[0] == pytest.approx(1.5 + 0.8)
    assert (res.kp_classes[: len(on_person)] == KeypointClass.UNUSED).all()
    assert (res.kp_classes[len(on_person) :] == KeypointClass.STATIC).all()
    # An occluded centre says nothing of the object's depth: the whole box stays out.
    depth, chair, on_chair, behind = chair_scene(with_occluder=True)
    occluded = classify_keypoints(np.concatenate([on_chair, behind]), depth, [chair], cfg)
    assert not occluded.box_usable[0] and (occluded.kp_classes == KeypointClass.UNUSED).all()


def test_a_thin_person_before_a_far_wall_can_keep_the_wall_seen_around_it() -> None:
    # A box fitted to a stick figure at 1.5 m (torso spanning the box's height, arms its width) before a wall at
    # 4 m that fills most of the box: the median lies on the wall, so the centre test calls the box occluded.
    depth = np.full((H, W), 4.0, np.float32)
    depth[80:460, 300:340] = 1.5
    depth[180:200, 200:440] = 1.5
    box = Detection((200.0, 80.0, 440.0, 460.0), PERSON_CLASS_ID, 0.9)
    on_person = grid(302, 82, 338, 458, 8)
    wall = np.concatenate([grid(204, 84, 296, 176, 10), grid(344, 204, 436, 456, 10)])
    kps = np.concatenate([on_person, wall])
    res = classify_keypoints(kps, depth, [box], KeypointClassificationConfig(repopulate_occluded_class_ids=()))
    st = res.box_stats[0]
    assert st is not None and st.std_m < 1.5 and st.median_m == pytest.approx(4.0) and st.centre_m == pytest.approx(1.5)
    assert not res.box_usable[0] and (res.kp_classes == KeypointClass.UNUSED).all()  # the paper's rule
    cfg = KeypointClassificationConfig(repopulate_occluded_class_ids=(PERSON_CLASS_ID, CHAIR_CLASS_ID))
    kept = classify_keypoints(kps, depth, [box])  # the default: person boxes
    assert (kept.kp_classes == classify_keypoints(kps, depth, [box], cfg).kp_classes).all()
    assert not kept.box_usable[0] and (kept.kp_classes[: len(on_person)] == KeypointClass.UNUSED).all()
    assert (kept.kp_classes[len(on_person) :] == KeypointClass.STATIC).all()
    # A pole in front of a chair spans the box's height but not its width: the chair behind keeps the box out.
    depth, chair, on_chair, behind = chair_scene(with_occluder=True)
    occluded = classify_keypoints(np.concatenate([on_chair, behind]), depth, [chair], cfg)
    assert not occluded.box_usable[0] and (occluded.kp_classes == KeypointClass.UNUSED).all()


def test_the_optional_centre_band_check_disables_an_object_behind_an_unlabelled_table() -> None:
    depth, box, on_person, behind = person_scene()
    depth[380:460, 230:410] = 0.5  # a table in front of the person's legs; the box centre stays on the person
    kps = np.concatenate([on_person, behind])
    res = classify_keypoints(kps, depth, [box], KeypointClassificationConfig(check_centre_in_object_band=True))
    assert not res.box_usable[0]
    assert (res.kp_classes == KeypointClass.UNUSED).all()
    # Without the check (the paper's rule, default) the person's torso (1.5 m > 0.5 + 0.8) is taken for background.
    paper = classify_keypoints(kps, depth, [box])
    assert paper.box_usable[0]
    assert (paper.kp_classes[: len(on_person)][on_person[:, 1] < 380] == KeypointClass.STATIC).all()


def test_overlapping_detected_boxes_are_left_out_of_each_others_statistics() -> None:
    depth = np.full((H, W), WALL_M, np.float32)
    depth[120:460, 100:300] = 2.0  # chair
    depth[60:470, 260:400] = 1.2  # person in front of the chair's right part
    chair = Detection((90.0, 110.0, 310.0, 465.0), CHAIR_CLASS_ID, 0.9)
    person = Detection((250.0, 50.0, 410.0, 475.0), PERSON_CLASS_ID, 0.9)
    on_chair = grid(102, 122, 248, 458, 15)
    on_person_in_overlap = grid(262, 122, 308, 458, 15)
    kps = np.concatenate([on_chair, on_person_in_overlap])
    res = classify_keypoints(kps, depth, [chair, person])
    iou = (60 * 355) / (220 * 355 + 160 * 425 - 60 * 355)
    np.testing.assert_allclose(res.iou, [[1.0, iou], [iou, 1.0]], atol=1e-9)
    st_chair = res.box_stats[0]
    assert st_chair is not None and st_chair.min_m == pytest.approx(2.0)  # the person's 1.2 m is excluded
    with_overlap = classify_keypoints(kps, depth, [chair, person], KeypointClassificationConfig(exclude_overlaps=False))
    assert with_overlap.box_stats[0] is not None and with_overlap.box_stats[0].min_m == pytest.approx(1.2)
    assert res.box_usable.all()
    assert (res.kp_classes[: len(on_chair)] == KeypointClass.MOVABLE).all()
    assert (res.kp_classes[len(on_chair) :] == KeypointClass.DYNAMIC).all()  # the person wins the overlap
    assert (res.kp_box_index[len(on_chair) :] == 1).all()


def test_debug_image_colours_keypoints_like_paper_figure_2() -> None:
    depth, box, on_person, behind = person_scene()
    kps = np.array([on_person[0], behind[0], [100.0, 100.0]])
    res = classify_keypoints(kps, depth, [box])
    img = draw_keypoint_classes(np.zeros((H, W, 3), np.uint8), kps, res.kp_classes, [box], radius_px=3)
    for (u, v), rgb in zip(kps, [(255, 0, 0), (0, 255, 0), (0, 255, 0)]):
        window = img[int(v) - 5 : int(v) + 6, int(u) - 5 : int(u) + 6].reshape(-1, 3)
        assert (window == rgb).all(axis=1).sum() >= 8  # the circle's ring in the class colour


def test_a_corner_on_the_silhouette_just_outside_a_tight_box_is_the_persons() -> None:
    """A tight box spanning the person's pixel indices 260..379 (x_max exclusive): corners detected on the
    silhouette's left edge lie up to half a pixel left of it (x 259.6); they take the person's class, while
    the wall a few pixels further out stays static."""
    depth = np.full((H, W), WALL_M, np.float32)
    depth[100:440, 260:380] = 1.5
    box = Detection((260.0, 100.0, 380.0, 440.0), PERSON_CLASS_ID, 1.0)
    edge = np.array([[259.6, 200.0], [259.7, 300.0], [300.0, 99.6]])
    wall = np.array([[254.0, 200.0], [300.0, 94.0]])
    res = classify_keypoints(np.concatenate([edge, wall]), depth, [box])
    assert (res.kp_classes[:3] == KeypointClass.DYNAMIC).all()
    assert (res.kp_classes[3:] == KeypointClass.STATIC).all()
    tight = classify_keypoints(edge, depth, [box], KeypointClassificationConfig(box_margin_px=0.0))
    assert (tight.kp_classes == KeypointClass.STATIC).all()  # what leaked into tracking before


def test_the_box_margin_widens_only_a_priori_dynamic_boxes() -> None:
    """The same silhouette corners next to a chair box (movable) stay outside it: only person boxes get the
    margin (widening every box took the PUC-like `static` run from 3.15 to 12.66 cm ATE)."""
    depth = np.full((H, W), WALL_M, np.float32)
    depth[100:440, 260:380] = 1.5
    chair = Detection((260.0, 100.0, 380.0, 440.0), 56, 1.0)
    edge = np.array([[259.6, 200.0], [259.7, 300.0], [300.0, 99.6]])
    inner = np.array([[300.0, 300.0]])
    res = classify_keypoints(np.concatenate([edge, inner]), depth, [chair])
    assert (res.kp_classes[:3] == KeypointClass.STATIC).all()
    assert res.kp_classes[3] == KeypointClass.MOVABLE


def test_nearest_depth_is_the_smallest_valid_depth_of_the_window_clipped_at_the_image_border() -> None:
    """Against a per-keypoint loop: windows cut by the border (keypoints on and past it, where the window's rows
    and columns clip one by one), no valid depth (0), a NaN in the window (-> 0, as the min propagates it)."""
    rng = np.random.default_rng(4)
    h, w, r = 24, 32, 2
    depth = rng.uniform(0.5, 4.0, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.3] = 0.0
    depth[5:10, 5:10] = 0.0
    depth[20, 3] = np.nan
    kps = np.vstack([rng.uniform(-3.0, w + 2.0, (300, 2)) * [1.0, h / w], [[7.0, 7.0], [3.2, 19.6], [31.6, 23.5]]])
    got = nearest_depth_around(depth, kps, r)
    for (x, y), d in zip(kps, got):
        u, v = int(np.rint(x)), int(np.rint(y))
        win = depth[np.clip(np.arange(v - r, v + r + 1), 0, h - 1)][:, np.clip(np.arange(u - r, u + r + 1), 0, w - 1)]
        if np.isnan(win).any():
            assert d == 0.0
            continue
        valid = win[win > 0.0]
        assert d == (float(valid.min()) if valid.size else 0.0)
    assert got[-3] == 0.0 and got[-2] == 0.0


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11])
def test_median_1d_is_numpys_median_bit_for_bit(n: int) -> None:
    vals = np.random.default_rng(n).uniform(0.3, 5.0, n)
    assert median_1d(vals) == float(np.median(vals))


@pytest.mark.parametrize("seed", range(4))
def test_a_keypoint_in_several_boxes_takes_the_unusable_then_dynamic_then_nearest_one(seed: int) -> None:
    """Random overlapping boxes over layered depth, against the rule written per keypoint: among the boxes a
    keypoint is inside (person boxes widened by `box_margin_px`) and in front of the box's background depth (or
    any keypoint, for an unusable box that has none), the unusable box wins, then a dynamic class, then the smallest minimum
    depth; a low score drops a box."""
    rng = np.random.default_rng(seed)
    cfg = KeypointClassificationConfig(min_detection_score=0.2)
    depth = np.full((H, W), WALL_M, np.float32)
    dets = []
    for k in range(6):
        x0, y0 = rng.uniform(0, W - 200), rng.uniform(0, H - 200)
        x1, y1 = x0 + rng.uniform(60, 200), y0 + rng.uniform(60, 200)
        depth[int(y0) + 5 : int(y1) - 5, int(x0) + 5 : int(x1) - 5] = rng.uniform(0.8, 2.8)
        if k == 5:  # something in front of this box's centre only: occluded, so unusable
            cy, cx = int((y0 + y1) / 2), int((x0 + x1) / 2)
            depth[cy - 12 : cy + 12, cx - 12 : cx + 12] = 0.3
        cls = PERSON_CLASS_ID if k % 3 == 0 else CHAIR_CLASS_ID
        dets.append(Detection((x0, y0, x1, y1), cls, 0.1 if k == 4 else 0.9))
    depth[rng.random((H, W)) < 0.05] = 0.0
    kps = rng.uniform([0, 0], [W, H], (800, 2))
    res = classify_keypoints(kps, depth, dets, cfg)
    kp_depth = nearest_depth_around(depth, kps, cfg.keypoint_depth_window_px)
    for i, (x, y) in enumerate(kps):
        owners = []
        for b, d in enumerate(dets):
            if d.score < cfg.min_detection_score:
                continue
            g = cfg.box_margin_px if d.class_id == PERSON_CLASS_ID else 0.0
            bx0, by0, bx1, by1 = d.box_xyxy
            if not (bx0 - g <= x < bx1 + g and by0 - g <= y < by1 + g):
                continue
            fg = kp_depth[i] <= res.box_background_depth_m[b] if kp_depth[i] > 0 else cfg.invalid_depth_is_object
            if fg or (not res.box_usable[b] and np.isinf(res.box_background_depth_m[b])):
                st = res.box_stats[b]
                owners.append((bool(res.box_usable[b]), d.class_id != PERSON_CLASS_ID, st.min_m if st else np.inf, b))
        if not owners:
            assert res.kp_box_index[i] == -1 and res.kp_classes[i] == KeypointClass.STATIC
            continue
        usable, not_dyn, _, b = min(owners)
        assert res.kp_box_index[i] == b and res.kp_object_class_ids[i] == dets[b].class_id
        want = KeypointClass.UNUSED if not usable else KeypointClass.MOVABLE if not_dyn else KeypointClass.DYNAMIC
        assert res.kp_classes[i] == want
    assert not res.box_usable[5] and (res.kp_classes == KeypointClass.UNUSED).any()
