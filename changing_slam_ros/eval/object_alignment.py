"""Moving a run's objects into the ground-truth frame: the trajectory alignment that places them (positions and
camera axes), and the objects and structure planes moved by it."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_point_weights import Plane

F64 = npt.NDArray[np.float64]
MAX_STAMP_GAP_S = 0.02
POSE_LEVER_M = 1.0  # lever arm of the camera axes in the object-placing alignment (trajectory_alignment)


def aligned_objects(objects: list[MapObject], T_gt_est: F64) -> list[MapObject]:
    """Copies of `objects` with their points moved by T_gt_est (4, 4) (centroids and boxes recomputed in that frame,
    viewing directions turned)."""
    R, t = T_gt_est[:3, :3], T_gt_est[:3, 3]
    return [dataclasses.replace(o, point_ids=o.point_ids.copy(), points_w=o.points_w @ R.T + t,
                                view_sum_w=R @ o.view_sum_w, up_sum_w=R @ o.up_sum_w) for o in objects]


def aligned_planes(planes: list[Plane], T_gt_est: F64) -> list[Plane]:
    """The planes n . x + d = 0 moved by T_gt_est (4, 4): normal R n, offset d - (R n) . t."""
    R, t = T_gt_est[:3, :3], T_gt_est[:3, 3]
    return [Plane(R @ p.normal, float(p.offset - (R @ p.normal) @ t)) for p in planes]


def trajectory_alignment(gt: Trajectory, est: Trajectory, lever_m: float = POSE_LEVER_M) -> F64 | None:
    """SE(3) T_gt_est (4, 4) aligning the estimate to ground truth (stamps within 20 ms), None if < 3 pairs.

    Umeyama on the camera positions and, with `lever_m` > 0, on the tips of each camera's three axes
    `lever_m` ahead of it (p + lever_m R e_i): the least-squares fit then also weighs orientation (the
    chordal distance of the rotations at that lever arm). Position-only alignment (`lever_m` 0) leaves the
    tilt about a horizontal axis free to absorb height noise on the planar path of a ground robot: on
    `shift` (0.8 m square loop, camera at one height) it tilted the map 2.3 deg, including at the first
    keyframe, whose pose is exact by construction (the map frame is its camera frame), and that put objects
    2.5 m away 8-10 cm off while the map's own orientation error was 0.7 deg on average. Camera ATE (eval.ate)
    keeps the usual position-only alignment; this one places the map's objects in the ground-truth frame.
    """
    from changing_slam_ros.eval.alignment import umeyama

    if len(est) < 3 or len(gt) < 3:
        return None
    idx = np.searchsorted(gt.stamps_s, est.stamps_s).clip(1, len(gt) - 1)
    nearer = np.where(np.abs(gt.stamps_s[idx - 1] - est.stamps_s) < np.abs(gt.stamps_s[idx] - est.stamps_s), idx - 1, idx)
    ok = np.abs(gt.stamps_s[nearer] - est.stamps_s) <= MAX_STAMP_GAP_S
    if ok.sum() < 3:
        return None
    src, dst = [est.positions[ok]], [gt.positions[nearer[ok]]]
    if lever_m > 0.0:
        pe, pg = est.poses()[ok], gt.poses()[nearer[ok]]
        for axis in range(3):
            src.append(pe[:, :3, 3] + lever_m * pe[:, :3, axis])
            dst.append(pg[:, :3, 3] + lever_m * pg[:, :3, axis])
    return umeyama(np.vstack(src), np.vstack(dst)).T_gt_est
