"""`changing-slam graph --live`: which topics it listens to, the one-line errors of options that cannot hold, and
what it gives the nodes (no player, sensor-data QoS, remapped topics) — no process starts."""

from __future__ import annotations

import argparse

import pytest

from changing_slam_ros.commands.graph import add_arguments
from changing_slam_ros.commands.graph_live import LiveGraph, resolve_live_topics
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.dataset_config import REALSENSE_JAZZY_TOPICS, TUM_TOPICS, DatasetConfig, TopicSet


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(list(argv))


def test_presets_config_and_single_topics() -> None:
    live = resolve_live_topics(_args("--live", "--out", "x"), None)
    assert live.preset == "realsense_jazzy" and live.topics == REALSENSE_JAZZY_TOPICS
    assert REALSENSE_JAZZY_TOPICS == TopicSet("/camera/camera/color/image_raw",
                                              "/camera/camera/aligned_depth_to_color/image_raw",
                                              "/camera/camera/color/camera_info")  # fmt: skip
    assert resolve_live_topics(_args("--live", "--out", "x"), DatasetConfig(topic_preset="tum")).topics == TUM_TOPICS
    # --topics wins over the config; a colour topic brings its camera_info along
    live = resolve_live_topics(_args("--live", "--out", "x", "--topics", "tum", "--colour-topic", "/cam/rgb/image_raw"),
                               DatasetConfig(topic_preset="realsense"))  # fmt: skip
    assert live.topics == TopicSet("/cam/rgb/image_raw", TUM_TOPICS.depth, "/cam/rgb/camera_info")
    live = resolve_live_topics(_args("--live", "--out", "x", "--colour-topic", "/a/image", "--depth-topic", "/b/depth",
                                     "--camera-info-topic", "/a/info"), None)  # fmt: skip
    assert live.preset == "explicit" and live.topics == TopicSet("/a/image", "/b/depth", "/a/info")


@pytest.mark.parametrize(("argv", "message"), [
    (["bag.mcap", "--live"], "--live with BAG bag.mcap: give one or the other"),
    (["--live", "--lossless"], "--live with --lossless"),
    (["--live", "--rate", "2"], "--live with --rate 2.0"),
    (["--live", "--duration", "0"], "--duration 0.0: expected seconds > 0"),
    (["--live", "--colour-topic", "camera/image"], "--colour-topic 'camera/image': expected an absolute topic name"),
    (["--live", "--depth-topic", "/d/compressedDepth"], "--depth-topic /d/compressedDepth: --live takes raw"),
    (["bag.mcap", "--topics", "tum", "--duration", "3"], "--topics, --duration: only with --live"),
    ([], "no BAG given: name a bag to replay, or --live"),
])  # fmt: skip
def test_bad_options_are_one_line_errors(tmp_path, argv, message) -> None:
    from changing_slam_ros.commands.graph import Graph

    args = _args(*argv, "--out", str(tmp_path / "out"), "--config", "sim")
    with pytest.raises(ConfigError) as err:
        (LiveGraph if args.live else Graph)(args)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()


def test_live_graph_has_no_player_and_listens_best_effort_on_the_driver_topics(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    graph = LiveGraph(_args("--live", "--out", str(tmp_path / "out"), "--config", "realsense_d435", "--no-detection",
                            "--duration", "5"))  # fmt: skip
    try:
        assert graph.player is None and graph.bag == "" and graph.env["ROS_DOMAIN_ID"] == "0"
        argv = " ".join(graph.nodes["tracking"].argv)
        assert "reliable_images:=false" in argv  # sensor-data QoS, as the driver publishes
        for node_topic, live_topic in (("/camera/rgb/image_color", REALSENSE_JAZZY_TOPICS.rgb),
                                       ("/camera/depth/image", REALSENSE_JAZZY_TOPICS.depth),
                                       ("/camera/rgb/camera_info", REALSENSE_JAZZY_TOPICS.camera_info)):  # fmt: skip
            assert f"-r {node_topic}:={live_topic}" in argv
        assert graph._source_summary()["live"]["preset"] == "realsense_jazzy"  # the config's topic_preset
    finally:
        graph.out_dir.abandon()
