"""Messages <-> core types, for the nodes. Nothing here decides anything: it only moves numbers.

Conventions: stamps are integer nanoseconds (`stamp_ns`); poses are camera-to-world 4x4 float64 matrices
(`T_world_cam`); per-keypoint arrays are numpy with the shapes of `core.keyframe.Keyframe`. Numeric sequence
fields are filled from bytes (`array.array(code, ndarray.tobytes())`), which is what keeps a 1000-keypoint
keyframe fast to convert. Image decoding is the IO layer's (`io/image_codec.py`), CameraInfo parsing too
(`io/camera_info.py`).
"""

from __future__ import annotations

import array
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion, Transform, Vector3
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from changing_slam_msgs.msg import Detection as DetectionMsg
from changing_slam_msgs.msg import DetectionArray
from changing_slam_msgs.msg import Keyframe as KeyframeMsg
from changing_slam_msgs.msg import LoopCorrection as LoopCorrectionMsg
from changing_slam_msgs.msg import MovingObject as MovingObjectMsg
from changing_slam_msgs.msg import MovingObjectArray
from changing_slam_msgs.msg import ObjectState as ObjectStateMsg
from changing_slam_msgs.msg import ObjectStateArray

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet, class_name
from changing_slam_ros.core.dynamic.dynamic_objects import ObjectState
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.slam.loop_closing import LoopCorrection
from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack
from changing_slam_ros.core.geometry.se3 import make_pose, quat_to_rot, rot_to_quat
from changing_slam_ros.errors import BagError
from changing_slam_ros.io.camera_info import camera_info_fields, intrinsics_from_camera_info
from changing_slam_ros.io.image_codec import (
    decode_any_depth,
    decode_any_rgb,
    depth_image_fields,
    rgb_image_fields,
)

F64 = npt.NDArray[np.float64]
NS_PER_S = 1_000_000_000


# -- time and frames -----------------------------------------------------------------------------
def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def ns_to_stamp(stamp_ns: int) -> Time:
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def make_header(stamp_ns: int, frame_id: str) -> Header:
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


# -- poses ---------------------------------------------------------------------------------------
def pose_to_matrix(pose: Any) -> F64:
    """geometry_msgs/Pose -> 4x4 (the quaternion is normalised; a zero quaternion is an error)."""
    q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if not np.isfinite(norm) or norm < 1e-9:
        raise ValueError(f"pose orientation {q.tolist()} is not a rotation quaternion")
    t = np.array([pose.position.x, pose.position.y, pose.position.z], dtype=np.float64)
    return make_pose(quat_to_rot(q / norm), t)


