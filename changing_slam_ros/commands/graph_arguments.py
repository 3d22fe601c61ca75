"""The options of `changing-slam graph` (`commands/graph.py`): a bag's replay, and the live topics of `--live`."""

from __future__ import annotations

import argparse

from changing_slam_ros.errors import ConfigError

BACKENDS = ("split", "in_process")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="BAG", nargs="?", default="",
                        help="ROS 1 bag, ROS 2 bag folder or mcap file to replay (none with --live)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    parser.add_argument("--config", default="", metavar="NAME|FILE", help="config YAML (as for `changing-slam run`)")
    parser.add_argument("--rate", type=float, default=1.0, metavar="R", help="playback speed factor (default 1)")
    parser.add_argument("--lossless", action="store_true",
                        help="the player waits for tracking's ack of each colour frame (no drops; not real time)")
    parser.add_argument("--detection", action=argparse.BooleanOptionalAction, default=None,
                        help="start the detection node (default: when the config's dynamic filter uses detections)")
    parser.add_argument("--object-map", action=argparse.BooleanOptionalAction, default=True,
                        help="start the object_map node (default on)")
    parser.add_argument("--detections-wait", type=float, default=None, metavar="S",
                        help="longest wait of tracking for a frame's own detections (default 0.05 in real time: the "
                             "frames the detector detects wait for their boxes, ~17 ms with INT8, the ones it skips "
                             "(its rate cap) are tracked at once with the earlier boxes carried forward; 0: never "
                             "wait; lossless 10 s)")
    parser.add_argument("--queue-depth", type=int, default=2, metavar="N",
                        help="colour/depth frames the middleware keeps for tracking while it is busy (default 2; "
                             "real time then tracks them in order while they are within their detection wait and "
                             "drops the older ones past it, frame_policy latest; 1: the middleware keeps the newest only)")
    parser.add_argument("--detector-threads", type=int, default=None, metavar="N",
                        help="onnxruntime threads of the detection node (default: 1 in real time, where the graph's "
                             "six processes share the cores and one thread costs ~10 %% less CPU per detection; "
                             "the config's in --lossless, where the detector's wall time per frame counts; -1: the config's)")
    parser.add_argument("--detector-model", default=None, metavar="NAME",
                        help="shipped detector of the detection node (default: ssd_mobilenet_v2_coco_int8 in real "
                             "time, the static INT8 SSD at ~0.4x the fp32 CPU per detection; the config's in "
                             "--lossless, so that the graph repeats `changing-slam run`; config: the config's)")
    parser.add_argument("--detection-max-hz", type=float, default=None, metavar="HZ",
                        help="real time: the detection node detects at most this often by image stamp (detection "
                             "node max_rate_hz; default 15 in real time: every other frame of a 30 Hz camera, half the INT8 "
                             "detector's CPU at the same 1x ATE; 0 = as often as it is free); not with --lossless, "
                             "where tracking waits for every frame's detections")
    parser.add_argument("--ba-solver", choices=("gtsam", "schur", "config"), default=None,
                        help="local_mapping's local BA solver (default: schur in real time, the numpy Schur-complement "
                             "LM that solves gtsam's problem at ~0.35x the CPU; the config's, gtsam unless set, in "
                             "--lossless, so that the graph repeats `changing-slam run`)")
    parser.add_argument("--max-restarts", type=int, default=2, metavar="N",
                        help="restarts per node (default 2); a node that dies once more, dies twice in a row with "
                             "the same error, or dies while (re)starting stops the graph: every process is stopped "
                             "within 10 s, the node's last log lines and log path are printed, exit 1")
    parser.add_argument("--timeout", type=float, default=900.0, metavar="S", help="give up after S seconds")
    parser.add_argument("--backend", choices=BACKENDS, default="split",
                        help="split: local_mapping and loop_closing in their own processes (default); "
                             "in_process: tracking runs the whole SLAM system")
    parser.add_argument("--map-in", metavar="MAP", default="",
                        help="multi-session: start from a map saved by `changing-slam run` (its DIR/map.npz); "
                             "tracking relocalises in it, poses stay in its frame")
    parser.add_argument("--nice", action="append", default=[], metavar="NODE=N",
                        help="start NODE with its niceness raised by N (repeatable; e.g. local_mapping=5 lets tracking "
                             "and detection take the cores first when they are short; a restart keeps it)")
    parser.add_argument("--kill", action="append", default=[], metavar="NODE@S",
                        help="fault injection: SIGKILL NODE (or bag_player) S seconds after playback starts "
                             "(repeatable); the graph restarts it: the player resumes where it was, a tracking "
                             "restart replays the bag from its start with local_mapping and loop_closing afresh")
    parser.add_argument("--loop", type=int, default=1, metavar="N",
                        help="play the bag N times, each pass later by the bag's duration so time runs forward "
                             "(a soak test; bench/bench_soak.py)")
    parser.add_argument("--load-map", action="append", default=[], metavar="MAP@S",
                        help="multi-session mid-run: S seconds after the player's first message, call local_mapping's LoadMap "
                             "with MAP (a map.npz); tracking and loop_closing follow (repeatable)")
    add_live_arguments(parser)


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    from changing_slam_ros.io.dataset_config import TOPIC_PRESETS

    live = parser.add_argument_group("live camera (no BAG)")
    live.add_argument("--live", action="store_true",
                      help="no bag: the nodes subscribe to a running camera driver's topics (sensor-data QoS, "
                           "wall-clock stamps, no /clock) until Ctrl-C or --duration, then write DIR as a bag run does")
    live.add_argument("--topics", choices=tuple(TOPIC_PRESETS), default=None, metavar="PRESET",
                      help="--live topic names: " + "; ".join(f"{name}: {t.rgb}, {t.depth}, {t.camera_info}"
                                                               for name, t in TOPIC_PRESETS.items())
                           + " (default: the config's dataset.topic_preset, realsense_jazzy when it is auto)")
    live.add_argument("--colour-topic", default="", metavar="TOPIC", help="--live: colour image topic (sensor_msgs/Image, "
                                                                          "rgb8 / bgr8); replaces the preset's")
    live.add_argument("--depth-topic", default="", metavar="TOPIC",
                      help="--live: depth registered to colour (16UC1 mm or 32FC1 m); replaces the preset's")
    live.add_argument("--camera-info-topic", default="", metavar="TOPIC",
                      help="--live: colour camera_info; replaces the preset's (default with --colour-topic: the "
                           "camera_info beside it)")
    live.add_argument("--duration", type=float, default=None, metavar="S",
                      help="--live: stop after S seconds of listening (default: at Ctrl-C)")


def check_live_arguments(args: argparse.Namespace) -> None:
    """Options that mean a bag, or values that cannot hold, as one-line errors before anything starts."""
    if args.bag:
        raise ConfigError(f"--live with BAG {args.bag}: give one or the other (--live listens to a driver's topics)")
    if args.lossless:
        raise ConfigError("--live with --lossless: a camera does not wait for tracking (lossless is for bags)")
    if args.rate != 1.0:
        raise ConfigError(f"--live with --rate {args.rate}: a camera plays at its own rate")
    if args.duration is not None and not args.duration > 0:
        raise ConfigError(f"--duration {args.duration}: expected seconds > 0")


def check_bag_arguments(args: argparse.Namespace) -> None:
    """Live-only options without --live."""
    given = [o for o, v in (("--topics", args.topics), ("--colour-topic", args.colour_topic),
                            ("--depth-topic", args.depth_topic), ("--camera-info-topic", args.camera_info_topic),
                            ("--duration", args.duration)) if v]  # fmt: skip
    if given:
        raise ConfigError(f"{', '.join(given)}: only with --live (a bag's topics are found in the bag)")
    if args.loop < 1:
        raise ConfigError(f"--loop {args.loop}: expected the number of passes, 1 or more")
