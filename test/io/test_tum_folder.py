"""TUM-layout folders: association, stamps, pixels, depths, intrinsics and ground truth on real data."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.errors import DatasetError
from changing_slam_ros.io.camera_info import write_camera_info_yaml
from changing_slam_ros.io.dataset_config import load_dataset_settings
from changing_slam_ros.io.tum_folder import (
    TumFolder,
    associate,
    format_stamp,
    parse_stamp_ns,
    read_groundtruth,
)
from changing_slam_ros.core.geometry.camera import CameraIntrinsics


def _settings(name: str):  # noqa: ANN202
    return load_dataset_settings(name)


# -- stamps and association ------------------------------------------------------------------------
def test_stamps_parse_exactly_without_float_rounding() -> None:
    assert parse_stamp_ns("1305031102.175304") == 1305031102_175304000
    assert parse_stamp_ns("1305031102.0060") == 1305031102_006000000
    assert parse_stamp_ns("0.033333") == 33_333_000
    assert parse_stamp_ns("12") == 12_000_000_000
    assert parse_stamp_ns("1.0000000015") == 1_000_000_002  # rounded half up past ns
    assert parse_stamp_ns("-0.5") == -500_000_000
    # float parsing would give ...175303888 for this stamp
    assert int(float("1305031102.175304") * 1e9) != 1305031102_175304000
    assert format_stamp(1305031102_175304000) == "1305031102.175304"
    assert format_stamp(5_000_000_001) == "5.000000001"
    for bad in ("", "abc", "1.2.3", "1e5", "."):
        with pytest.raises(ValueError):
            parse_stamp_ns(bad)


def _associate_py(first: dict[float, str], second: dict[float, str], offset: float, max_diff: float):  # noqa: ANN202
    """The algorithm of TUM's associate.py, written out for the comparison below."""
    first_keys, second_keys = list(first), list(second)
    potential = sorted(
        (abs(a - (b + offset)), a, b) for a in first_keys for b in second_keys if abs(a - (b + offset)) < max_diff
    )
    matches = []
    for _, a, b in potential:
        if a in first_keys and b in second_keys:
            first_keys.remove(a)
            second_keys.remove(b)
            matches.append((a, b))
    return sorted(matches)


def test_association_prefers_smallest_difference_and_each_stamp_once() -> None:
    # rgb at 0, 10, 20 ms; depth at 4, 9, 40 ms; max 20 ms.
    # candidates by diff: (10,9)=1 (0,4)=4 (10,4)=6 (20,9)=11 ... (20,40)=20 not < 20
    rgb = [0, 10_000_000, 20_000_000]
    depth = [4_000_000, 9_000_000, 40_000_000]
    assert associate(rgb, depth, 0, 20_000_000) == [(0, 0), (1, 1)]
    # offset -25 ms shifts depth to -21, -16, 15 ms: 10 and 20 tie at 5 ms for the 15 ms frame and
    # the earlier colour stamp wins the tie (tuple order); then 0 takes -16 (16 ms)
    assert associate(rgb, depth, -25_000_000, 20_000_000) == [(0, 1), (1, 2)]
    # 20 ms apart is NOT associated (strict <), 19.999999 ms is
    assert associate([0], [20_000_000], 0, 20_000_000) == []
    assert associate([0], [19_999_999], 0, 20_000_000) == [(0, 0)]


def test_association_matches_associate_py_on_real_fr1_lists() -> None:
    root = require(FR1_XYZ_10)
    from changing_slam_ros.io.tum_folder import read_file_list

    rgb = read_file_list(root / "rgb.txt")
    depth = read_file_list(root / "depth.txt")
    for max_diff in (0.005, 0.01, 0.02, 0.05):
        for offset in (0.0, 0.012):
            got = associate([f.stamp_ns for f in rgb], [f.stamp_ns for f in depth],
                            round(offset * 1e9), round(max_diff * 1e9))  # fmt: skip
            ref = _associate_py(
                {float(format_stamp(f.stamp_ns)): f.relpath for f in rgb},
                {float(format_stamp(f.stamp_ns)): f.relpath for f in depth}, offset, max_diff,
            )  # fmt: skip
            got_s = [(float(format_stamp(rgb[i].stamp_ns)), float(format_stamp(depth[j].stamp_ns))) for i, j in got]
            assert got_s == ref, (max_diff, offset)
    # at the default 0.02 s, colour 1305031102.243211 loses its nearest depth frame to a closer pair
    assert len(associate([f.stamp_ns for f in rgb], [f.stamp_ns for f in depth])) == 9