def matrix_to_pose(T: F64) -> Pose:  # noqa: N803 - a pose matrix
    """4x4 rigid transform -> geometry_msgs/Pose."""
    T = np.asarray(T, dtype=np.float64)
    x, y, z, w = (float(v) for v in rot_to_quat(T[:3, :3]))
    return Pose(
        position=Point(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        orientation=Quaternion(x=x, y=y, z=z, w=w),
    )


def matrix_to_transform(T: F64) -> Transform:  # noqa: N803
    """4x4 -> geometry_msgs/Transform (for TF)."""
    pose = matrix_to_pose(T)
    p = pose.position
    return Transform(translation=Vector3(x=p.x, y=p.y, z=p.z), rotation=pose.orientation)


# -- images and camera ---------------------------------------------------------------------------
def image_to_rgb(msg: Any, topic: str = "image") -> npt.NDArray[np.uint8]:
    """Image or CompressedImage -> (H, W, 3) uint8 RGB; BagError names the topic on bad input."""
    return decode_any_rgb(msg, topic)


def image_to_depth_m(msg: Any, topic: str = "depth") -> npt.NDArray[np.float32]:
    """Image (16UC1 mm, 32FC1 m) or CompressedImage depth -> (H, W) float32 metres, 0 = no reading."""
    return decode_any_depth(msg, topic)


def rgb_to_image(rgb: npt.NDArray[np.uint8], stamp_ns: int, frame_id: str, encoding: str = "rgb8") -> Image:
    f = rgb_image_fields(rgb, encoding)
    return Image(
        header=make_header(stamp_ns, frame_id), height=f["height"], width=f["width"], encoding=f["encoding"],
        is_bigendian=f["is_bigendian"], step=f["step"], data=_bytes_array(f["data"]),
    )  # fmt: skip


def depth_to_image(depth_m: npt.NDArray[np.float32], stamp_ns: int, frame_id: str, encoding: str = "32FC1") -> Image:
    f = depth_image_fields(depth_m, encoding)
    return Image(
        header=make_header(stamp_ns, frame_id), height=f["height"], width=f["width"], encoding=f["encoding"],
        is_bigendian=f["is_bigendian"], step=f["step"], data=_bytes_array(f["data"]),
    )  # fmt: skip


def camera_info_to_intrinsics(msg: Any, topic: str = "camera_info") -> CameraIntrinsics:
    return intrinsics_from_camera_info(msg, topic)


def intrinsics_to_camera_info(camera: CameraIntrinsics, stamp_ns: int = 0, frame_id: str = "") -> CameraInfo:
    f = camera_info_fields(camera)
    msg = CameraInfo(header=make_header(stamp_ns, frame_id), height=f["height"], width=f["width"])
    msg.distortion_model = f["distortion_model"]
    msg.d = [float(v) for v in f["d"]]
    msg.k = np.asarray(f["k"], dtype=np.float64)
    msg.r = np.asarray(f["r"], dtype=np.float64)
    msg.p = np.asarray(f["p"], dtype=np.float64)
    return msg


# -- detections ----------------------------------------------------------------------------------
def detections_to_msg(detections: DetectionSet, frame_id: str) -> DetectionArray:
    """DetectionSet -> DetectionArray (boxes as x, y, w, h), stamped with the image's stamp."""
    out = DetectionArray(header=make_header(detections.stamp_ns, frame_id))
    out.width, out.height = int(detections.width), int(detections.height)
    for d in detections.detections:
        x0, y0, x1, y1 = d.box_xyxy
        out.detections.append(
            DetectionMsg(x=float(x0), y=float(y0), w=float(x1 - x0), h=float(y1 - y0), class_id=int(d.class_id),
                         score=float(d.score))
        )  # fmt: skip
    return out


def detections_from_msg(msg: Any) -> DetectionSet:
    dets = tuple(
        Detection((float(d.x), float(d.y), float(d.x + d.w), float(d.y + d.h)), int(d.class_id), float(d.score))
        for d in msg.detections
    )
    return DetectionSet(stamp_to_ns(msg.header.stamp), dets, int(msg.width), int(msg.height))


# -- keyframes -----------------------------------------------------------------------------------
def keyframe_to_msg(kf: Keyframe, frame_id: str) -> KeyframeMsg:
    """core Keyframe -> Keyframe message; header.frame_id is the map frame the pose is in."""
    msg = KeyframeMsg(header=make_header(kf.stamp_ns, frame_id), id=int(kf.id), map_id=int(kf.map_id))
    msg.pose = matrix_to_pose(kf.T_world_cam)
    msg.camera_info = intrinsics_to_camera_info(kf.camera, kf.stamp_ns)
    msg.keypoints = _array("f", kf.keypoints_px, np.float32)
    msg.octaves = _array("b", kf.octaves, np.int8)
    msg.descriptors = _bytes_array(kf.descriptors)
    msg.depths = _array("f", kf.depths_m, np.float32)
    msg.point_ids = _array("q", kf.point_ids, np.int64)
    msg.kp_classes = _array("b", kf.kp_classes, np.int8)
    msg.object_ids = _array("q", kf.object_ids, np.int64)
    return msg


def keyframe_from_msg(msg: Any, topic: str = "keyframes") -> Keyframe:
    """Keyframe message -> core Keyframe; BagError when the per-keypoint arrays disagree in length."""
    kps = np.frombuffer(msg.keypoints, dtype=np.float32).reshape(-1, 2) if len(msg.keypoints) % 2 == 0 else None
    n = 0 if kps is None else len(kps)
    sizes = {
        "keypoints": len(msg.keypoints) // 2 if kps is not None else -1,
        "octaves": len(msg.octaves),
        "descriptors": len(msg.descriptors) // 32 if len(msg.descriptors) % 32 == 0 else -1,
        "depths": len(msg.depths),
        "point_ids": len(msg.point_ids),
        "kp_classes": len(msg.kp_classes),
        "object_ids": len(msg.object_ids),
    }
    bad = {k: v for k, v in sizes.items() if v != n}
    if kps is None or bad:
        raise BagError(
            f"{topic}: keyframe {msg.id}: per-keypoint arrays disagree ({', '.join(f'{k} {v}' for k, v in sizes.items())}); "
            "expected N each (keypoints 2N, descriptors 32N values)"
        )
    return Keyframe(
        id=int(msg.id),
        stamp_ns=stamp_to_ns(msg.header.stamp),
        T_world_cam=pose_to_matrix(msg.pose),
        camera=camera_info_to_intrinsics(msg.camera_info, f"{topic}: keyframe {msg.id} camera_info"),
        keypoints_px=kps.copy(),
        octaves=np.frombuffer(msg.octaves, dtype=np.int8).copy(),
        descriptors=np.frombuffer(bytes(msg.descriptors), dtype=np.uint8).reshape(n, 32).copy(),
        depths_m=np.frombuffer(msg.depths, dtype=np.float32).copy(),
        point_ids=np.frombuffer(msg.point_ids, dtype=np.int64).copy(),
        kp_classes=np.frombuffer(msg.kp_classes, dtype=np.int8).copy(),
        object_ids=np.frombuffer(msg.object_ids, dtype=np.int64).copy(),
        map_id=int(msg.map_id),
    )


# -- object states -------------------------------------------------------------------------------
def object_state_to_msg(state: ObjectState, belief: float = 0.5, active: bool = True) -> ObjectStateMsg:
    """core ObjectState -> message (NaN position/velocity before the first measurement stay NaN)."""
    p = np.asarray(state.position_world, dtype=np.float64)
    v = np.asarray(state.velocity_world, dtype=np.float64)
    msg = ObjectStateMsg(
        id=int(state.object_id), class_id=int(state.class_id), class_name=class_name(int(state.class_id)),
        position=Point(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        velocity=Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2])),
        is_dynamic=bool(state.is_dynamic), belief=float(belief), active=bool(active),
    )  # fmt: skip
    msg.covariance = np.asarray(state.covariance, dtype=np.float64).reshape(36)
    return msg


