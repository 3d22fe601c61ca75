"""Place recognition on top of the keyframe database: temporal consistency of loop candidates, and relocalisation.

- `ConsistencyChecker`: temporal consistency of loop candidates (ORB-SLAM2's `DetectLoop` groups);
- `DriftGateConfig` / `check_drift`: a verified loop against the drift the odometry can have made;
- `relocalise`: the pose of a lost frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.slam.geometric_verification import match_descriptors
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.map.keyframe_database import Covisibility, KeyframeDatabase, PlaceCandidate
from changing_slam_ros.core.geometry.se3 import invert, make_pose

F64 = npt.NDArray[np.float64]


def neighbours(covisibility: Covisibility, kf_id: int, n: int | None = None) -> list[int]:
    """Covisible keyframes of `kf_id`, best first when weights are given ({id: shared points}), at most n."""
    nbrs = covisibility.get(kf_id, ())
    if isinstance(nbrs, Mapping):
        ordered = sorted(nbrs, key=lambda j: (-nbrs[j], j))
    else:
        ordered = list(nbrs)
    return ordered if n is None else ordered[:n]


class ConsistencyChecker:
    """Accepts loop candidates whose covisibility group keeps matching over consecutive query keyframes.

    ORB-SLAM2's `LoopClosing::DetectLoop` group logic: a candidate's group is the candidate with its covisible
    keyframes; a group is consistent with a group of the previous query when they share a keyframe, and a
    candidate is accepted once its group has been consistent over `threshold` consecutive keyframes. A single
    lucky BoW match therefore never triggers a loop."""

    def __init__(self, threshold: int = 3) -> None:
        self.threshold = threshold
        self._groups: list[tuple[set[int], int]] = []  # (group of keyframe ids, consistency count)

    def reset(self) -> None:
        self._groups = []

    def update(self, candidates: Iterable[PlaceCandidate], covisibility: Covisibility) -> list[PlaceCandidate]:
        """Feed the candidates of the newest keyframe; returns those consistent `threshold` times in a row."""
        current: list[tuple[set[int], int]] = []
        used_previous = [False] * len(self._groups)
        accepted: list[PlaceCandidate] = []
        for cand in candidates:
            group = {cand.keyframe_id, *neighbours(covisibility, cand.keyframe_id)}
            consistent = False
            accepted_this = False
            for i, (prev_group, prev_count) in enumerate(self._groups):
                if group & prev_group:
                    consistent = True
                    count = prev_count + 1
                    if not used_previous[i]:
                        current.append((group, count))
                        used_previous[i] = True
                    if count >= self.threshold and not accepted_this:
                        accepted.append(cand)
                        accepted_this = True
            if not consistent:
                current.append((group, 0))
        self._groups = current
        return accepted


@dataclass(frozen=True)
class DriftGateConfig:
    """YAML section `loop.drift_gate`. The defaults (a standard deviation of 5 % of the path, 10 % of the turn)
    pass a translation correction up to ~15 % of the path plus 0.15 m, and the synthetic tests' 1 deg per
    keyframe bias. On the randomised changing rooms' tuning seeds 0-9 right loops corrected at most 4.3 % of
    their path (0.12 m over 2.8 m; 8 % for one that undid a wrong loop's bend), and the one wrong loop, a wall
    photo tiled every 1.5 m, would have moved the camera 1.5 m after 5.2 m: 10 % per metre let it through.

    The correction a verified loop implies (the verified relative pose of the two keyframes against their current
    estimate) must be a plausible drift for the path travelled between them. Drift is modelled as zero-mean with
    a standard deviation growing linearly with the distance and the angle travelled (`sigma_floor_m +
    sigma_per_m * path`, `sigma_floor_deg + sigma_per_deg * turn`); the correction's squared normalised
    translation plus rotation must stay under `chi2_max` (chi2 with 2 dof). A repeated texture (a wallpaper motif
    a tile away) can pass RANSAC with a pose a whole period off a few seconds after the robot left that place;
    no odometry drifts a metre in a metre of travel."""

    enabled: bool = True
    sigma_floor_m: float = 0.05
    sigma_per_m: float = 0.05  # translation drift std per metre travelled between the two keyframes
    sigma_floor_deg: float = 1.0
    sigma_per_deg: float = 0.1  # rotation drift std per degree turned between the two keyframes
    chi2_max: float = 9.21  # chi2(2 dof) at 99 %


@dataclass(frozen=True)
class DriftCheck:
    """The loop correction against the expected drift: correction size, path travelled, chi2, verdict."""

    correction_m: float
    correction_deg: float
    path_m: float
    turn_deg: float
    chi2: float
    accepted: bool


def path_travelled(poses: Iterable[F64]) -> tuple[float, float]:
    """Distance (m) and total rotation (deg) along consecutive T_world_cam (4, 4) poses."""
    dist, turn = 0.0, 0.0
    prev: F64 | None = None
    for T in poses:
        if prev is not None:
            rel = invert(prev) @ T
            dist += float(np.linalg.norm(rel[:3, 3]))
            turn += _angle_deg(rel)
        prev = T
    return dist, turn


def check_drift(T_est_a_b: F64, T_loop_a_b: F64, path_m: float, turn_deg: float, config: DriftGateConfig) -> DriftCheck:
    """Compare a verified relative pose `T_loop_a_b` (4, 4) with the current estimate `T_est_a_b` (4, 4) of the same
    two keyframes, `path_m` / `turn_deg` travelled between them (see `DriftGateConfig`)."""
    d = invert(T_est_a_b) @ T_loop_a_b
    dt = float(np.linalg.norm(d[:3, 3]))
    dr = _angle_deg(d)
    st = config.sigma_floor_m + config.sigma_per_m * path_m
    sr = config.sigma_floor_deg + config.sigma_per_deg * turn_deg
    chi2 = (dt / st) ** 2 + (dr / sr) ** 2
    return DriftCheck(dt, dr, path_m, turn_deg, chi2, (not config.enabled) or chi2 <= config.chi2_max)


def _angle_deg(T: F64) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))


@dataclass(frozen=True)
class RelocalisationConfig:
    """YAML section `loop.relocalisation`."""

    ratio: float = 0.8
    max_hamming: int = 80
    reprojection_px: float = 4.0  # RANSAC inlier threshold
    ransac_iterations: int = 200
    min_inliers: int = 30  # ORB-SLAM needs 50 after pose optimisation; PnP inliers here
    max_candidates: int = 5
    neighbours_per_candidate: int = 10
    seed: int = 0


@dataclass(frozen=True)
class Relocalisation:
    """A relocalised frame: `T_world_cam` (4, 4), the keyframe that matched, and the inliers as
    `frame_indices` (M,) keypoint indices with `point_ids` (M,) the map points they observe."""

    T_world_cam: F64
    keyframe_id: int
    frame_indices: npt.NDArray[np.int64]
    point_ids: npt.NDArray[np.int64]

    @property
    def num_inliers(self) -> int:
        return len(self.frame_indices)


def relocalise(
    keypoints_px: npt.NDArray[np.floating],
    descriptors: npt.NDArray[np.uint8],
    camera: CameraIntrinsics,
    database: KeyframeDatabase,
    keyframes: Mapping[int, Keyframe],
    point_positions: Mapping[int, F64],
    covisibility: Covisibility,
    config: RelocalisationConfig = RelocalisationConfig(),
    map_id: int | None = None,
    active_mask: npt.NDArray[np.bool_] | None = None,
) -> Relocalisation | None:
    """Pose of a lost frame (keypoints (N, 2) undistorted px, descriptors (N, 32)) in the map, or None.

    `point_positions` maps point id -> (3,) world position; keyframes' `point_ids` say which keypoint sees
    which point. `active_mask` (N,) excludes frame keypoints (dynamic ones) from the BoW query and matching.
    Candidates come from the database; descriptors are matched against the map points of each candidate and its
    covisible keyframes, `cv2.solvePnPRansac`, then a refinement on the inliers. The first candidate with enough
    inliers wins.
    """
    kp = np.asarray(keypoints_px, np.float64)
    mask = np.ones(len(kp), bool) if active_mask is None else np.asarray(active_mask, bool)
    if mask.sum() < 4:
        return None
    bow = database.vocabulary.transform(descriptors[mask]).bow
    candidates = database.relocalisation_candidates(bow, covisibility, map_id)
    candidates = sorted(candidates, key=lambda c: (-c.score, c.keyframe_id))[: config.max_candidates]
    cv2.setRNGSeed(config.seed)
    for cand in candidates:
        pids, pdesc = _local_points(cand.keyframe_id, keyframes, point_positions, covisibility, config)
        if len(pids) < config.min_inliers:
            continue
        matches = match_descriptors(descriptors, pdesc, mask, np.ones(len(pids), bool), config.ratio, config.max_hamming)
        if len(matches) < config.min_inliers:
            continue
        obj = np.array([point_positions[int(p)] for p in pids[matches[:, 1]]], np.float64)
        img = kp[matches[:, 0]]
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            obj, img, camera.K, None,
            iterationsCount=config.ransac_iterations,
            reprojectionError=config.reprojection_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_EPNP,
        )
        if not ok or inliers is None or len(inliers) < config.min_inliers:
            continue
        inl = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], camera.K, None, rvec, tvec)
        # recount inliers under the refined pose
        proj, _ = cv2.projectPoints(obj, rvec, tvec, camera.K, None)
        err = np.linalg.norm(proj.reshape(-1, 2) - img, axis=1)
        r, _ = cv2.Rodrigues(rvec)
        depth = (obj @ r.T + tvec.reshape(1, 3))[:, 2]
        inl = np.nonzero((err < config.reprojection_px) & (depth > 0))[0]
        if len(inl) < config.min_inliers:
            continue
        T_cam_world = make_pose(np.asarray(r, np.float64), np.asarray(tvec, np.float64).ravel())
        return Relocalisation(
            invert(T_cam_world), cand.keyframe_id, matches[inl, 0].astype(np.int64), pids[matches[inl, 1]].astype(np.int64)
        )
    return None


def _local_points(
    kf_id: int,
    keyframes: Mapping[int, Keyframe],
    point_positions: Mapping[int, F64],
    covisibility: Covisibility,
    config: RelocalisationConfig,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.uint8]]:
    """Map points seen by a keyframe and its best covisible keyframes, one descriptor each (first seen)."""
    ids: list[int] = []
    descs: list[npt.NDArray[np.uint8]] = []
    seen: set[int] = set()
    for k in [kf_id, *neighbours(covisibility, kf_id, config.neighbours_per_candidate)]:
        kf = keyframes.get(k)
        if kf is None:
            continue
        for i in np.flatnonzero(kf.point_ids >= 0).tolist():
            pid = int(kf.point_ids[i])
            if pid in seen or pid not in point_positions:
                continue
            seen.add(pid)
            ids.append(pid)
            descs.append(kf.descriptors[i])
    if not ids:
        return np.zeros(0, np.int64), np.zeros((0, 32), np.uint8)
    return np.array(ids, np.int64), np.stack(descs)
