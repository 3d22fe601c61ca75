"""What `changing-slam graph` makes of a finished run: the nodes' stats files read back, outputs.mcap (the
trajectories, ground truth and moving objects as PoseStamped topics), the ATE against the bag's ground truth, and
the warnings of a run that may not be what it seems (cameras that disagree, no frame tracked)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from changing_slam_ros.commands.graph_process import NodeProcess
from changing_slam_ros.errors import SlamError
from changing_slam_ros.io.camera_check import CameraMismatch, first_keyframe_camera, map_camera_mismatch


def graph_provenance(config: str, args: Any) -> dict[str, Any]:
    """Package version, git commit and the nodes' configuration as resolved (graph_summary.json)."""
    from changing_slam_ros.nodes.slam_backend import load_backend_config
    from changing_slam_ros.provenance import run_provenance

    cfg = load_backend_config(config or "")
    return run_provenance(cfg.data, cfg.where, options=vars(args))


def read_json(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.is_file() else None


def detection_median_ms(node: NodeProcess | None) -> float | None:
    """The last 'median X ms per frame' the detection node logged (every 100 frames), if any."""
    if node is None:
        return None
    import re

    found = re.findall(r"median ([0-9.]+) ms per frame", node.log_text())
    return float(found[-1]) if found else None


def write_outputs_mcap(bag: str, config: str, out: Path) -> str | None:
    """outputs.mcap: /tracking/pose (final), /tracking/pose_online (PoseStamped, `map`) and the bag's ground truth
    (/ground_truth/pose, `world`), written from the trajectory files after the run (not a live recording), so
    that `evo_ape bag2 outputs.mcap /ground_truth/pose /tracking/pose -a` and Foxglove read them."""
    from changing_slam_ros.core.geometry.se3 import rot_to_quat
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.mcap_writer import RgbdMcapWriter
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    final = out / "trajectory.txt"
    if not final.is_file():
        return None
    try:
        gt = open_dataset(bag, config or None).groundtruth if bag else None  # live topics: none
    except SlamError:
        gt = None
    path = out / "outputs.mcap"
    with RgbdMcapWriter(path) as writer:
        t = writer.typestore.types
        for topic, name in (("/tracking/pose", "trajectory.txt"), ("/tracking/pose_online", "trajectory_online.txt")):
            if not (out / name).is_file():
                continue
            traj = read_tum_trajectory(out / name)
            for stamp_s, T in zip(traj.stamps_s, traj.poses(), strict=True):
                stamp_ns = round(float(stamp_s) * 1e9)
                q = rot_to_quat(T[:3, :3])
                sec, nsec = divmod(stamp_ns, 1_000_000_000)
                header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](sec, nsec), "map")
                pose = t["geometry_msgs/msg/Pose"](t["geometry_msgs/msg/Point"](*(float(v) for v in T[:3, 3])),
                                                   t["geometry_msgs/msg/Quaternion"](*(float(v) for v in q)))  # fmt: skip
                writer.write_message(topic, "geometry_msgs/msg/PoseStamped",
                                     t["geometry_msgs/msg/PoseStamped"](header, pose), stamp_ns)  # fmt: skip
        if gt is not None:
            for stamp_s, T in zip(gt.stamps_s, gt.poses(), strict=True):
                writer.write_pose(round(float(stamp_s) * 1e9), T)
        write_mover_topics(writer, out)
    return str(path)


def write_mover_topics(writer: Any, out: Path) -> int:
    """Tracking's moving_objects.json (class-agnostic movers) into the open mcap: every pose of object N as
    /moving_objects/object_N/pose (PoseStamped, `map`; evo reads it), and at the last pose a
    /tracking/moving_objects MovingObjectArray (full trajectories; no points: the file has none) and a
    /tracking/moving_object_markers MarkerArray (line strips), as the tracking node published them last.
    Returns the number of objects (0 without the file)."""
    from rclpy.serialization import serialize_message

    from changing_slam_ros.io.moving_objects_file import INDEX_NAME, read_moving_objects
    from changing_slam_ros.io.msg_types import register_project_types
    from changing_slam_ros.nodes.conversions import make_header, moving_object_markers, moving_objects_to_msg

    index = out / INDEX_NAME
    if not index.is_file():
        return 0
    tracks = [t for t in read_moving_objects(index) if len(t.stamps_ns)]
    if not tracks:
        return 0
    store = writer.typestore
    if "changing_slam_msgs/msg/MovingObjectArray" not in store.fielddefs:
        register_project_types(store)
    pose_type = "geometry_msgs/msg/PoseStamped"
    for track in tracks:
        msg = moving_objects_to_msg([track], {}, make_header(0, "map")).objects[0]
        for pose in msg.trajectory.poses:
            writer.write_message(f"/moving_objects/object_{track.object_id}/pose", pose_type,
                                 store.deserialize_cdr(serialize_message(pose), pose_type),
                                 pose.header.stamp.sec * 1_000_000_000 + pose.header.stamp.nanosec)  # fmt: skip
    last_ns = max(t.last_stamp_ns for t in tracks)
    header = make_header(last_ns, "map")
    for topic, msg_type, msg in (
        ("/tracking/moving_objects", "changing_slam_msgs/msg/MovingObjectArray", moving_objects_to_msg(tracks, {}, header)),
        ("/tracking/moving_object_markers", "visualization_msgs/msg/MarkerArray", moving_object_markers(tracks, header)),
    ):
        writer.write_message(topic, msg_type, store.deserialize_cdr(serialize_message(msg), msg_type), last_ns)
    return len(tracks)


