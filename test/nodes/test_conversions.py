"""Message <-> core round trips (nodes/conversions.py), through real CDR serialisation."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

import cv2  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from changing_slam_msgs.msg import DetectionArray, Keyframe as KeyframeMsg, LoopCorrection as LoopMsg  # noqa: E402
from changing_slam_ros.core.geometry.camera import CameraIntrinsics  # noqa: E402
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet  # noqa: E402
from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion, ObjectState  # noqa: E402
from changing_slam_ros.core.map.keyframe import Keyframe  # noqa: E402
from changing_slam_ros.core.slam.loop_closing import LoopCorrection  # noqa: E402
from changing_slam_ros.core.geometry.se3 import make_pose  # noqa: E402
from changing_slam_ros.errors import BagError  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402

FR1 = CameraIntrinsics(640, 480, 517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633))


def wire(msg):  # noqa: ANN001, ANN201
    """Serialise and deserialise, as a message crossing a topic does."""
    return deserialize_message(serialize_message(msg), type(msg))


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    x, y, z, w = q
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    return make_pose(r, rng.normal(size=3) * 3.0)


def test_pose_matrix_round_trip_is_exact_to_1e12():
    rng = np.random.default_rng(3)
    for _ in range(50):
        T = random_pose(rng)
        np.testing.assert_allclose(cv.pose_to_matrix(wire(cv.matrix_to_pose(T))), T, atol=1e-12)
    t = cv.matrix_to_transform(T)
    assert t.translation.x == pytest.approx(T[0, 3]) and t.rotation.w == pytest.approx(cv.matrix_to_pose(T).orientation.w)


def test_stamps_keep_every_nanosecond():
    for ns in (0, 1305031102_175304000, 1305031102_999999999):
        assert cv.stamp_to_ns(cv.ns_to_stamp(ns)) == ns


def test_keyframe_round_trip_keeps_every_array_and_the_camera():
    rng = np.random.default_rng(7)
    n = 1000
    kf = Keyframe(
        id=17, stamp_ns=1305031102_211214000, T_world_cam=random_pose(rng), camera=FR1,
        keypoints_px=rng.uniform(0, 640, size=(n, 2)).astype(np.float32),
        octaves=rng.integers(0, 8, n).astype(np.int8),
        descriptors=rng.integers(0, 256, size=(n, 32)).astype(np.uint8),
        depths_m=rng.uniform(0.3, 5.0, n).astype(np.float32),
        point_ids=rng.integers(-1, 10**12, n).astype(np.int64),
        kp_classes=rng.integers(0, 4, n).astype(np.int8),
        object_ids=rng.integers(-1, 50, n).astype(np.int64), map_id=2,
    )  # fmt: skip
    back = cv.keyframe_from_msg(wire(cv.keyframe_to_msg(kf, "map")))
    assert (back.id, back.stamp_ns, back.map_id, len(back)) == (17, kf.stamp_ns, 2, n)
    np.testing.assert_allclose(back.T_world_cam, kf.T_world_cam, atol=1e-12)
    for name in ("keypoints_px", "octaves", "descriptors", "depths_m", "point_ids", "kp_classes", "object_ids"):
        a, b = getattr(back, name), getattr(kf, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert back.camera == FR1


def test_a_keyframe_with_inconsistent_arrays_is_rejected_naming_the_field():
    msg = KeyframeMsg(id=4)
    msg.keypoints = [1.0, 2.0, 3.0, 4.0]  # two keypoints
    msg.octaves = [0]  # one
    with pytest.raises(BagError, match="keyframe 4: per-keypoint arrays disagree .*octaves 1"):
        cv.keyframe_from_msg(msg, "/keyframes")


def test_detections_round_trip_as_xywh_boxes_with_the_image_stamp():
    ds = DetectionSet(1305031102_243211000, (Detection((10.5, 20.0, 110.5, 220.0), 0, 0.91),
                                             Detection((300.0, 50.0, 420.0, 130.0), 56, 0.4)), 640, 480)  # fmt: skip
    msg = wire(cv.detections_to_msg(ds, "openni_rgb_optical_frame"))
    assert isinstance(msg, DetectionArray) and msg.detections[0].w == pytest.approx(100.0)
    back = cv.detections_from_msg(msg)
    assert back.stamp_ns == ds.stamp_ns and (back.width, back.height) == (640, 480)
    np.testing.assert_allclose(back.boxes_xyxy(), ds.boxes_xyxy(), atol=1e-4)  # float32 on the wire
    assert back.class_ids().tolist() == [0, 56]
    np.testing.assert_allclose(back.scores(), [0.91, 0.4], atol=1e-6)


def test_fr1_images_and_camera_info_round_trip_in_metres_and_pixels():
    root = require(FR1_XYZ_10)
    rgb = np.ascontiguousarray(cv2.imread(str(next((root / "rgb").glob("*.png"))))[:, :, ::-1])
    depth_png = cv2.imread(str(next((root / "depth").glob("*.png"))), cv2.IMREAD_UNCHANGED)
    depth_m = depth_png.astype(np.float32) / 5000.0
    back_rgb = cv.image_to_rgb(wire(cv.rgb_to_image(rgb, 5, "cam", "bgr8")))
    np.testing.assert_array_equal(back_rgb, rgb)
    for encoding, tol in (("32FC1", 0.0), ("16UC1", 0.0005)):  # 16UC1 rounds to millimetres
        back = cv.image_to_depth_m(wire(cv.depth_to_image(depth_m, 5, "cam", encoding)))
        assert back.dtype == np.float32 and np.abs(back - depth_m).max() <= tol + 1e-7
    info = wire(cv.intrinsics_to_camera_info(FR1, 5, "cam"))
    assert cv.camera_info_to_intrinsics(info) == FR1


def test_a_malformed_image_is_a_one_line_error_naming_the_topic():
    bad = Image(height=480, width=640, encoding="rgb8", step=1920)
    bad.data = bytes(100)
    with pytest.raises(BagError, match="/camera/rgb/image_color"):
        cv.image_to_rgb(bad, "/camera/rgb/image_color")


def test_object_state_message_carries_position_velocity_and_covariance():
    cov = np.diag([0.01, 0.02, 0.03, 0.1, 0.2, 0.3])
    state = ObjectState(5, 0, (0.0, 0.0, 10.0, 10.0), np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.0, 0.0]), 0.5,
                        ObjectMotion.DYNAMIC, 4, False, cov)  # fmt: skip
    msg = wire(cv.object_states_to_msg([state], 7, "map")).objects[0]
    assert (msg.id, msg.class_id, msg.class_name, msg.is_dynamic) == (5, 0, "person", True)
    assert (msg.position.z, msg.velocity.x) == (3.0, 0.5)
    np.testing.assert_array_equal(np.asarray(msg.covariance).reshape(6, 6), cov)


def test_loop_correction_round_trip_and_pose_corrections_from_the_receivers_old_poses():
    rng = np.random.default_rng(11)
    new = {i: random_pose(rng) for i in (0, 3, 9)}
    old = {i: random_pose(rng) for i in (0, 3, 9)}
    lc = LoopCorrection(
        query_kf_id=9, match_kf_id=0, map_id=1, T_match_query=random_pose(rng), num_inliers=140,
        keypoint_matches=np.zeros((0, 2), np.int64), corrected_poses=new,
        corrected_points={100: np.array([1.0, 2.0, 3.0]), 7: np.array([-1.0, 0.5, 2.0])},
        fused_points=[(100, 7)], pose_corrections={},
    )  # fmt: skip
    msg = wire(cv.loop_correction_to_msg(lc, 11, "map"))
    assert isinstance(msg, LoopMsg)
    back = cv.loop_correction_from_msg(msg, old_poses=old)
    assert (back.query_kf_id, back.match_kf_id, back.map_id, back.num_inliers) == (9, 0, 1, 140)
    np.testing.assert_allclose(back.T_match_query, lc.T_match_query, atol=1e-12)
    for i in new:
        np.testing.assert_allclose(back.corrected_poses[i], new[i], atol=1e-12)
        np.testing.assert_allclose(back.pose_corrections[i] @ old[i], new[i], atol=1e-9)
    np.testing.assert_array_equal(back.corrected_points[7], [-1.0, 0.5, 2.0])
    assert back.fused_points == [(100, 7)]