def test_association_on_constructed_lists_like_associate_py(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    rgb_t = np.cumsum(rng.uniform(0.025, 0.040, 200)) + 1000.0
    depth_t = np.sort(rgb_t + rng.normal(0.0, 0.012, 200))
    rgb_s = [f"{t:.6f}" for t in rgb_t]
    depth_s = [f"{t:.6f}" for t in depth_t]
    got = associate([parse_stamp_ns(s) for s in rgb_s], [parse_stamp_ns(s) for s in depth_s], 0, 20_000_000)
    ref = _associate_py({float(s): s for s in rgb_s}, {float(s): s for s in depth_s}, 0.0, 0.02)
    assert [(float(rgb_s[i]), float(depth_s[j])) for i, j in got] == ref
    assert 120 < len(got) < 200


# -- real folders -------------------------------------------------------------------------------------
def test_fr1_folder_uses_associations_and_reads_exact_pixels_and_metres() -> None:
    root = require(FR1_XYZ_10)
    s = _settings("tum_fr1")
    src = TumFolder(root, s.dataset, s.camera)
    assert len(src) == 9  # associations.txt pairs 9 of the 10 colour frames
    lines = [ln.split() for ln in (root / "associations.txt").read_text().splitlines() if ln.strip()]
    frames = list(src)
    for k, (frame, parts) in enumerate(zip(frames, lines)):
        assert frame.index == k
        assert frame.stamp_ns == parse_stamp_ns(parts[0])
        assert src.pairs[k].depth_path == root / parts[3]
        bgr = cv2.imread(str(root / parts[1]), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(frame.rgb, bgr[:, :, ::-1])
        raw = cv2.imread(str(root / parts[3]), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(frame.depth_m, raw.astype(np.float32) / 5000.0)
        assert frame.rgb.dtype == np.uint8 and frame.depth_m.dtype == np.float32
    assert frames[0].stamp_ns == 1305031102_175304000
    # metres: the fr1_xyz desk is 0.5 .. 3 m away
    valid = frames[0].depth_m[frames[0].depth_m > 0]
    assert 0.4 < np.percentile(valid, 5) and np.percentile(valid, 95) < 3.5
    cam = frames[0].camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (517.3, 516.5, 318.6, 255.3)
    assert cam.dist == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)


def test_fr1_ground_truth_is_the_nearest_pose_of_groundtruth_txt() -> None:
    root = require(FR1_XYZ_10)
    s = _settings("tum_fr1")
    src = TumFolder(root, s.dataset, s.camera)
    gt = src.groundtruth
    assert gt is not None
    rows = np.array([[float(v) for v in ln.split()] for ln in (root / "groundtruth.txt").read_text().splitlines()
                     if ln.strip() and not ln.startswith("#")])  # fmt: skip
    assert len(gt) == len(rows)
    np.testing.assert_allclose(gt.stamps_s, rows[:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(gt.positions, rows[:, 1:4], atol=1e-12)
    frame = next(iter(src))
    k = int(np.argmin(np.abs(rows[:, 0] - 1305031102.175304)))
    T = frame.T_world_cam_gt
    assert T is not None
    np.testing.assert_allclose(T[:3, 3], rows[k, 1:4], atol=1e-12)
    q = rows[k, 4:8] / np.linalg.norm(rows[k, 4:8])
    x, y, z, w = q
    # third column of R is the optical axis: compare against the textbook formula
    np.testing.assert_allclose(T[:3, 2], [2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert abs(rows[k, 0] - 1305031102.175304) < 0.01


def test_redkitchen_7scenes_reads_millimetre_depth_and_identical_stamps() -> None:
    root = require(REDKITCHEN)
    s = _settings("7scenes")
    src = TumFolder(root, s.dataset, s.camera)
    assert len(src) == 1000  # 7-Scenes stamps of colour and depth are identical
    assert all(p.rgb_stamp_ns == p.depth_stamp_ns for p in src.pairs)
    assert src.pairs[1].rgb_stamp_ns == 33_333_000
    for k in (0, 1, 999):
        frame = src.frame(k)
        bgr = cv2.imread(str(src.pairs[k].rgb_path), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(frame.rgb, bgr[:, :, ::-1])
        raw = cv2.imread(str(src.pairs[k].depth_path), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(frame.depth_m, raw.astype(np.float32) / 1000.0)
        assert frame.T_world_cam_gt is not None
    assert (src.camera.fx, src.camera.cx, src.camera.cy) == (585.0, 320.0, 240.0)
    gt_first = np.array("-0.340456340 0.016469818 0.296569170".split(), float)
    np.testing.assert_allclose(src.frame(0).T_world_cam_gt[:3, 3], gt_first, atol=1e-12)


def test_camera_info_yaml_beside_data_wins_over_config(tmp_path: Path) -> None:
    root = require(FR1_XYZ_10)
    copy = tmp_path / "fr1"
    shutil.copytree(root, copy)
    write_camera_info_yaml(copy / "camera_info.yaml", CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5))
    s = _settings("tum_fr1")
    src = TumFolder(copy, s.dataset, s.camera)
    assert (src.camera.fx, src.camera.cy, src.camera.dist) == (525.0, 239.5, (0.0,) * 5)


def test_without_associations_file_rgb_and_depth_lists_are_associated(tmp_path: Path) -> None:
    root = require(FR1_XYZ_10)
    copy = tmp_path / "fr1"
    shutil.copytree(root, copy)
    (copy / "associations.txt").unlink()
    s = _settings("tum_fr1")
    src = TumFolder(copy, s.dataset, s.camera)
    # the lists are paired by associate.py rules (9 pairs), not the hand-made registration (10)
    assert len(src) == 9
    for pair in src.pairs:
        assert abs(pair.rgb_stamp_ns - pair.depth_stamp_ns) < 20_000_000


# -- bad input ----------------------------------------------------------------------------------------
def test_empty_folder_names_the_missing_list(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"missing rgb\.txt"):
        TumFolder(tmp_path, _settings("tum_fr1").dataset, _settings("tum_fr1").camera)


def test_not_a_folder(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"nope: not a folder"):
        TumFolder(tmp_path / "nope", _settings("tum_fr1").dataset)


def test_missing_camera_is_explained(tmp_path: Path) -> None:
    root = require(FR1_XYZ_10)
    with pytest.raises(DatasetError, match=r"no camera_info\.yaml beside the data and no camera: section"):
        TumFolder(root, _settings("tum_fr1").dataset, None)


def _copy(tmp_path: Path) -> Path:
    copy = tmp_path / "fr1"
    shutil.copytree(require(FR1_XYZ_10), copy)
    for p in copy.rglob("*"):
        p.chmod(0o755 if p.is_dir() else 0o644)
    copy.chmod(0o755)
    return copy


def test_missing_and_truncated_images_name_the_file(tmp_path: Path) -> None:
    copy = _copy(tmp_path)
    s = _settings("tum_fr1")
    src = TumFolder(copy, s.dataset, s.camera)
    (copy / "rgb/1305031102.211214.png").unlink()  # removed after opening: found when read
    with pytest.raises(DatasetError, match=r"rgb/1305031102\.211214\.png: colour image file missing"):
        list(src)
    # missing when opening: reported at once, before any frame is read
    with pytest.raises(DatasetError, match=r"rgb/1305031102\.211214\.png: image file missing \(1 of the 18 files"):
        TumFolder(copy, s.dataset, s.camera)
    d = copy / "depth/1305031102.194330.png"
    d.write_bytes(d.read_bytes()[:5000])
    with pytest.raises(DatasetError, match=r"depth/1305031102\.194330\.png: depth image is truncated"):
        src.frame(0)
    d.write_bytes(b"not a png at all")
    with pytest.raises(DatasetError, match=r"1305031102\.194330\.png: depth image cannot be decoded"):
        src.frame(0)


def test_colour_depth_size_mismatch_is_reported(tmp_path: Path) -> None:
    copy = _copy(tmp_path)
    s = _settings("tum_fr1")
    d = copy / "depth/1305031102.194330.png"
    cv2.imwrite(str(d), np.zeros((240, 320), np.uint16))
    with pytest.raises(DatasetError, match=r"is 640x480 but .*1305031102\.194330\.png is 320x240"):
        TumFolder(copy, s.dataset, s.camera).frame(0)


def test_8bit_depth_is_rejected(tmp_path: Path) -> None:
    copy = _copy(tmp_path)
    s = _settings("tum_fr1")
    cv2.imwrite(str(copy / "depth/1305031102.194330.png"), np.zeros((480, 640), np.uint8))
    with pytest.raises(DatasetError, match=r"depth image is uint8 480x640, expected a 16-bit"):
        TumFolder(copy, s.dataset, s.camera).frame(0)


def test_malformed_lists_name_file_and_line(tmp_path: Path) -> None:
    copy = _copy(tmp_path)
    s = _settings("tum_fr1")
    (copy / "associations.txt").write_text("# c\n1.0 rgb/a.png 1.0\n")
    with pytest.raises(DatasetError, match=r"associations\.txt:2: expected 't_rgb rgb/x\.png t_depth"):
        TumFolder(copy, s.dataset, s.camera)
    (copy / "associations.txt").unlink()
    (copy / "rgb.txt").write_text("1305031102.17x rgb/a.png\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt:1: timestamp '1305031102\.17x' is not a decimal"):
        TumFolder(copy, s.dataset, s.camera)
    (copy / "rgb.txt").write_text("# nothing\n")
    with pytest.raises(DatasetError, match=r"rgb\.txt: lists no frames"):
        TumFolder(copy, s.dataset, s.camera)
    (copy / "rgb.txt").write_text("5.0 rgb/a.png\n")
    with pytest.raises(DatasetError, match=r"no colour frame has a depth frame within 0\.02 s"):
        TumFolder(copy, s.dataset, s.camera)


def test_bad_groundtruth_names_file_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "groundtruth.txt"
    bad.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError, match=r"groundtruth\.txt:2: expected 8 columns"):
        read_groundtruth(bad)
    bad.write_text("1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"pose 1 has a non-finite value or a zero quaternion"):
        read_groundtruth(bad)
    bad.write_text("# empty\n")
    with pytest.raises(DatasetError, match=r"groundtruth\.txt: no poses"):
        read_groundtruth(bad)
