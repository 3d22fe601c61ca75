"""The changing_slam_ros node graph, for machines with a full ROS 2 install (`ros2 launch` is not on PyPI).

    ros2 launch changing_slam_ros changing_slam.launch.py bag:=bags/tum_fr1_xyz_first10.mcap config:=tum_fr1

Arguments: bag (empty = no player: live camera), config, rate, lossless (bag_player waits for tracking's
per-frame acks), use_sim_time (default true with a bag: nodes follow bag_player's /clock), map_file (multi-session:
start tracking, local_mapping and loop_closing from a `changing-slam run` map.npz), detector_threads (onnxruntime
threads of the detection node; -1 = the config's; 1 costs ~10 % less CPU per detection where the nodes share few
cores, as `changing-slam graph` does in real time), detector_model (a shipped detector by name, e.g.
ssd_mobilenet_v2_coco_int8, the static INT8 SSD at ~0.4x the CPU that `changing-slam graph` uses in real time;
empty = the config's), detection_max_hz (real time: detect at most this often; 0 = as often as the detector is
free), ba_solver (local BA: gtsam or schur, the numpy
Schur-complement LM at ~0.35x the CPU that `changing-slam graph` uses in real time; empty = the config's). Out of lossless mode tracking
runs as `changing-slam graph` does in real time: the newest frame first (frame_policy latest), each frame the
detector detects waiting at most detections_wait_s (default 0.05 s) for its boxes (the detector announces the frames
it skips, which do not wait), and no waiting while detections keep arriving later than that.
Without ROS 2 launch, `changing-slam graph BAG` (issue 7) starts the same processes.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

PACKAGE = "changing_slam_ros"


def generate_launch_description() -> LaunchDescription:
    bag = LaunchConfiguration("bag")
    config = LaunchConfiguration("config")
    rate = LaunchConfiguration("rate")
    lossless = LaunchConfiguration("lossless")
    use_sim_time = LaunchConfiguration("use_sim_time")
    map_file = LaunchConfiguration("map_file")
    map_out = LaunchConfiguration("map_out")
    detector_threads = LaunchConfiguration("detector_threads")
    ba_solver = LaunchConfiguration("ba_solver")
    detector_model = LaunchConfiguration("detector_model")
    detection_max_hz = LaunchConfiguration("detection_max_hz")
    real_time_wait = LaunchConfiguration("detections_wait_s")
    real_time = PythonExpression(["'", lossless, "' != 'true'"])
    frame_policy = PythonExpression(["'all' if '", lossless, "' == 'true' else 'latest'"])
    has_bag = PythonExpression(["'", bag, "' != ''"])
    sim_time = {"use_sim_time": use_sim_time}
    ack_topic = PythonExpression(["'/bag_player/ack' if '", lossless, "' == 'true' else ''"])
    detections_wait = PythonExpression(["10.0 if '", lossless, "' == 'true' else float('", real_time_wait, "')"])

    return LaunchDescription([
        DeclareLaunchArgument("bag", default_value="", description="bag or mcap to replay; empty = live input"),
        DeclareLaunchArgument("config", default_value="tum_fr1", description="config name or YAML path"),
        DeclareLaunchArgument("rate", default_value="1.0", description="bag playback rate"),
        DeclareLaunchArgument("lossless", default_value="false", description="bag_player waits for tracking"),
        DeclareLaunchArgument("use_sim_time", default_value="true", description="follow /clock from the bag"),
        DeclareLaunchArgument("map_file", default_value="", description="start from this map.npz (multi-session)"),
        DeclareLaunchArgument("map_out", default_value="", description="local_mapping saves the map here at shutdown "
                              "(and on ~/save_map); start the next session from it with map_file"),
        DeclareLaunchArgument("detector_threads", default_value="-1",
                              description="onnxruntime threads of the detection node (-1: the config's)"),
        DeclareLaunchArgument("detector_model", default_value="",
                              description="shipped detector of the detection node, e.g. ssd_mobilenet_v2_coco_int8 "
                                          "(empty: the config's)"),
        DeclareLaunchArgument("detection_max_hz", default_value="0.0",
                              description="real time: detect at most this often by image stamp (0: as often as "
                                          "the detector is free; keep 0 with lossless)"),
        DeclareLaunchArgument("detections_wait_s", default_value="0.05",
                              description="real time: longest wait of tracking for a detected frame's boxes "
                                          "(0: track at once with the earlier boxes carried forward)"),
        DeclareLaunchArgument("ba_solver", default_value="",
                              description="local BA solver of local_mapping: gtsam or schur (empty: the config's)"),
        Node(
            package=PACKAGE, executable="bag_player", name="bag_player", output="screen", condition=IfCondition(has_bag),
            parameters=[{"bag": bag, "rate": rate, "lossless": lossless,
                         "ack_topics": ["/camera/rgb/image_color"], "confirm_topics": ["/camera/rgb/camera_info"]}],
        ),
        Node(package=PACKAGE, executable="detection", name="detection", output="screen",
             parameters=[{"config": config, "intra_op_threads": detector_threads, "model": detector_model,
                         "max_rate_hz": detection_max_hz}, sim_time],
             remappings=[("image", "/camera/rgb/image_color")]),
        Node(package=PACKAGE, executable="tracking", name="tracking", output="screen",
             parameters=[{"config": config, "ack_topic": ack_topic, "in_process_backend": False,
                          "wait_for_map_updates": lossless, "map_file": map_file, "frame_policy": frame_policy,
                          "detections_skip_late": real_time,
                          "detections_wait_s": detections_wait}, sim_time]),
        Node(package=PACKAGE, executable="local_mapping", name="local_mapping", output="screen",
             parameters=[{"config": config, "wait_for_loop_results": lossless, "map_file": map_file,
                         "map_out": map_out, "ba_solver": ba_solver}, sim_time]),
        Node(package=PACKAGE, executable="loop_closing", name="loop_closing", output="screen",
             parameters=[{"config": config, "map_file": map_file}, sim_time]),
        Node(package=PACKAGE, executable="object_map", name="object_map", output="screen",
             parameters=[{"config": config}, sim_time],
             remappings=[("/tracking/semantic_map", "/local_mapping/semantic_map")]),  # the object layer's map
    ])  # fmt: skip
