"""The tracking node publishes class-agnostic movers (Dai et al.): ~/moving_objects and their markers.

In-process: 120 frames of the simulator's unknown_mover (320x240 at 15 fps: the box rests on the table for
3 s, then is picked up and carried in front of a nearly still camera) are published frame by frame to a
tracking node with its in-process backend and `dynamic.movers` on (no detector); each next frame goes out once
the node has taken the last one (lossless). Offline, `changing-slam run` on the same frames and config gives
12 tracks, the longest 51 poses with 1.3 cm RMSE against the box (camera ATE 0.13 cm; `eval.moving_objects` as
of 48b6fd3, 4.6 cm with its earlier alignment); `changing-slam graph` on an mcap of these frames (--lossless
--no-detection) wrote the same 12 tracks (poses equal to 1e-8) into moving_objects.json.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from changing_slam_msgs.msg import MovingObjectArray  # noqa: E402
from changing_slam_ros.eval.moving_objects import camera_alignment, object_errors_m, read_sim_movers  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.moving_objects_file import read_moving_objects  # noqa: E402
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory  # noqa: E402
from changing_slam_ros.nodes import conversions as cv  # noqa: E402
from changing_slam_ros.nodes.tracking_node import TrackingNode  # noqa: E402
from helpers import REPO, spin_until  # noqa: E402

FRAMES, FPS, WIDTH, HEIGHT = 120, 15.0, 320, 240


@pytest.fixture(scope="module")
def unknown_mover(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    out = tmp_path_factory.mktemp("unknown_mover")
    simulate(build_scenario("unknown_mover", 0), out,
             RenderOptions(width=WIDTH, height=HEIGHT, frames=FRAMES, fps=FPS), 0)  # fmt: skip
    return out


def test_tracking_node_publishes_the_carried_box_and_its_trajectory(ros_context, unknown_mover, tmp_path):
    cfg = tmp_path / "movers.yaml"
    cfg.write_text((REPO / "config" / "sim.yaml").read_text() + "\ndynamic:\n  movers:\n    enabled: true\n    min_track_frames: 1\n")
    out = tmp_path / "out"
    reliable = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    tracking = TrackingNode(image_qos=reliable, context=ros_context, parameter_overrides=[
        Parameter("config", value=str(cfg)), Parameter("in_process_backend", value=True),
        Parameter("loop_closing", value=False), Parameter("intrinsics_from", value="camera_info"),
        Parameter("moving_objects_period_s", value=0.0), Parameter("debug_image", value=False),
        Parameter("output_dir", value=str(out)),
    ])  # fmt: skip
    probe = Node("probe", context=ros_context)
    pub_info = probe.create_publisher(CameraInfo, "/camera/rgb/camera_info", reliable)
    pub_rgb = probe.create_publisher(Image, "/camera/rgb/image_color", reliable)
    pub_depth = probe.create_publisher(Image, "/camera/depth/image", reliable)
    movers: list[MovingObjectArray] = []
    markers: list[MarkerArray] = []
    probe.create_subscription(MovingObjectArray, "/tracking/moving_objects", movers.append, 50)
    probe.create_subscription(MarkerArray, "/tracking/moving_object_markers", markers.append, 50)
    executor = SingleThreadedExecutor(context=ros_context)
    for node in (tracking, probe):
        executor.add_node(node)
    spin_until(executor, lambda: pub_rgb.get_subscription_count() > 0 and probe.count_publishers("/tracking/moving_objects") > 0, 10.0)

    source = open_dataset(unknown_mover, "sim")
    for k, frame in enumerate(source):
        pub_info.publish(cv.intrinsics_to_camera_info(frame.camera, frame.stamp_ns, "camera"))
        pub_rgb.publish(cv.rgb_to_image(frame.rgb, frame.stamp_ns, "camera"))
        pub_depth.publish(cv.depth_to_image(frame.depth_m, frame.stamp_ns, "camera"))
        assert spin_until(executor, lambda k=k: tracking.frames_in > k, 30.0), f"frame {k} not taken"
    spin_until(executor, lambda: False, 0.3)
    assert tracking.frames_in == FRAMES and tracking.published_poses == FRAMES

    # The last message: the longest track is the box, near its ground truth (camera-aligned like the offline test).
    assert movers and markers and tracking.movers_out.published >= 10
    tracks = cv.moving_objects_from_msg(movers[-1])
    track, points = max(tracks, key=lambda tp: len(tp[0].stamps_ns))
    assert len(track.stamps_ns) >= 40 and len(points) == track.n_points >= 50
    assert movers[-1].header.frame_id == "map" and movers[-1].objects[0].trajectory.header.frame_id == "map"
    truth = read_sim_movers(unknown_mover)[0]
    tracking.destroy_node()  # writes the outputs
    S, camera_ate = camera_alignment(source.groundtruth, read_tum_trajectory(out / "trajectory_online.txt"))
    assert camera_ate < 0.01
    err = object_errors_m(track, S, truth)
    assert len(err) >= 40 and float(np.sqrt(np.mean(err**2))) < 0.04
    # The box moved: its trajectory spans more than its error.
    positions = track.T_world_obj[:, :3, 3]
    assert np.linalg.norm(positions.max(axis=0) - positions.min(axis=0)) > 0.2

    # Markers: a line strip through the same positions.
    strips = [m for m in markers[-1].markers if m.type == Marker.LINE_STRIP and m.id == track.object_id]
    assert len(strips) == 1 and len(strips[0].points) == len(track.stamps_ns)
    assert strips[0].points[-1].x == pytest.approx(positions[-1, 0])

    # moving_objects.json in output_dir holds the same tracks.
    on_disk = {t.object_id: t for t in read_moving_objects(out / "moving_objects.json")}
    assert len(on_disk[track.object_id].stamps_ns) == len(track.stamps_ns)
    assert json.loads((out / "tracking_stats.json").read_text())["moving_objects_messages"] >= 10
    probe.destroy_node()
