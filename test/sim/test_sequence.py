"""A rendered sequence's files agree with each other: depth + ground-truth poses, masks + objects.json,
oracle detections + masks; and the same seed gives the same bytes."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from changing_slam_ros.core.geometry.se3 import invert, quat_to_rot, make_pose
from changing_slam_ros.io.camera_info import read_camera_info_yaml
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory
from changing_slam_ros.sim.scenarios import build_scenario
from changing_slam_ros.sim.sequence import RenderOptions, simulate

W, H = 160, 120


@pytest.fixture(scope="module")
def walking(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """walking_xyz, 8 frames 0.5 s apart at 160x120: people walk, the camera moves by decimetres."""
    out = tmp_path_factory.mktemp("walking_xyz")
    simulate(build_scenario("walking_xyz", 3), out, RenderOptions(W, H, frames=8, fps=2.0), seed=3)
    return out


def _load(folder: Path) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], np.ndarray, dict]:
    lines = [ln.split() for ln in (folder / "associations.txt").read_text().splitlines()]
    rgbs, depths, masks = [], [], []
    for _, rgb, _, depth in lines:
        rgbs.append(cv2.imread(str(folder / rgb), cv2.IMREAD_COLOR))
        d = cv2.imread(str(folder / depth), cv2.IMREAD_UNCHANGED)
        assert d.dtype == np.uint16
        depths.append(d.astype(np.float64) / 5000.0)
        masks.append(cv2.imread(str(folder / "masks" / Path(rgb).name), cv2.IMREAD_UNCHANGED))
    poses = read_tum_trajectory(folder / "groundtruth.txt").poses()
    objects = json.loads((folder / "objects.json").read_text())
    return rgbs, depths, masks, poses, objects


def _static_reprojection_errors(folder: Path, poses: np.ndarray, depths: list[np.ndarray],
                                masks: list[np.ndarray], i: int, j: int,
                                grey: list[np.ndarray] | None = None) -> np.ndarray:
    """Room pixels of frame j back-projected, moved into frame i with the ground-truth poses, and
    compared with frame i's depth there (bilinear): |z_predicted - z_rendered| in metres; with `grey`,
    the grey-level difference between the two frames instead."""
    cam = read_camera_info_yaml(folder / "camera_info.yaml")
    v, u = np.nonzero((masks[j] == 0) & (depths[j] > 0))
    pts_j = cam.backproject(np.c_[u, v].astype(float), depths[j][v, u])
    T_i_j = invert(poses[i]) @ poses[j]
    pts_i = pts_j @ T_i_j[:3, :3].T + T_i_j[:3, 3]
    uv = cam.project(pts_i)
    x, y = uv[:, 0], uv[:, 1]
    ok = (pts_i[:, 2] > 0.1) & (x >= 0) & (x <= W - 1.001) & (y >= 0) & (y <= H - 1.001)
    x, y, z = x[ok], y[ok], pts_i[ok, 2]
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ax, ay = x - x0, y - y0
    di, mi = (depths[i] if grey is None else grey[i]), masks[i]
    corners = [(y0, x0), (y0, x0 + 1), (y0 + 1, x0), (y0 + 1, x0 + 1)]
    room = np.all([mi[c] == 0 for c in corners], axis=0)  # not occluded by a person in frame i
    d = ((1 - ax) * (1 - ay) * di[corners[0]] + ax * (1 - ay) * di[corners[1]]
         + (1 - ax) * ay * di[corners[2]] + ax * ay * di[corners[3]])
    if grey is not None:
        z = grey[j][v, u][ok]
    return np.abs(d - z)[room]


def test_static_scene_depth_lands_on_the_same_3d_points_across_frames(walking: Path) -> None:
    rgbs, depths, masks, poses, _ = _load(walking)
    grey = [cv2.cvtColor(c, cv2.COLOR_BGR2GRAY).astype(np.float64) for c in rgbs]
    moved = np.linalg.norm(poses[0][:3, 3] - poses[-1][:3, 3])
    assert moved > 0.1  # the camera really moved
    for i, j in ((0, 3), (2, 7), (5, 1)):
        err = _static_reprojection_errors(walking, poses, depths, masks, i, j)
        assert err.size > 0.3 * W * H
        # surfaces are smooth away from depth edges: median sub-millimetre, 90 % within 1 cm
        assert np.median(err) < 1e-3
        assert np.quantile(err, 0.9) < 1e-2
        # the colours agree too (the texture lands on itself)
        photometric = np.median(_static_reprojection_errors(walking, poses, depths, masks, i, j, grey))
        assert photometric < 2.0
    # the checks have teeth: 2 cm along the optical axis shows in depth, 5 cm sideways in colour
    bad = poses.copy()
    bad[3] = bad[3] @ make_pose(np.eye(3), np.array([0.0, 0.0, 0.02]))
    assert np.median(_static_reprojection_errors(walking, bad, depths, masks, 0, 3)) > 0.015
    bad = poses.copy()
    bad[3] = bad[3] @ make_pose(np.eye(3), np.array([0.05, 0.0, 0.0]))
    good = np.median(_static_reprojection_errors(walking, poses, depths, masks, 0, 3, grey))
    assert np.median(_static_reprojection_errors(walking, bad, depths, masks, 0, 3, grey)) > 2 * good


def test_object_pixels_back_project_into_the_object_box_objects_json_gives(walking: Path) -> None:
    _, depths, masks, poses, objects = _load(walking)
    cam = read_camera_info_yaml(walking / "camera_info.yaml")
    checked = set()
    for k in range(len(masks)):
        for obj in objects["objects"]:
            v, u = np.nonzero(masks[k] == obj["id"])
            if u.size < 30:
                continue
            pose = obj["poses"][k]
            T_world_obj = make_pose(quat_to_rot(np.array(pose[3:])), np.array(pose[:3]))
            pts_cam = cam.backproject(np.c_[u, v].astype(float), depths[k][v, u])
            T_obj_cam = invert(T_world_obj) @ poses[k]
            p = pts_cam @ T_obj_cam[:3, :3].T + T_obj_cam[:3, 3]
            lo, hi = np.array(obj["box_min_m"]) - 0.01, np.array(obj["box_max_m"]) + 0.01
            inside = np.all((p >= lo) & (p <= hi), axis=1)
            assert inside.mean() > 0.99, f"{obj['name']} frame {k}: {inside.mean():.3f} inside its box"
            checked.add(obj["name"])
    assert {"person_astronaut", "person_cameraman", "table", "monitor"} <= checked


def test_walkers_move_and_furniture_stays(walking: Path) -> None:
    *_, objects = _load(walking)
    by_name = {o["name"]: o for o in objects["objects"]}
    for name in ("person_astronaut", "person_cameraman"):
        p = np.array([q[:3] for q in by_name[name]["poses"]])
        assert np.linalg.norm(p[-1] - p[0]) > 0.5 or np.ptp(p[:, 0]) > 0.5
        assert by_name[name]["class_id"] == 0 and by_name[name]["moving"]
    table = np.array([q for q in by_name["table"]["poses"]])
    assert np.ptp(table, axis=0).max() == 0.0


def test_oracle_detections_are_the_mask_bounding_boxes(walking: Path) -> None:
    _, _, masks, _, objects = _load(walking)
    doc = json.loads((walking / "detections.json").read_text())
    classes = {o["id"]: o["class_id"] for o in objects["objects"]}
    assert len(doc["frames"]) == len(masks)
    n = 0
    for frame, mask in zip(doc["frames"], masks):
        expected = {}
        for obj_id in np.unique(mask):
            v, u = np.nonzero(mask == obj_id)
            if obj_id == 0 or u.size < 40 or classes[int(obj_id)] < 0:
                continue
            expected[int(obj_id)] = [int(u.min()), int(v.min()), int(u.max()) + 1, int(v.max()) + 1]
        got = {d["object_id"]: d["box_xyxy"] for d in frame["detections"]}
        assert got == expected
        for d in frame["detections"]:
            assert d["class_id"] == classes[d["object_id"]]
            assert d["pixels"] == int((mask == d["object_id"]).sum())
        n += len(got)
    assert n >= 2 * len(masks)


def test_ground_truth_and_camera_info_match_the_scenario(walking: Path) -> None:
    cam = read_camera_info_yaml(walking / "camera_info.yaml")
    assert (cam.width, cam.height) == (W, H)
    assert cam.fx == pytest.approx(525.0 * W / 640, abs=1e-6)
    assert (cam.cx, cam.cy) == ((W - 1) / 2, (H - 1) / 2)
    traj = read_tum_trajectory(walking / "groundtruth.txt")
    assert np.allclose(np.diff(traj.stamps_s), 0.5, atol=1e-6)
    scenario = build_scenario("walking_xyz", 3)
    for k, T in enumerate(traj.poses()):
        ref = scenario.camera.pose_at(0.5 * k)
        assert np.abs(T - ref).max() < 1e-6


def _digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path: Path) -> None:
    opts = RenderOptions(96, 72, frames=3, fps=2.0)
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        simulate(build_scenario("walking_static", seed), tmp_path / name, opts, seed=seed)
    a, b, c = (_digest(tmp_path / n) for n in "abc")
    assert len(a) == 3 * 3 + 7
    assert a == b
    assert a["objects.json"] != c["objects.json"]
    assert any(a[k] != c[k] for k in a if k.startswith("rgb/"))
