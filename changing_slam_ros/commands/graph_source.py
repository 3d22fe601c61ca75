"""The bag `changing-slam graph` plays: what it holds, the player's parameters, and where a restarted player
resumes (its last progress line: the pass and the position in the bag it had published up to)."""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass
from typing import Any

from changing_slam_ros.errors import ConfigError

ACK_TOPIC = "/bag_player/ack"
CAMERA_INFO_TOPIC = "/camera/rgb/camera_info"
PLAYER_FIRST_MESSAGE = "bag_player: played 1/"  # the player's log line when its first message is out
# io/playback.py's progress line: the pass (1-based, absent in the first) and seconds from the pass's start
PLAYER_POSITION = re.compile(r"bag_player: (?:pass (\d+): )?played \d+/\d+ messages, ([0-9.]+)/[0-9.]+ s of the bag")
RESUME_MARGIN_S = 0.01  # the progress line rounds to 10 ms: a little earlier, so no message is skipped


@dataclass(frozen=True)
class BagInfo:
    colour_topic: str
    compressed: bool
    colour_frames: int
    duration_s: float
    sensor_topics: tuple[str, ...] = ()  # colour, depth, camera_info as the bag has them (tracking reads all)


def inspect_bag(path: str) -> BagInfo:
    """Which colour topic the bag has (raw or compressed TUM names) and how many frames."""
    from changing_slam_ros.io.bag_messages import BagMessages

    with BagMessages(path) as bag:
        topics = bag.topics
        duration_s = (bag.end_ns - bag.start_ns) / 1e9
    sensors = ("/camera/depth/image", "/camera/depth/image/compressed", "/camera/depth/image/compressedDepth",
               CAMERA_INFO_TOPIC)
    for name, compressed in (("/camera/rgb/image_color", False), ("/camera/rgb/image_color/compressed", True)):
        if name in topics:
            return BagInfo(name, compressed, topics[name].msgcount, duration_s,
                           (name, *(t for t in sensors if t in topics)))
    raise ConfigError(f"{path}: no /camera/rgb/image_color[/compressed] topic (has {', '.join(sorted(topics))})")


def player_params(args: argparse.Namespace, bag: str, info: BagInfo, detection: bool) -> dict[str, Any]:
    """bag_player's parameters: subscribers waited for (tracking, and detection when it runs), lossless acks, and
    `--loop N` as N passes, each later by the bag's duration."""
    params = {"bag": bag, "rate": float(args.rate), "lossless": bool(args.lossless), "ack_topic": ACK_TOPIC,
              "ack_topics": [info.colour_topic], "ack_timeout_s": 120.0, "wait_subscribers_timeout_s": 300.0,
              "wait_for_topics": list(info.sensor_topics or (info.colour_topic,)),
              "min_subscribers": 2 if detection else 1, "wait_subscribers": True, "dds_ack_wait": False}  # fmt: skip
    if args.lossless and CAMERA_INFO_TOPIC in info.sensor_topics:
        # camera_info's own writer can be matched after the images' (volatile: lost intrinsics); tracking
        # confirms each camera_info on the ack topic, and the player re-sends it until one is confirmed
        params["confirm_topics"] = [CAMERA_INFO_TOPIC]
    if args.loop > 1:
        params.update(loop=True, loop_passes=int(args.loop))
    return params


@dataclass(frozen=True)
class ResumePoint:
    """Where a player starts: the pass (0-based) and seconds from the pass's start (the bag's first message)."""

    first_pass: int = 0
    resume_at_s: float = 0.0

    def params(self) -> dict[str, Any]:
        return {"first_pass": self.first_pass, "resume_at_s": self.resume_at_s}


def resume_point(player_log: str, previous: ResumePoint) -> ResumePoint:
    """Where a player that was killed picks up: at the position of its last progress line, a message it had
    published (the ones after it, and the few before within the line's rounding, are sent again; tracking drops
    the stamps it already has), or where the killed player itself started when it logged no position."""
    found = PLAYER_POSITION.findall(player_log)
    if not found:
        return previous
    pass_text, at_s = found[-1]
    return ResumePoint(int(pass_text) - 1 if pass_text else 0, max(float(at_s) - RESUME_MARGIN_S, 0.0))