def object_states_to_msg(states: list[ObjectState], stamp_ns: int, frame_id: str) -> ObjectStateArray:
    return ObjectStateArray(header=make_header(stamp_ns, frame_id), objects=[object_state_to_msg(s) for s in states])


# -- moving objects (class-agnostic movers, Dai et al.) ------------------------------------------
def moving_objects_to_msg(
    tracks: list[MovingObjectTrack], points_obj: Mapping[int, F64], header: Header
) -> MovingObjectArray:
    """Tracks -> MovingObjectArray: per object its latest pose, its trajectory (a Path in `header.frame_id`)
    and its model points in the object frame (`points_obj[id]`, (P, 3); none when missing). Objects
    without a pose are left out. The message has no class field: every mover is class-agnostic."""
    out = MovingObjectArray(header=header)
    for track in tracks:
        if len(track.stamps_ns) == 0:
            continue
        poses = [PoseStamped(header=make_header(int(s), header.frame_id), pose=matrix_to_pose(T))
                 for s, T in zip(track.stamps_ns, track.T_world_obj, strict=True)]  # fmt: skip
        msg = MovingObjectMsg(header=make_header(track.last_stamp_ns, header.frame_id), id=int(track.object_id))
        msg.pose = poses[-1].pose
        msg.trajectory = PathMsg(header=make_header(track.last_stamp_ns, header.frame_id), poses=poses)
        pts = points_obj.get(track.object_id)
        if pts is not None:
            msg.points = _array("f", np.asarray(pts, dtype=np.float32).reshape(-1), np.float32)
        out.objects.append(msg)
    return out


def moving_objects_from_msg(msg: Any) -> list[tuple[MovingObjectTrack, F64]]:
    """MovingObjectArray -> [(track, points (P, 3) in the object frame)], class_id -1; ValueError on a bad
    point array or pose."""
    out = []
    for obj in msg.objects:
        flat = np.asarray(obj.points, dtype=np.float64)
        if flat.size % 3:
            raise ValueError(f"moving object {obj.id}: {flat.size} point values, not a multiple of 3")
        stamps = np.array([stamp_to_ns(p.header.stamp) for p in obj.trajectory.poses], dtype=np.int64)
        poses = np.array([pose_to_matrix(p.pose) for p in obj.trajectory.poses]).reshape(-1, 4, 4)
        out.append((MovingObjectTrack(int(obj.id), -1, stamps, poses, flat.size // 3), flat.reshape(-1, 3)))
    return out


def moving_object_markers(tracks: list[MovingObjectTrack], header: Header, width_m: float = 0.01) -> MarkerArray:
    """MarkerArray: DELETEALL, then per object a LINE_STRIP of its trajectory (object origins) and a SPHERE at
    its latest position, in a colour of its own (golden-angle hue by id)."""
    import colorsys

    out = MarkerArray(markers=[Marker(header=header, action=Marker.DELETEALL)])
    for track in tracks:
        if len(track.stamps_ns) == 0:
            continue
        r, g, b = colorsys.hsv_to_rgb((track.object_id * 0.618034) % 1.0, 0.9, 1.0)
        colour = ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0)
        line = Marker(header=header, ns="moving_object_trajectories", id=int(track.object_id),
                      type=Marker.LINE_STRIP, action=Marker.ADD, color=colour)  # fmt: skip
        line.pose.orientation.w = 1.0
        line.scale.x = float(width_m)
        line.points = [Point(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])) for T in track.T_world_obj]
        head = Marker(header=header, ns="moving_objects", id=int(track.object_id), type=Marker.SPHERE,
                      action=Marker.ADD, color=colour, pose=matrix_to_pose(track.T_world_obj[-1]))  # fmt: skip
        head.scale.x = head.scale.y = head.scale.z = 5.0 * float(width_m)
        out.markers += [line, head] if len(track.stamps_ns) > 1 else [head]
    return out


