"""`changing-slam graph --detector-threads`: what the detection node is started with (no process is started).

Real time: one onnxruntime thread, since the graph's six processes share the cores and one thread costs ~10 % less
CPU per detection (docs/architecture.md, "Session 9: one detector thread in real time"); lossless: the config's
(-1), where the detector's wall time per frame paces the replay."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from changing_slam_ros.commands.graph import Graph, add_arguments

REPO = Path(__file__).resolve().parents[2]


def _detection_threads(tmp_path: Path, *extra: str) -> str:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    bag = REPO / "bags" / "sim_walking_changing.mcap"
    if not bag.is_file():
        pytest.skip(f"{bag} missing")
    graph = Graph(parser.parse_args([str(bag), "--out", str(tmp_path), "--config", "sim", *extra]))
    argv = graph.nodes["detection"].argv
    return next(a.split(":=", 1)[1] for a in argv if a.startswith("intra_op_threads:="))


def test_real_time_gives_the_detector_one_thread_and_lossless_the_configs(tmp_path: Path) -> None:
    assert _detection_threads(tmp_path / "rt") == "1"
    assert _detection_threads(tmp_path / "ll", "--lossless") == "-1"
    assert _detection_threads(tmp_path / "two", "--detector-threads", "2") == "2"
