"""What `changing-slam graph` starts its nodes with in real time and in lossless mode (no process is started).

Real time, where the graph's six processes share the cores: the detector gets one onnxruntime thread (~10 % less
CPU per detection) and the static INT8 SSD (~0.4x the fp32 CPU per detection), and local_mapping the numpy Schur-complement BA solver (~0.35x gtsam's solver CPU, same cost);
lossless keeps the config's (gtsam), so that the graph repeats `changing-slam run` byte for byte."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from changing_slam_ros.commands.graph import Graph, add_arguments

REPO = Path(__file__).resolve().parents[2]


def _param(tmp_path: Path, node: str, name: str, *extra: str) -> str:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    bag = REPO / "bags" / "sim_walking_changing.mcap"
    if not bag.is_file():
        pytest.skip(f"{bag} missing")
    graph = Graph(parser.parse_args([str(bag), "--out", str(tmp_path), "--config", "sim", *extra]))
    return next(a.split(":=", 1)[1] for a in graph.nodes[node].argv if a.startswith(f"{name}:="))


def test_real_time_gives_the_detector_one_thread_and_lossless_the_configs(tmp_path: Path) -> None:
    assert _param(tmp_path / "rt", "detection", "intra_op_threads") == "1"
    assert _param(tmp_path / "ll", "detection", "intra_op_threads", "--lossless") == "-1"
    assert _param(tmp_path / "two", "detection", "intra_op_threads", "--detector-threads", "2") == "2"


def test_real_time_maps_with_the_schur_solver_and_lossless_with_the_configs(tmp_path: Path) -> None:
    assert _param(tmp_path / "rt", "local_mapping", "ba_solver") == "'schur'"
    assert _param(tmp_path / "ll", "local_mapping", "ba_solver", "--lossless") == "''"
    assert _param(tmp_path / "g", "local_mapping", "ba_solver", "--ba-solver", "gtsam") == "'gtsam'"


def test_real_time_detects_with_the_int8_ssd_and_lossless_with_the_configs(tmp_path: Path) -> None:
    from changing_slam_ros.errors import ConfigError

    assert _param(tmp_path / "rt", "detection", "model") == "'ssd_mobilenet_v2_coco_int8'"
    assert _param(tmp_path / "ll", "detection", "model", "--lossless") == "''"
    assert _param(tmp_path / "c", "detection", "model", "--detector-model", "config") == "''"
    assert _param(tmp_path / "f", "detection", "model", "--detector-model", "ssd_mobilenet_v2_coco") == "'ssd_mobilenet_v2_coco'"
    with pytest.raises(ConfigError, match="--detector-model yolo9: not a shipped detector"):
        _param(tmp_path / "bad", "detection", "model", "--detector-model", "yolo9")


def test_real_time_caps_detection_at_15_hz_and_lossless_refuses_a_cap(tmp_path: Path) -> None:
    from changing_slam_ros.errors import ConfigError

    assert _param(tmp_path / "rt", "detection", "max_rate_hz") == "15.0"
    assert _param(tmp_path / "rt0", "detection", "max_rate_hz", "--detection-max-hz", "0") == "0.0"
    assert _param(tmp_path / "rt10", "detection", "max_rate_hz", "--detection-max-hz", "10") == "10.0"
    assert _param(tmp_path / "ll", "detection", "max_rate_hz", "--lossless") == "0.0"
    with pytest.raises(ConfigError, match="--detection-max-hz 15.0: must be >= 0, and 0 with --lossless"):
        _param(tmp_path / "bad", "detection", "max_rate_hz", "--lossless", "--detection-max-hz", "15")


def test_real_time_tracking_waits_50_ms_for_a_detected_frames_boxes_and_lossless_10_s(tmp_path: Path) -> None:
    """The detector announces the frames its cap skips, so only the detected ones wait for their own boxes."""
    assert _param(tmp_path / "rt", "tracking", "detections_wait_s") == "0.05"
    assert _param(tmp_path / "rt0", "tracking", "detections_wait_s", "--detections-wait", "0") == "0.0"
    assert _param(tmp_path / "ll", "tracking", "detections_wait_s", "--lossless") == "10.0"


def test_tracking_gets_two_frames_queued_by_the_middleware_while_busy(tmp_path: Path) -> None:
    """With one, a loaded machine loses 6-11 % of the frames in the middleware (266-272 of 300 poses with two CPU
    burners and a queue of one, 297 with two)."""
    assert _param(tmp_path / "rt", "tracking", "image_queue_depth") == "2"
    assert _param(tmp_path / "q1", "tracking", "image_queue_depth", "--queue-depth", "1") == "1"