def evaluate(bag: str, config: str, out: Path) -> dict[str, Any]:
    """ATE RMSE of trajectory.txt and trajectory_online.txt against the bag's ground truth (SE(3) aligned)."""
    from changing_slam_ros.eval.ate import ate
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    result: dict[str, Any] = {}
    try:
        gt = open_dataset(bag, config or None).groundtruth
    except SlamError as err:
        return {"evaluation_error": str(err)}
    if gt is None:
        return {"evaluation_error": f"{bag}: no ground truth"}
    for key, name in (("ate_rmse_m", "trajectory.txt"), ("ate_online_rmse_m", "trajectory_online.txt")):
        path = out / name
        if not path.is_file():
            result.setdefault("evaluation_error", f"{path}: not written")
            continue
        try:
            result[key] = float(ate(gt, read_tum_trajectory(path), est_name=name).stats.rmse)
        except SlamError as err:
            result.setdefault("evaluation_error", str(err))
    return result


# Why a colour frame of the bag has no pose, in the order a frame meets them; graph_summary.json `drops_by_reason`
# (docs/commands.md#drops-by-reason): reason -> where the count comes from (tracking_stats.json).
DROP_REASONS: dict[str, str] = {
    "not_received": "colour frames played (the bag's, times the passes) minus colour_received",
    "unpaired": "unpaired_colour_dropped",
    "waiting_for_depth_at_end": "colour_waiting_for_depth",
    "stale": "frames_dropped_stale",
    "malformed": "frames_rejected",
    "no_camera_info": "frames_skipped_no_camera_info",
    "waiting_for_map": "frames_skipped_waiting_for_map",
    "not_tracked": "frames_lost",
}


def drops_by_reason(frames_played: int, stats: dict[str, Any]) -> dict[str, int]:
    """Each colour frame played that did not become a pose, by the reason tracking counted (`DROP_REASONS`), every
    reason present (0 where none). `unaccounted` is what the counts do not explain (0 in a complete run; a frame
    in flight when tracking stopped, say), so that the values add up to `frames_played - poses_published`."""
    received = int(stats.get("colour_received") or 0)
    out = {"not_received": max(frames_played - received, 0)}
    for reason, key in DROP_REASONS.items():
        if reason != "not_received":
            out[reason] = int(stats.get(key) or 0)
    dropped = frames_played - int(stats.get("poses_published") or 0)
    out["unaccounted"] = dropped - sum(out.values())
    return out


def drops_text(drops: int, by_reason: dict[str, int]) -> str:
    """`3 dropped: 1 malformed, 2 not_tracked` (the reasons with a count), or `0 dropped`."""
    named = [f"{n} {reason}" for reason, n in by_reason.items() if n]
    return f"{drops} dropped" + (": " + ", ".join(named) if named and drops else "")


def lossless_gaps(player_log: str, stats: dict[str, Any], mapping: dict[str, Any] | None) -> list[str]:
    """What a lossless run did not finish: player acks or tracking's map-update waits that timed out,
    keyframes without a map update, keyframes received but not mapped. Empty when the run is complete."""
    gaps = []
    found = re.findall(r"bag_player: finished: .*?, (\d+) ack timeouts", player_log)
    if found and int(found[-1]):
        gaps.append(f"{found[-1]} frames went out without tracking's ack (ack timeout)")
    if stats.get("map_update_waits_timed_out"):
        gaps.append(f"tracking went on without {stats['map_update_waits_timed_out']} map updates / loop verdicts")
    if stats.get("keyframes_without_map_update"):
        gaps.append(f"{stats['keyframes_without_map_update']} keyframes sent never came back as a map update")
    # a keyframe tracking sent again after a resync answer was mapped already: counted as a duplicate, not a gap
    distinct = (mapping or {}).get("keyframes_received", 0) - (mapping or {}).get("keyframes_duplicate", 0)
    if mapping and mapping.get("keyframes_mapped") != distinct:
        gaps.append(f"local_mapping received {distinct} distinct keyframes and mapped "
                    f"{mapping.get('keyframes_mapped')}")  # fmt: skip
    if not stats:
        gaps.append("tracking wrote no tracking_stats.json")
    return gaps


def camera_mismatches(bag: str, config: str, map_in: str, loaded: Any) -> list[CameraMismatch]:
    """The bag's first CameraInfo against the config's camera, and the camera the nodes will use against the one
    the `--map-in` map was made with (`loaded`: its `LoadedMap`, or None); nothing when the bag cannot be read
    here (the nodes then say why)."""
    from changing_slam_ros.io.dataset import open_dataset

    try:
        source = open_dataset(bag, config or None)
    except SlamError:
        return []
    found = [source.camera_mismatch]
    if loaded is not None:
        found.append(map_camera_mismatch(map_in, first_keyframe_camera(loaded.atlas.current.keyframes),
                                         source.camera))  # fmt: skip
    return [m for m in found if m is not None]


def graph_warnings(summary: dict[str, Any], mismatches: list[CameraMismatch]) -> list[str]:
    """graph_summary.json `warnings`: cameras that disagree, no frame tracked (then `graph` exits 1), no frame
    received from live topics."""
    out = [m.message() for m in mismatches]
    live = summary.get("live")
    if live and not summary.get("colour_received"):
        out.append(f"no colour frame received on {live['colour_topic']}: is the camera driver running, on this "
                   "ROS_DOMAIN_ID, with these topic names (`ros2 topic list`)?")  # fmt: skip
    if summary.get("colour_frames_in_bag") and not summary.get("frames_tracked"):
        out.append(f"0 of {summary['colour_frames_in_bag']} colour frames tracked: check the config's camera and "
                   "dataset against the bag, and logs/tracking.log")  # fmt: skip
    return out
