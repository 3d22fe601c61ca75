"""The changing_slam_ros node graph, for machines with a full ROS 2 install (`ros2 launch` is not on PyPI).

    ros2 launch changing_slam_ros changing_slam.launch.py bag:=bags/tum_fr1_xyz_first10.mcap config:=tum_fr1
    ros2 launch changing_slam_ros changing_slam.launch.py config:=realsense_d435 topics:=realsense_jazzy \
        use_sim_time:=false

Without a bag the graph runs on live topics: `topics` names a preset of the three sensor topics (tum, realsense,
realsense_jazzy: `io.dataset_config.TOPIC_PRESETS`), and colour_topic / depth_topic / camera_info_topic replace
single names of it. The arguments whose default is `auto` take what
`changing-slam graph` gives the nodes (`commands.graph.MODE_DEFAULTS`): its measured real-time settings, or
with lossless:=true the config's, so that the graph repeats `changing-slam run`. Each argument's description
says what it sets; `changing-slam graph BAG` starts the same processes without ROS 2 launch.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from changing_slam_ros.commands.graph import MODE_DEFAULTS
from changing_slam_ros.io.dataset_config import TOPIC_PRESETS

PACKAGE = "changing_slam_ros"


def _auto(name: str, lossless: LaunchConfiguration) -> PythonExpression:
    """Launch argument `name` as given (cast to its default's type), or when it is 'auto' what `changing-slam graph`
    gives the node: `MODE_DEFAULTS[name]` for real time or lossless:=true."""
    real_time, in_lossless = MODE_DEFAULTS[name]
    arg = LaunchConfiguration(name)
    return PythonExpression(["(", repr(in_lossless), " if '", lossless, "' == 'true' else ", repr(real_time), ") if '",
                             arg, "' == 'auto' else ", type(real_time).__name__, "('", arg, "')"])  # fmt: skip


def _topic(name: str, field: str, topics: LaunchConfiguration) -> PythonExpression:
    """Launch argument `name` when given, else the `field` (rgb, depth, camera_info) of the `topics` preset."""
    names = {preset: getattr(t, field) for preset, t in TOPIC_PRESETS.items()}
    return PythonExpression(["'", LaunchConfiguration(name), "' or ", repr(names), "['", topics, "']"])


def generate_launch_description() -> LaunchDescription:
    bag = LaunchConfiguration("bag")
    config = LaunchConfiguration("config")
    rate = LaunchConfiguration("rate")
    lossless = LaunchConfiguration("lossless")
    use_sim_time = LaunchConfiguration("use_sim_time")
    map_file = LaunchConfiguration("map_file")
    map_out = LaunchConfiguration("map_out")
    topics = LaunchConfiguration("topics")
    colour_topic = _topic("colour_topic", "rgb", topics)
    depth_topic = _topic("depth_topic", "depth", topics)
    camera_info_topic = _topic("camera_info_topic", "camera_info", topics)
    base_frame = LaunchConfiguration("base_frame")
    odom_source = LaunchConfiguration("odom_source")
    mode = LaunchConfiguration("mode")
    # 'auto': what `changing-slam graph` gives the node in real time, the config's in lossless mode
    auto = {name: _auto(name, lossless) for name in MODE_DEFAULTS}
    real_time = PythonExpression(["'", lossless, "' != 'true'"])
    frame_policy = PythonExpression(["'all' if '", lossless, "' == 'true' else 'latest'"])
    has_bag = PythonExpression(["'", bag, "' != ''"])
    sim_time = {"use_sim_time": use_sim_time}
    ack_topic = PythonExpression(["'/bag_player/ack' if '", lossless, "' == 'true' else ''"])

    return LaunchDescription([
        DeclareLaunchArgument("bag", default_value="", description="bag or mcap to replay; empty = live input"),
        DeclareLaunchArgument("config", default_value="tum_fr1", description="config name or YAML path"),
        DeclareLaunchArgument("topics", default_value="tum", choices=list(TOPIC_PRESETS),
                              description="sensor topic names: " + "; ".join(
                                  f"{name}: {t.rgb}, {t.depth}, {t.camera_info}" for name, t in TOPIC_PRESETS.items())
                              + " (realsense_jazzy: realsense2_camera's defaults on Jazzy)"),
        DeclareLaunchArgument("colour_topic", default_value="",
                              description="colour image topic (sensor_msgs/Image); empty = the topics preset's"),
        DeclareLaunchArgument("depth_topic", default_value="",
                              description="depth image registered to colour (32FC1 metres or 16UC1 millimetres); "
                                          "empty = the topics preset's"),
        DeclareLaunchArgument("camera_info_topic", default_value="",
                              description="colour camera_info (intrinsics); empty = the topics preset's"),
        DeclareLaunchArgument("base_frame", default_value="",
                              description="robot base frame (base_link): pose, odometry and TF for it; empty = camera"),
        DeclareLaunchArgument("odom_source", default_value="visual",
                              description="visual: tracking publishes odom -> base; tf: the robot does (wheel odometry)"),
        DeclareLaunchArgument("mode", default_value="mapping",
                              description="mapping, or localization in the map_file map (the map is never changed)"),
        DeclareLaunchArgument("rate", default_value="1.0", description="bag playback rate"),
        DeclareLaunchArgument("lossless", default_value="false", description="bag_player waits for tracking"),
        DeclareLaunchArgument("use_sim_time", default_value="true", description="follow /clock from the bag"),
        DeclareLaunchArgument("map_file", default_value="", description="start from this map.npz (multi-session)"),
        DeclareLaunchArgument("map_out", default_value="", description="local_mapping saves the map here at shutdown "
                              "(and on ~/save_map); start the next session from it with map_file"),
        DeclareLaunchArgument("detector_threads", default_value="auto",
                              description="onnxruntime threads of the detection node (-1: the config's; auto: 1 "
                                          "in real time, the config's with lossless)"),
        DeclareLaunchArgument("detector_model", default_value="auto",
                              description="shipped detector of the detection node, e.g. ssd_mobilenet_v2_coco_int8 "
                                          "(empty: the config's; auto: INT8 in real time, the config's with lossless)"),
        DeclareLaunchArgument("detection_max_hz", default_value="auto",
                              description="real time: detect at most this often by image stamp (0: as often as "
                                          "the detector is free; auto: 15 in real time, 0 with lossless)"),
        DeclareLaunchArgument("detections_wait_s", default_value="auto",
                              description="longest wait of tracking for a detected frame's boxes (0: track at "
                                          "once with the earlier boxes carried forward; auto: 0.05 in real time, "
                                          "10 with lossless)"),
        DeclareLaunchArgument("ba_solver", default_value="auto",
                              description="local BA solver of local_mapping: gtsam or schur (empty: the config's; "
                                          "auto: schur in real time, the config's with lossless)"),
        Node(
            package=PACKAGE, executable="bag_player", name="bag_player", output="screen", condition=IfCondition(has_bag),
            parameters=[{"bag": bag, "rate": rate, "lossless": lossless,
                         "ack_topics": ["/camera/rgb/image_color"], "confirm_topics": ["/camera/rgb/camera_info"]}],
        ),
        Node(package=PACKAGE, executable="detection", name="detection", output="screen",
             parameters=[{"config": config, "intra_op_threads": auto["detector_threads"],
                          "model": auto["detector_model"], "max_rate_hz": auto["detection_max_hz"]}, sim_time],
             remappings=[("image", colour_topic)]),
        Node(package=PACKAGE, executable="tracking", name="tracking", output="screen",
             parameters=[{"config": config, "ack_topic": ack_topic, "in_process_backend": False,
                          "wait_for_map_updates": lossless, "map_file": map_file, "frame_policy": frame_policy,
                          "detections_skip_late": real_time,
                          "detections_wait_s": auto["detections_wait_s"], "base_frame": base_frame,
                          "odom_source": odom_source, "mode": mode}, sim_time],
             remappings=[("/camera/rgb/image_color", colour_topic), ("/camera/depth/image", depth_topic),
                         ("/camera/rgb/camera_info", camera_info_topic)]),
        Node(package=PACKAGE, executable="local_mapping", name="local_mapping", output="screen",
             parameters=[{"config": config, "wait_for_loop_results": lossless, "map_file": map_file,
                         "map_out": map_out, "ba_solver": auto["ba_solver"]}, sim_time]),
        Node(package=PACKAGE, executable="loop_closing", name="loop_closing", output="screen",
             parameters=[{"config": config, "map_file": map_file}, sim_time]),
        Node(package=PACKAGE, executable="object_map", name="object_map", output="screen",
             parameters=[{"config": config}, sim_time],
             remappings=[("/tracking/semantic_map", "/local_mapping/semantic_map")]),  # the object layer's map
    ])  # fmt: skip
