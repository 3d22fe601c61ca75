"""The tracking node's REP-105 TF (nodes/tracking_tf.py, nodes/tf_buffer.py): with the robot's own odometry on
/tf (odom_source tf) and with visual odometry, in-process on the bundled fr1 bag; holding map -> odom while lost."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from geometry_msgs.msg import PoseStamped, TransformStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from changing_slam_ros.core.geometry.se3 import invert, make_pose  # noqa: E402
from changing_slam_ros.core.geometry.transform_tree import TransformTree  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.core.geometry.trajectory import Trajectory  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402
from changing_slam_ros.nodes.tf_buffer import TF_STATIC_QOS, transform_to_matrix  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from changing_slam_ros.nodes.tracking_tf import Rep105Outputs  # noqa: E402
from helpers import REPO, lossless_player, require, spin_until  # noqa: E402

# The camera (optical frame: z forward, x right, y down) 0.2 m ahead of the base and 0.5 m up, looking along
# the base's x axis (base: x forward, y left, z up).
T_BASE_CAM = make_pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.array([0.2, 0.0, 0.5]))


def rot_z(rad: float) -> np.ndarray:
    return np.array([[np.cos(rad), -np.sin(rad), 0.0], [np.sin(rad), np.cos(rad), 0.0], [0.0, 0.0, 1.0]])


def tf_msg(parent: str, child: str, stamp_ns: int, T: np.ndarray) -> TransformStamped:  # noqa: N803
    t = TransformStamped(header=cv.make_header(stamp_ns, parent), child_frame_id=child)
    t.transform = cv.matrix_to_transform(T)
    return t


def run_graph(ros_context, params, robot_setup):  # noqa: ANN001, ANN201
    """The fr1 bag through tracking with a `robot` node set up by `robot_setup(robot)`; returns what came out."""
    bag = require(REPO / "bags" / "tum_fr1_xyz_first10.mcap")
    tracking = TrackingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="tum_fr1"), Parameter("ack_topic", value="/bag_player/ack"),
        Parameter("in_process_backend", value=True), Parameter("camera_frame", value="camera_link"),
        Parameter("base_frame", value="base_link"), *params,
    ])  # fmt: skip
    player = lossless_player(ros_context, bag)
    robot = Node("robot", context=ros_context)
    got: dict[str, list] = {"tf": [], "static": [], "pose": [], "odom": []}
    robot.create_subscription(TFMessage, "/tf", got["tf"].append, 1000)
    robot.create_subscription(TFMessage, "/tf_static", got["static"].append, TF_STATIC_QOS)
    robot.create_subscription(PoseStamped, "/tracking/pose", got["pose"].append, 100)
    robot.create_subscription(Odometry, "/tracking/odometry", got["odom"].append, 100)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, robot, player):
        executor.add_node(node)
    robot_setup(robot)
    assert spin_until(executor, lambda: tracking.poses_out.odom_pub.get_subscription_count() > 0)
    spin_until(executor, lambda: False, 0.3)  # /tf and /tf_static delivered before the first image
    result = player.play(executor)
    assert result.completed and result.ack_timeouts == 0
    spin_until(executor, lambda: len(got["pose"]) >= 9 and len(got["odom"]) >= 9, 5.0)
    spin_until(executor, lambda: False, 0.3)
    gt = open_dataset(bag, "tum_fr1").groundtruth
    executor.shutdown()
    return tracking, got, gt, (player, robot)


def tree_of(got) -> TransformTree:  # noqa: ANN001
    tree = TransformTree()
    for static, msgs in ((True, got["static"]), (False, got["tf"])):
        for m in msgs:
            for t in m.transforms:
                tree.set_transform(t.header.frame_id, t.child_frame_id, cv.stamp_to_ns(t.header.stamp),
                                   transform_to_matrix(t.transform), static=static)  # fmt: skip
    return tree


def test_with_the_robots_odometry_tracking_publishes_only_map_to_odom_and_tf_composes_to_the_slam_pose(ros_context):
    """A base publishing odom -> base_link from the ground truth plus drift (2 cm/s along x, 1 deg/s of yaw)
    and base_link -> camera_link on /tf_static; its odometry stops after 0.35 s of the 0.59 s, so the last
    frames wait tf_timeout_s and keep the last map -> odom."""
    def robot_setup(robot: Node) -> None:
        bag = REPO / "bags" / "tum_fr1_xyz_first10.mcap"
        gt = open_dataset(bag, "tum_fr1").groundtruth
        static = robot.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
        static.publish(TFMessage(transforms=[tf_msg("base_link", "camera_link", 0, T_BASE_CAM)]))
        pub = robot.create_publisher(TFMessage, "/tf", 100)
        t0 = gt.stamps_s[0]
        robot.odom_end_s = gt.stamps_s[0] + 0.35  # type: ignore[attr-defined]
        for t, T_world_cam in zip(gt.stamps_s, gt.poses(), strict=True):
            if t > robot.odom_end_s:  # type: ignore[attr-defined]
                break
            drift = make_pose(rot_z(np.deg2rad(1.0) * (t - t0)), np.array([0.02 * (t - t0), 0.0, 0.0]))
            pub.publish(TFMessage(transforms=[tf_msg("odom", "base_link", round(t * 1e9),
                                                     drift @ T_world_cam @ invert(T_BASE_CAM))]))  # fmt: skip

    tracking, got, gt, others = run_graph(ros_context, [Parameter("odom_source", value="tf"),
                                                        Parameter("tf_timeout_s", value=0.05)], robot_setup)  # fmt: skip
    assert tracking.frames_out.tf is not None and tracking.frames_out.tf.kind in ("own", "tf2_ros")
    poses = got["pose"]
    assert len(poses) == 9
    # One parent per frame: tracking sent map -> odom only, the robot odom -> base_link and base_link -> camera_link.
    parents: dict[str, set[str]] = {}
    for m in got["tf"] + got["static"]:
        for t in m.transforms:
            parents.setdefault(t.child_frame_id, set()).add(t.header.frame_id)
    assert parents == {"odom": {"map"}, "base_link": {"odom"}, "camera_link": {"base_link"}}
    # map -> base_link through TF equals the SLAM pose of the base at every pose stamp whose odometry came.
    tree = tree_of(got)
    odom_end_ns = round((gt.stamps_s[gt.stamps_s <= gt.stamps_s[0] + 0.35][-1]) * 1e9)
    on_time = [p for p in poses if cv.stamp_to_ns(p.header.stamp) <= odom_end_ns]
    late = [p for p in poses if cv.stamp_to_ns(p.header.stamp) > odom_end_ns]
    assert len(on_time) >= 4 and len(late) >= 2
    worst = 0.0
    for p in on_time:
        T_tf = tree.lookup("map", "base_link", cv.stamp_to_ns(p.header.stamp))  # noqa: N806
        T_slam = cv.pose_to_matrix(p.pose)  # noqa: N806
        worst = max(worst, float(np.linalg.norm(T_tf[:3, 3] - T_slam[:3, 3])), float(np.abs(T_tf[:3, :3] - T_slam[:3, :3]).max()))
    assert worst < 1e-3  # measured: 2e-15 (6 stamps with odometry, 3 without)
    assert tracking.frames_out.odom_timeouts == len(late)
    # The base poses track the base's ground truth (aligned): the camera ATE of the node test, seen from the base.
    stamps = np.array([cv.stamp_to_ns(p.header.stamp) * 1e-9 for p in poses])
    est = Trajectory.from_poses(stamps, np.array([cv.pose_to_matrix(p.pose) @ T_BASE_CAM for p in poses]))
    assert ate(gt, est).stats.rmse < 0.01
    # Odometry: the base's pose with the covariance from the inliers (0.01 m, 0.01 rad at 100 inliers).
    odom = got["odom"][-1]
    assert odom.child_frame_id == "base_link" and odom.header.frame_id == "map"
    cov = np.array(odom.pose.covariance).reshape(6, 6)
    assert np.count_nonzero(cov) == 6 and 1e-6 < cov[0, 0] < 1e-4 and cov[0, 0] == cov[5, 5]
    values = tracking.diagnostic_values()
    assert values["tracking_state"] == "OK" and values["odom_source"] == "tf" and values["map_odom_jumps"] == 0
    tracking.destroy_node()
    for n in others:
        n.destroy_node()


def test_with_visual_odometry_map_to_odom_is_identity_and_odom_to_base_is_the_base_pose(ros_context):
    def robot_setup(robot: Node) -> None:
        static = robot.create_publisher(TFMessage, "/tf_static", TF_STATIC_QOS)
        static.publish(TFMessage(transforms=[tf_msg("base_link", "camera_link", 0, T_BASE_CAM)]))

    tracking, got, gt, others = run_graph(ros_context, [], robot_setup)
    poses = got["pose"]
    assert len(poses) == 9
    ours = [m for m in got["tf"] if m.transforms[0].header.frame_id == "map"]
    assert len(ours) == 9
    assert all([(t.header.frame_id, t.child_frame_id) for t in m.transforms] == [("map", "odom"), ("odom", "base_link")]
               for m in ours)  # fmt: skip
    tree = tree_of(got)
    for p, m in zip(poses, ours, strict=True):
        assert m.transforms[0].transform.translation.x == 0.0 and m.transforms[0].transform.rotation.w == 1.0
        T_tf = tree.lookup("map", "base_link", cv.stamp_to_ns(p.header.stamp))  # noqa: N806
        assert np.abs(T_tf - cv.pose_to_matrix(p.pose)).max() < 1e-6
    # The map is the base's frame at the first frame (z up with the base), not the first camera's optical frame:
    # the first base pose is the map origin, and the first camera pose is the mounting.
    np.testing.assert_allclose(cv.pose_to_matrix(poses[0].pose), np.eye(4), atol=1e-9)
    first_kf = tracking.backend.system.atlas.current.keyframes[0]
    np.testing.assert_allclose(first_kf.T_world_cam, T_BASE_CAM, atol=1e-9)
    tracking.destroy_node()
    for n in others:
        n.destroy_node()


def test_while_lost_the_last_map_to_odom_goes_on_and_relocalisation_jumps_only_map_to_odom(ros_context):
    node = Node("tracking", context=ros_context)
    sent: list[TFMessage] = []
    out = Rep105Outputs(node, {"odom_source": "visual", "map_frame": "map", "odom_frame": "odom",
                               "camera_frame": "camera", "base_frame": "", "tf_timeout_s": 0.1, "tf_cache_s": 10.0,
                               "publish_tf": True})  # fmt: skip
    out._send = lambda stamp_ns, edges: sent.append((stamp_ns, [(p, c, T.copy()) for p, c, T in edges]))  # type: ignore[method-assign]
    step = make_pose(np.eye(3), np.array([0.0, 0.0, 0.1]))  # 10 cm forward per frame
    T = np.eye(4)  # noqa: N806
    for k in range(3):
        out.on_tracked(k, T, map_moved=False, T_prev_cur_cam=step if k else None)
        T = T @ step  # noqa: N806
    out.on_lost(3)
    out.on_lost(4)
    assert out.tracking == "LOST" and out.n_lost_frames == 2
    from changing_slam_ros.nodes.tracking_stats import _warn_if

    # /diagnostics: the state, and level WARN while lost
    assert _warn_if(out.diagnostic_values()) == "tracking LOST: no pose until relocalisation"
    assert [s for s, _ in sent[3:]] == [3, 4] and all(len(e) == 1 and e[0][1] == "odom" for _, e in sent[3:])
    np.testing.assert_allclose(sent[4][1][0][2], np.eye(4))  # the last map -> odom: still identity
    # Relocalised 1 m to the left of where odometry last was (0.2 m forward): odom -> camera holds, map -> odom jumps.
    reloc = make_pose(np.eye(3), np.array([-1.0, 0.0, 0.5]))
    T_map_pose, child = out.on_tracked(5, reloc, map_moved=False, T_prev_cur_cam=None)  # noqa: N806
    assert out.tracking == "RELOCALISED" and child == "camera" and out.state.jumps == 1
    values = out.diagnostic_values()
    assert values["tracking_state"] == "RELOCALISED" and values["relocalisations"] == 1 and _warn_if(values) is None
    (_, _, T_map_odom), (_, _, T_odom_cam) = sent[-1][1]  # noqa: N806
    np.testing.assert_allclose(T_odom_cam[:3, 3], [0.0, 0.0, 0.2], atol=1e-12)
    np.testing.assert_allclose(T_map_odom[:3, 3], [-1.0, 0.0, 0.3], atol=1e-12)
    np.testing.assert_allclose(T_map_odom @ T_odom_cam, T_map_pose, atol=1e-12)
    out.on_tracked(6, reloc @ step, map_moved=False, T_prev_cur_cam=step)
    assert out.diagnostic_values()["tracking_state"] == "OK" and out.diagnostic_values()["relocalisations"] == 1
    node.destroy_node()
