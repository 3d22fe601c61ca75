"""`changing-slam graph --live --out DIR`: the node graph on a running camera driver's topics, without a bag.

    changing-slam graph --live --out DIR [--config realsense_d435] [--topics realsense_jazzy|realsense|tum]
        [--colour-topic T] [--depth-topic T] [--camera-info-topic T] [--duration S] [graph options]

No bag_player starts: tracking and detection subscribe to the driver's topics with sensor-data QoS (best effort,
as drivers publish), the nodes use wall-clock time (no /clock) and the images' own stamps. The nodes run on the
ROS_DOMAIN_ID of the environment (0 when unset) with its discovery range, so that they see the driver. The run
ends at Ctrl-C (or SIGTERM) or after --duration seconds; DIR then gets what a bag run writes, without the
evaluation against ground truth.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from typing import Any

from changing_slam_ros.commands.graph import BagInfo, Graph
from changing_slam_ros.commands.graph_arguments import check_live_arguments
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.dataset_config import TOPIC_PRESETS, DatasetConfig, TopicSet, sibling_camera_info

DEFAULT_PRESET = "realsense_jazzy"  # when the config's dataset.topic_preset is auto
# The TUM names the nodes subscribe to, remapped to the live topics.
NODE_TOPICS = TopicSet("/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info")


@dataclass(frozen=True)
class LiveTopics:
    """The topics a live run listens to, and the preset they came from (`explicit` when all three were given)."""

    preset: str
    topics: TopicSet

    def as_dict(self) -> dict[str, str]:
        t = self.topics
        return {"preset": self.preset, "colour_topic": t.rgb, "depth_topic": t.depth, "camera_info_topic": t.camera_info}


def resolve_live_topics(args: argparse.Namespace, dataset: DatasetConfig | None) -> LiveTopics:
    """--topics (or the config's topic_preset, or realsense_jazzy) with --colour-topic / --depth-topic /
    --camera-info-topic replacing single names; camera_info beside a given colour topic unless named."""
    preset = args.topics or (dataset.topic_preset if dataset and dataset.topic_preset != "auto" else DEFAULT_PRESET)
    base = TOPIC_PRESETS[preset]
    for option, name in (("--colour-topic", args.colour_topic), ("--depth-topic", args.depth_topic),
                         ("--camera-info-topic", args.camera_info_topic)):  # fmt: skip
        if name and (not name.startswith("/") or " " in name or name.endswith("/")):
            raise ConfigError(f"{option} {name!r}: expected an absolute topic name such as /camera/camera/color/image_raw")
        if name.endswith(("/compressed", "/compressedDepth")):
            raise ConfigError(f"{option} {name}: --live takes raw sensor_msgs/Image topics (the driver's image_raw)")
    info = args.camera_info_topic or (sibling_camera_info(args.colour_topic) if args.colour_topic else base.camera_info)
    topics = TopicSet(args.colour_topic or base.rgb, args.depth_topic or base.depth, info)
    named = all((args.colour_topic, args.depth_topic, args.camera_info_topic))
    return LiveTopics("explicit" if named else preset, topics)


class LiveGraph(Graph):
    """`Graph` without a bag: the nodes listen to live topics until Ctrl-C or --duration."""

    def _open_source(self) -> tuple[str, BagInfo]:
        check_live_arguments(self.args)
        dataset = None
        if self.config:
            from changing_slam_ros.io.dataset_config import load_dataset_settings

            dataset = load_dataset_settings(self.config).dataset
        self.live = resolve_live_topics(self.args, dataset)
        t = self.live.topics
        return "", BagInfo(t.rgb, False, 0, 0.0, (t.rgb, t.depth, t.camera_info))

    def _ros_env(self) -> dict[str, str]:
        """The driver's domain: the environment's ROS_DOMAIN_ID (0 when unset) and discovery range."""
        return {"ROS_DOMAIN_ID": os.environ.get("ROS_DOMAIN_ID") or "0"}

    def _sensor_inputs(self) -> tuple[dict[str, str], bool]:
        t = self.live.topics
        remaps = {NODE_TOPICS.rgb: t.rgb, NODE_TOPICS.depth: t.depth, NODE_TOPICS.camera_info: t.camera_info}
        return remaps, False

    def _play(self, t_play: float, up_s: float) -> None:
        t = self.live.topics
        until = f"for {self.args.duration:.0f} s" if self.args.duration else "until Ctrl-C"
        print(f"graph: {', '.join(self.nodes)} up after {up_s:.1f} s (ROS_DOMAIN_ID {self.env['ROS_DOMAIN_ID']}); "
              f"listening to {t.rgb}, {t.depth}, {t.camera_info} ({self.live.preset}) {until}", flush=True)  # fmt: skip
        try:
            self._supervise(t_play)
        except KeyboardInterrupt:  # Ctrl-C (SIGTERM too) ends a live run: the nodes write their outputs
            if self.progress is not None:
                self.progress.finish()
            print("graph: stopping (Ctrl-C); the nodes write their outputs", flush=True)

    def _playing(self, started_s: float) -> bool:
        return self.args.duration is None or time.monotonic() - started_s < self.args.duration

    def _source_summary(self) -> dict[str, Any]:
        return {"live": self.live.as_dict()}
