"""Object metrics on a constructed objects.json: matching, centroid error, box IoU, stale and spurious."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.semantic_map import SemanticMap, SemanticObject
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.object_metrics import (
    box_iou_3d, evaluate_objects, load_ground_truth_objects, world_box,
)
from changing_slam_ros.eval.semantic_map_plot import plot_semantic_map

YAW90 = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]


def _gt_file(tmp_path: Path) -> Path:
    doc = {
        "format": "changing_slam_ros sim objects v1", "scenario": "constructed", "stamps_ns": [0, 100],
        "objects": [
            {"id": 1, "name": "chair", "class_id": 56, "class_name": "chair", "moving": False,
             "box_min_m": [-0.25, -0.25, 0.0], "box_max_m": [0.25, 0.25, 0.9],
             "poses": [[1, 1, 0, 0, 0, 0, 1], [3, 1, 0, 0, 0, 0, 1]]},  # moved
            {"id": 2, "name": "cup", "class_id": 41, "class_name": "cup", "moving": False,
             "box_min_m": [-0.05, -0.05, 0.0], "box_max_m": [0.05, 0.05, 0.1],
             "poses": [[0, 2, 0.75, 0, 0, 0, 1], None]},  # removed
            {"id": 3, "name": "monitor", "class_id": 62, "class_name": "tv", "moving": False,
             "box_min_m": [-0.1, -0.3, 0.0], "box_max_m": [0.1, 0.3, 0.5],
             "poses": [[-1, 0, 0.7, *YAW90], [-1, 0, 0.7, *YAW90]]},  # turned 90 deg: world x +-0.3, y +-0.1
            {"id": 4, "name": "walker", "class_id": 0, "class_name": "person", "moving": True,
             "box_min_m": [-0.2, -0.2, 0.0], "box_max_m": [0.2, 0.2, 1.8],
             "poses": [[0, 0, 0, 0, 0, 0, 1], [0.5, 0, 0, 0, 0, 0, 1]]},
        ],
        "changes": [],
    }
    p = tmp_path / "objects.json"
    p.write_text(json.dumps(doc))
    return p


def _est(oid: int, cls: int, centroid: list[float], centre: list[float], size: list[float]) -> SemanticObject:
    return SemanticObject(oid, cls, "x", tuple(centroid), tuple(centre), tuple(size), 0.9, True, 30, 0, 1)


def test_world_box_of_a_turned_object_and_box_iou() -> None:
    lo, hi = world_box([-0.1, -0.3, 0.0], [0.1, 0.3, 0.5], [-1, 0, 0.7, *YAW90])
    np.testing.assert_allclose(lo, [-1.3, -0.1, 0.7], atol=1e-12)
    np.testing.assert_allclose(hi, [-0.7, 0.1, 1.2], atol=1e-12)
    a0, a1 = np.zeros(3), np.ones(3)
    assert box_iou_3d(a0, a1, a0, a1) == pytest.approx(1.0)
    assert box_iou_3d(a0, a1, a0 + [0.5, 0, 0], a1 + [0.5, 0, 0]) == pytest.approx(0.5 / 1.5)
    assert box_iou_3d(a0, a1, a0 + 2, a1 + 2) == 0.0


def test_matching_errors_iou_stale_and_spurious_on_a_constructed_case(tmp_path: Path) -> None:
    gt = load_ground_truth_objects(_gt_file(tmp_path))
    assert [o.name for o in gt.objects] == ["chair", "cup", "monitor", "walker"]
    est = [
        _est(0, 56, [3.05, 1.0, 0.45], [3.0, 1.0, 0.45], [0.5, 0.5, 0.9]),  # chair at its new place
        _est(1, 56, [1.0, 1.0, 0.45], [1.0, 1.0, 0.45], [0.5, 0.5, 0.9]),  # chair at its old place: stale
        _est(2, 41, [0.0, 2.0, 0.8], [0.0, 2.0, 0.8], [0.1, 0.1, 0.1]),  # the removed cup: stale
        _est(3, 62, [-1.0, 0.1, 0.95], [-1.0, 0.0, 0.825], [0.6, 0.2, 0.25]),  # a second, farther tv: spurious
        _est(6, 62, [-1.0, 0.05, 0.95], [-1.0, 0.0, 0.825], [0.6, 0.2, 0.25]),  # the tv, half its height
        _est(4, 41, [5.0, 5.0, 0.0], [5.0, 5.0, 0.0], [0.1, 0.1, 0.1]),  # nothing there: spurious
    ]
    m = evaluate_objects(est, gt)
    assert m.frame == 1
    by_id = {x.estimate_id: x for x in m.matches}
    assert sorted(by_id) == [0, 6]
    assert by_id[0].gt_name == "chair" and by_id[0].centroid_error_m == pytest.approx(0.05)
    assert by_id[0].box_center_error_m == pytest.approx(0.0) and by_id[0].iou == pytest.approx(1.0)
    assert by_id[6].gt_name == "monitor" and by_id[6].centroid_error_m == pytest.approx(0.05)
    assert by_id[6].iou == pytest.approx(0.5)
    assert m.stale == ((1, "chair"), (2, "cup"))
    assert m.spurious == (3, 4)
    assert m.missed == ()  # the walker (moving) is not a map object
    assert m.mean_centroid_error_m == pytest.approx(0.05) and m.mean_iou == pytest.approx(0.75)
    # at the first frame the chair stood at (1, 1): estimate 1 matches, estimate 0 has no chair left behind
    m0 = evaluate_objects(est, gt, frame=0)
    assert {x.estimate_id for x in m0.matches} == {1, 2, 6}
    assert m0.stale == () and 0 in m0.spurious
    assert evaluate_objects([], gt).missed == ("chair", "monitor")
    assert json.loads(json.dumps(m.to_dict()))["matched"] == 2


def test_unmatched_fixed_background_objects_are_structure_not_missed(tmp_path: Path) -> None:
    doc = json.loads(_gt_file(tmp_path).read_text())
    doc["objects"].append({"id": 9, "name": "table", "class_id": 60, "class_name": "dining table", "moving": False,
                           "box_min_m": [-0.6, -0.4, 0.0], "box_max_m": [0.6, 0.4, 0.75],
                           "poses": [[0, 2, 0, 0, 0, 0, 1], [0, 2, 0, 0, 0, 0, 1]]})
    p = tmp_path / "with_table.json"
    p.write_text(json.dumps(doc))
    gt = load_ground_truth_objects(p)
    m = evaluate_objects([], gt)
    assert m.missed == ("chair", "monitor") and m.structure == ("table",)  # dining table (60) is fixed background
    assert m.to_dict()["structure"] == ["table"]
    assert evaluate_objects([], gt, structure_class_ids=()).missed == ("chair", "monitor", "table")
    # a table the layer did map (a config without it in fixed_class_ids) is a match, not structure
    table = _est(5, 60, [0.05, 2.0, 0.4], [0.0, 2.0, 0.375], [1.2, 0.8, 0.75])
    m2 = evaluate_objects([table], gt)
    assert [x.gt_name for x in m2.matches] == ["table"] and m2.structure == ()


def test_bad_ground_truth_files_raise_eval_errors(tmp_path: Path) -> None:
    with pytest.raises(EvalError, match="nope.json: cannot read"):
        load_ground_truth_objects(tmp_path / "nope.json")
    p = tmp_path / "bad.json"
    p.write_text('{"format": "changing_slam_ros sim objects v1", "stamps_ns": [0], "objects": [{"id": 1}]}')
    with pytest.raises(EvalError, match="bad.json: malformed objects ground truth .*KeyError"):
        load_ground_truth_objects(p)
    gt = load_ground_truth_objects(_gt_file(tmp_path))
    with pytest.raises(EvalError, match="frame 5: ground truth has 2 frames"):
        evaluate_objects([], gt, frame=5)


def test_top_view_png_is_written(tmp_path: Path) -> None:
    smap = SemanticMap((_est(0, 56, [3.05, 1.0, 0.45], [3.0, 1.0, 0.45], [0.5, 0.5, 0.9]),
                        SemanticObject(1, 41, "cup", (0.0, 2.0, 0.8), (0.0, 2.0, 0.8), (0.1, 0.1, 0.1), 0.3, False,
                                       12, 0, 1)), ObjectMapConfig().belief_threshold)
    out = tmp_path / "top.png"
    plot_semantic_map(out, smap, trajectory_xyz=np.array([[0.0, 0.0, 0.3], [1.0, 0.5, 0.3], [2.0, 0.0, 0.3]]),
                      ground_truth=[("chair", np.array([2.75, 0.75, 0.0]), np.array([3.25, 1.25, 0.9]))])
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape[0] > 400 and img.shape[1] > 500
    assert (img.std(axis=2) > 20).sum() > 300  # coloured boxes were drawn (not a grey-only figure)
    with pytest.raises(EvalError, match="nothing to plot"):
        plot_semantic_map(tmp_path / "empty.png", SemanticMap((), 0.6))


def test_visible_surface_centroid_is_the_seen_side_and_scores_the_point_centroid_fairly(tmp_path: Path) -> None:
    """A camera at the origin looking along +x (optical z = world x) sees the -x face of the chair at (3, 1):
    the visible-surface centroid is on that face (x = 2.75), 25 cm from the volume centre; an estimate whose
    centroid is the mean of that face's points is 25 cm off the box centre but 0 cm off the seen surface."""
    from changing_slam_ros.core.geometry.camera import CameraIntrinsics
    from changing_slam_ros.eval.object_metrics import SurfaceView, visible_surface_centroids

    gt = load_ground_truth_objects(_gt_file(tmp_path))
    cam = CameraIntrinsics(320, 240, 200.0, 200.0, 159.5, 119.5)
    T_world_cam = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0.45], [0, 0, 0, 1]], float)  # x fwd, z up
    # the chair's front face x = 2.75, y in [0.75, 1.25], z in [0, 0.9], rendered as instance id 1 at depth 2.75
    ids = np.zeros((240, 320), np.uint8)
    depth = np.zeros((240, 320), np.float32)
    vv, uu = np.mgrid[0:240, 0:320]
    u_lo, u_hi = cam.cx - cam.fx * 1.25 / 2.75, cam.cx - cam.fx * 0.75 / 2.75
    v_lo, v_hi = cam.cy - cam.fy * 0.45 / 2.75, cam.cy + cam.fy * 0.45 / 2.75
    face = (uu >= u_lo) & (uu <= u_hi) & (vv >= v_lo) & (vv <= v_hi)
    ids[face], depth[face] = 1, 2.75
    seen_before_move = visible_surface_centroids(gt, [(0, SurfaceView(ids, depth, T_world_cam, cam.backproject))])
    assert "chair" not in seen_before_move  # frame 0: the chair stood elsewhere, not at its final place
    surf = visible_surface_centroids(gt, [(1, SurfaceView(ids, depth, T_world_cam, cam.backproject))])
    np.testing.assert_allclose(surf["chair"], [2.75, 1.0, 0.45], atol=0.05)  # pixel grid of the constructed face
    est = [_est(10, 56, [2.75, 1.02, 0.45], [2.9, 1.0, 0.45], [0.3, 0.5, 0.9])]
    m = evaluate_objects(est, gt, surface_centroids=surf)
    (match,) = m.matches
    assert match.centroid_error_m == pytest.approx(0.25, abs=0.01)
    assert match.surface_centroid_error_m < 0.03 and m.mean_surface_centroid_error_m < 0.03
    assert math.isnan(evaluate_objects(est, gt).matches[0].surface_centroid_error_m)