# -- loop corrections ----------------------------------------------------------------------------
def loop_correction_to_msg(lc: LoopCorrection, stamp_ns: int, frame_id: str) -> LoopCorrectionMsg:
    """core LoopCorrection -> message (keypoint matches and pose_corrections stay in loop_closing)."""
    msg = LoopCorrectionMsg(header=make_header(stamp_ns, frame_id), map_id=int(lc.map_id))
    msg.query_keyframe_id, msg.match_keyframe_id = int(lc.query_kf_id), int(lc.match_kf_id)
    msg.relative_pose = matrix_to_pose(lc.T_match_query)
    msg.n_inliers = int(lc.num_inliers)
    kf_ids = sorted(lc.corrected_poses)
    msg.corrected_keyframe_ids = _array("q", np.array(kf_ids, dtype=np.int64), np.int64)
    msg.corrected_keyframe_poses = [matrix_to_pose(lc.corrected_poses[i]) for i in kf_ids]
    pt_ids = sorted(lc.corrected_points)
    msg.corrected_point_ids = _array("q", np.array(pt_ids, dtype=np.int64), np.int64)
    positions = np.array([lc.corrected_points[i] for i in pt_ids], dtype=np.float64).reshape(-1)
    msg.corrected_point_positions = _array("d", positions, np.float64)
    msg.fused_point_pairs = _array("q", np.array(lc.fused_points, dtype=np.int64).reshape(-1), np.int64)
    return msg


def loop_correction_from_msg(msg: Any, old_poses: Mapping[int, F64] | None = None) -> LoopCorrection:
    """Message -> core LoopCorrection; `pose_corrections` (T_new @ T_old^-1) need the receiver's old poses."""
    kf_ids = np.frombuffer(msg.corrected_keyframe_ids, dtype=np.int64)
    poses = {int(i): pose_to_matrix(p) for i, p in zip(kf_ids, msg.corrected_keyframe_poses, strict=True)}
    pt_ids = np.frombuffer(msg.corrected_point_ids, dtype=np.int64)
    positions = np.frombuffer(msg.corrected_point_positions, dtype=np.float64).reshape(-1, 3)
    pairs = np.frombuffer(msg.fused_point_pairs, dtype=np.int64).reshape(-1, 2)
    corrections = {}
    for i, T_new in poses.items():
        if old_poses is not None and i in old_poses:
            corrections[i] = T_new @ np.linalg.inv(old_poses[i])
    return LoopCorrection(
        query_kf_id=int(msg.query_keyframe_id), match_kf_id=int(msg.match_keyframe_id), map_id=int(msg.map_id),
        T_match_query=pose_to_matrix(msg.relative_pose), num_inliers=int(msg.n_inliers),
        keypoint_matches=np.zeros((0, 2), np.int64), corrected_poses=poses,
        corrected_points={int(i): positions[k].copy() for k, i in enumerate(pt_ids)},
        fused_points=[(int(a), int(b)) for a, b in pairs], pose_corrections=corrections,
    )  # fmt: skip


# -- helpers -------------------------------------------------------------------------------------
def _array(code: str, values: Any, dtype: Any) -> array.array:
    """numpy -> array.array of `code` through bytes (fast for large arrays)."""
    return array.array(code, np.ascontiguousarray(np.asarray(values, dtype=dtype)).reshape(-1).tobytes())


def _bytes_array(values: Any) -> array.array:
    return _array("B", values, np.uint8)
