"""Tracking (ORB-SLAM3 `Tracking` for RGB-D): pose of every frame against the map, keyframe decision.

Per frame: 1. predict the pose with a constant-velocity model (or keep the last pose after a gap);
2. match the last frame's points by projection (fallback: brute-force matching against the
reference keyframe); 3. optimise the pose; 4. track the local map (points of covisible keyframes)
by projection and optimise again; 5. decide whether the frame becomes a keyframe. When tracking
fails the state is LOST and every following frame tries relocalisation against candidate keyframes
(`KeyframeCandidates`, e.g. the loop engineer's bag-of-words database); after
`lost_frames_new_map` failures a new map is started in the Atlas. An initial pose (`set_pose_hint`,
`core/slam/initial_pose.py`) limits relocalisation to its surroundings.
"""

from __future__ import annotations

import enum
from collections import Counter
from dataclasses import dataclass
from itertools import chain
from typing import Protocol

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.features.matcher import ProjectionQuery, match_brute_force, search_by_projection
from changing_slam_ros.core.features.orb_features import FeatureConfig
from changing_slam_ros.core.geometry.pose_optimizer import PinholeStereo, PoseObservations, optimize_pose, orthonormalised
from changing_slam_ros.core.geometry.se3 import invert, scale_motion, transform_points
from changing_slam_ros.core.slam.initial_pose import HintedCandidates, PoseHint
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.slam.still_camera import StillCamera
from changing_slam_ros.core.slam.tracking_config import TrackingConfig
from changing_slam_ros.core.slam.motion_gate import MotionGate, check_speed
from changing_slam_ros.core.slam.rotation_vote import vote_rotation

F64 = npt.NDArray[np.float64]


class TrackingState(enum.Enum):
    NOT_INITIALISED = 0
    OK = 1
    LOST = 2


class KeyframeCandidates(Protocol):
    """Where relocalisation looks: keyframe ids of `slam_map` that may show what `frame` sees, best first."""

    def candidates(self, frame: Frame, slam_map: SlamMap) -> list[int]: ...


class RecentKeyframes:
    """Fallback candidate source: the most recent keyframes of the map (no appearance index)."""

    def __init__(self, n: int = 6) -> None:
        self.n = n

    def candidates(self, frame: Frame, slam_map: SlamMap) -> list[int]:
        return sorted(slam_map.keyframes, reverse=True)[: self.n]


@dataclass
class TrackResult:
    """What tracking reports for one frame."""

    state: TrackingState
    T_world_cam: F64 | None
    n_inliers: int
    new_keyframe: Keyframe | None
    relocalised: bool = False
    new_map: bool = False


class Tracker:
    """Tracks frames against `atlas.current`; creates keyframes (the caller hands them to local mapping)."""

    def __init__(
        self,
        atlas: Atlas,
        features: FeatureConfig,
        config: TrackingConfig | None = None,
        candidates: KeyframeCandidates | None = None,
    ) -> None:
        self.atlas = atlas
        self.fcfg = features
        self.cfg = config or TrackingConfig()
        self.candidates = candidates or RecentKeyframes(self.cfg.n_reloc_candidates)
        self.state = TrackingState.NOT_INITIALISED
        self.scales = features.level_scales()
        self.inv_sigma2 = 1.0 / features.level_sigma2()
        self.last_frame: Frame | None = None
        self.velocity: F64 | None = None  # T_last_current as camera motion, (4, 4)
        self.velocity_dt_s = 0.0  # the stamp step `velocity` was measured over
        self.ref_kf_id = -1
        self.last_kf_index = -(10**9)
        self.keyframe_requested = False  # the object layer asked for a keyframe (`request_keyframe`)
        self.last_reloc_index = -(10**9)
        self.n_lost = 0
        self.n_vote_aimed = 0  # frames tracked from a prediction re-aimed by the displacement vote
        self.n_jumps_refused = 0  # tracked poses refused for leaving the prediction (`motion_max_jump_m`)
        self.next_kf_id = 0
        self.mapping_idle = True  # False while local mapping has keyframes to map (real-time graph: set per frame)
        self.last_good_pose: F64 = np.eye(4)
        self.last_good_stamp_ns: int | None = None  # of `last_good_pose`; None before the first one in this map
        self.n_gated = 0  # poses refused by the motion gate (tracked and relocalised)
        self._T_wc_pred: F64 = np.eye(4)  # the motion model's prediction for the frame being tracked
        self._predicted = False  # whether a velocity made that prediction (not only the last pose)
        self.gate = MotionGate(self.cfg.motion_gate)
        self.still = StillCamera(self.cfg.still_camera)
        self.n_refused = 0  # frames in a row refused by the gate since the last accepted one
        self.awaiting_loaded_map = False  # a loaded map: relocalise against it before starting a new one
        self._grace_start_ns: int | None = None
        self.loaded_map_relocalised_index = -1  # the frame that relocalised in the loaded map, -1 = not (yet)
        # Localisation only: the map is read, never written (no keyframes, no new maps, no point statistics);
        # a lost frame only tries relocalisation, for as long as it takes.
        self.localization = False
        self.pose_hint: PoseHint | None = None  # relocalise near this pose (an operator's initial pose)
        self._hint_start_ns: int | None = None

    @property
    def map(self) -> SlamMap:
        return self.atlas.current

    def start_from_map(self, next_keyframe_id: int) -> None:
        """Begin a session on a loaded Atlas (multi-session): every frame tries relocalisation against
        `atlas.current` for `loaded_map_grace_s` seconds before a new map is started; new keyframes take ids
        from `next_keyframe_id` on."""
        self.state = TrackingState.LOST
        self.n_lost = 0
        self.next_kf_id = max(self.next_kf_id, int(next_keyframe_id))
        self.awaiting_loaded_map = True
        self._grace_start_ns = None

    def set_pose_hint(self, hint: PoseHint | None) -> None:
        """Relocalise near `hint` from the next frame on (None: drop it). A tracker that is OK keeps tracking
        when its last pose lies within the hint's tolerance; elsewhere it is set LOST, so that it relocalises."""
        self.pose_hint = hint
        self._hint_start_ns = None
        if hint is None:
            return
        last = self.last_frame
        if self.state == TrackingState.OK and last is not None and last.T_world_cam is not None \
                and hint.admits(last.T_world_cam):  # fmt: skip
            self.pose_hint = None
            return
        self.state = TrackingState.LOST
        self.n_lost = 0
        self.velocity = None

    def _hint_holds(self, frame: Frame) -> bool:
        """A pose hint is set and not yet timed out (`initial_pose_timeout_s` of frame stamps)."""
        if self.pose_hint is None:
            return False
        if self._hint_start_ns is None:
            self._hint_start_ns = frame.stamp_ns
        if (frame.stamp_ns - self._hint_start_ns) * 1e-9 <= self.cfg.initial_pose_timeout_s:
            return True
        self.pose_hint = None
        return False

    def _within_grace(self, frame: Frame) -> bool:
        """Still waiting to relocalise in the loaded map (False once the grace period is over)."""
        if self._grace_start_ns is None:
            self._grace_start_ns = frame.stamp_ns
        if (frame.stamp_ns - self._grace_start_ns) * 1e-9 < self.cfg.loaded_map_grace_s:
            return True
        self.awaiting_loaded_map = False
        return False

    # 0. Entry point -------------------------------------------------------------------------------
    def track(self, frame: Frame) -> TrackResult:
        gap = self._time_gap(frame)
        if self.state == TrackingState.NOT_INITIALISED and self.localization:
            self.state = TrackingState.LOST  # nothing to initialise: the frame relocalises in the map
        if self.state == TrackingState.NOT_INITIALISED:
            return self._initialise(frame, self.last_good_pose)
        if self.state == TrackingState.OK:
            ok = self._track_frame_to_frame(frame, gap)
            if ok:
                ok = self._track_local_map(frame, self.cfg.min_local_inliers)
            if ok and (not self._plausible(frame) or self._jumped(frame)):
                ok = self._track_from_prediction(frame)
                if not ok and self.n_refused < self.cfg.motion_gate.max_refused_frames:
                    return self._refuse(frame)
            if ok:
                return self._accept(frame)
            self.state = TrackingState.LOST
            self.n_lost = 0
            self.gate.reset()  # the track resumes at a relocalisation
        # LOST: relocalise, or start a new map after too many failures.
        hinted = self._hint_holds(frame)
        if self._relocalise(frame):
            self.state = TrackingState.OK
            self.n_lost = 0
            self.last_reloc_index = frame.index
            if self.awaiting_loaded_map:
                self.awaiting_loaded_map = False
                self.loaded_map_relocalised_index = frame.index
            res = self._accept(frame)
            res.relocalised = True
            return res
        self.n_lost += 1
        self.last_frame = frame
        self.velocity = None
        if self.localization or hinted:  # a hint: no new map while it holds
            return TrackResult(TrackingState.LOST, None, 0, None)
        if self.awaiting_loaded_map:
            if self._within_grace(frame):
                return TrackResult(TrackingState.LOST, None, 0, None)
            return self._initialise(frame, self.last_good_pose, new_map=True)
        if self.n_lost >= self.cfg.lost_frames_new_map:
            res = self._initialise(frame, self.last_good_pose, new_map=True)
            return res
        return TrackResult(TrackingState.LOST, None, 0, None)

    def _time_gap(self, frame: Frame) -> bool:
        if self.last_frame is None:
            return False
        dt = (frame.stamp_ns - self.last_frame.stamp_ns) * 1e-9
        if dt <= 0 or dt > self.cfg.max_time_gap_s:
            self.velocity = None
            return True
        return False

    # 1. Initialisation ----------------------------------------------------------------------------
    def _initialise(self, frame: Frame, T_world_cam: F64, new_map: bool = False) -> TrackResult:
        n_kept = int((frame.features.depths_m > 0).sum())
        n_image = n_kept if frame.n_depth_extracted < 0 else frame.n_depth_extracted
        if n_image < self.cfg.min_init_points or n_kept < min(self.cfg.min_init_points, self.cfg.min_init_kept_points):
            self.last_frame = frame
            return TrackResult(self.state, None, 0, None)
        if new_map and len(self.map.keyframes) > 0:
            self.atlas.new_map()
        frame.T_world_cam = T_world_cam.copy()
        kf = self._make_keyframe(frame)
        self.state = TrackingState.OK
        self.n_lost = 0
        self.velocity = None
        self.last_frame = frame
        self.last_good_pose = frame.T_world_cam
        self.last_good_stamp_ns = frame.stamp_ns
        self.gate.reset()
        self.gate.accept(frame.T_world_cam, frame.stamp_ns)
        return TrackResult(TrackingState.OK, frame.T_world_cam, 0, kf, new_map=new_map)

    # 2. Frame-to-frame ----------------------------------------------------------------------------
    def _track_frame_to_frame(self, frame: Frame, gap: bool) -> bool:
        last = self.last_frame
        assert last is not None and last.T_world_cam is not None
        T_wc_pred = last.T_world_cam @ self._motion(frame) if (self.velocity is not None and not gap) else last.T_world_cam
        self._T_wc_pred = T_wc_pred
        self._predicted = self.velocity is not None and not gap
        pts = self.map.points
        ids = last.point_ids[last.tracked_mask()]
        ids = ids[pts.usable()[ids]] if len(ids) else ids
        radius = self.cfg.radius_motion_px * (1.0 if self.velocity is not None and not gap else 2.0)
        T_cw_pred = invert(T_wc_pred)
        n = self._search(frame, T_cw_pred, ids, radius, ratio=0.9)
        if n < self.cfg.min_motion_inliers:
            frame.point_ids[:] = -1
            n = self._search(frame, T_cw_pred, ids, 2 * radius, ratio=0.9)
        if (n >= self.cfg.min_motion_inliers
                and self._optimise(frame, T_cw_pred, self.cfg.motion_pose_rounds) >= self.cfg.min_motion_inliers):
            return True
        if self._track_from_vote(frame, T_cw_pred, ids, radius):
            return True
        # Fallback: brute-force match against the reference keyframe, from the last pose.
        frame.point_ids[:] = -1
        frame.outliers[:] = False
        if self.ref_kf_id not in self.map.keyframes:
            return False
        n = self._match_keyframe(frame, self.map.keyframes[self.ref_kf_id])
        if n < 15:
            return False
        return self._optimise(frame, invert(last.T_world_cam)) >= 10

    def matches_at_prediction(self, frame: Frame) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """`frame`'s keypoints (K,) that match the last frame's map points (K,) projected at the pose the motion
        model predicts (the first search of frame-to-frame tracking), changing no state; none unless tracking is
        OK. Whether a set of keypoints can see the map, before it is tracked with."""
        last = self.last_frame
        none = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if self.state != TrackingState.OK or last is None or last.T_world_cam is None:
            return none
        dt = (frame.stamp_ns - last.stamp_ns) * 1e-9
        predicted = self.velocity is not None and 0 < dt <= self.cfg.max_time_gap_s
        T_wc = last.T_world_cam @ self._motion(frame) if predicted else last.T_world_cam
        ids = last.point_ids[last.tracked_mask()]
        ids = ids[self.map.points.usable()[ids]] if len(ids) else ids
        if len(ids) == 0:
            return none
        q = self._projection_query(ids)
        radius = self.cfg.radius_motion_px * (1.0 if predicted else 2.0)
        res = search_by_projection(frame, invert(T_wc), q, radius, self.scales, ratio=0.9, bf_m_px=self.fcfg.bf_m_px)
        return res.kp_indices, ids[res.rows]

    def _jumped(self, frame: Frame, count: bool = True) -> bool:
        """True when a velocity predicted this frame's pose and its camera centre lies more than
        `motion_max_jump_m` from the prediction's: a shifted copy of a repeated pattern, or a mover that pulled the
        pose along, not a motion. Such a pose is refused as the motion gate refuses one."""
        if not self._predicted or self.cfg.motion_max_jump_m <= 0.0 or frame.T_world_cam is None:
            return False
        if np.linalg.norm(frame.T_world_cam[:3, 3] - self._T_wc_pred[:3, 3]) <= self.cfg.motion_max_jump_m:
            return False
        self.n_jumps_refused += int(count)
        return True

    def _track_from_vote(self, frame: Frame, T_cw_pred: F64, ids: npt.NDArray[np.int64], radius: float) -> bool:
        """The motion-model search again from a prediction re-aimed by the displacement vote (`rotation_vote`)."""
        vcfg = self.cfg.rotation_vote
        if not vcfg.enabled or len(ids) == 0:
            return False
        pts = self.map.points
        vote = vote_rotation(vcfg, frame.camera, transform_points(T_cw_pred, pts.positions[ids]), pts.descriptors[ids],
                             frame.features.keypoints_px, frame.features.descriptors)
        if vote is None:
            return False
        T_cw = T_cw_pred.copy()
        T_cw[:3, :] = vote.R_delta @ T_cw_pred[:3, :]
        frame.point_ids[:] = -1
        frame.outliers[:] = False
        n = self._search(frame, T_cw, ids, radius, ratio=0.9)
        if n < self.cfg.min_motion_inliers:
            return False
        if self._optimise(frame, T_cw, self.cfg.motion_pose_rounds) < self.cfg.min_motion_inliers:
            return False
        # The vote re-aims the rotation only: a pose whose centre left the prediction's took a shifted copy of a
        # repeated pattern, which a translation along it explains as well.
        T_wc = invert(T_cw)
        assert frame.T_world_cam is not None
        if np.linalg.norm(frame.T_world_cam[:3, 3] - T_wc[:3, 3]) > vcfg.max_translation_m:
            return False
        self._T_wc_pred = T_wc
        self.n_vote_aimed += 1
        return True

    def _motion(self, frame: Frame) -> F64:
        """The predicted camera motion from the last frame to `frame` (constant velocity over the stamp step)."""
        assert self.velocity is not None and self.last_frame is not None
        tol = self.cfg.velocity_rescale_tolerance
        if tol < 0 or self.velocity_dt_s <= 0:
            return self.velocity
        k = (frame.stamp_ns - self.last_frame.stamp_ns) * 1e-9 / self.velocity_dt_s
        return self.velocity if abs(k - 1.0) <= tol else scale_motion(self.velocity, k)

    def _search(self, frame: Frame, T_cw: F64, ids: npt.NDArray[np.int64], radius: float, ratio: float) -> int:
        """Projection search of map points `ids`; fills `frame.point_ids`, returns the number matched."""
        if len(ids) == 0:
            return int((frame.point_ids >= 0).sum())
        q = self._projection_query(ids)
        res = search_by_projection(frame, T_cw, q, radius, self.scales, ratio=ratio, bf_m_px=self.fcfg.bf_m_px)
        frame.point_ids[res.kp_indices] = ids[res.rows]
        frame.outliers[res.kp_indices] = False
        self._visible_rows = ids[res.visible_rows]
        return int((frame.point_ids >= 0).sum())

    def _projection_query(self, ids: npt.NDArray[np.int64]) -> ProjectionQuery:
        pts = self.map.points
        return ProjectionQuery(pts.positions[ids], pts.descriptors[ids], ids, pts.normals[ids], pts.min_dist[ids], pts.max_dist[ids])

    def _match_keyframe(self, frame: Frame, kf: Keyframe) -> int:
        with_pt = np.flatnonzero(kf.point_ids >= 0)
        with_pt = with_pt[self.map.points.usable()[kf.point_ids[with_pt]]]
        ia, ib = match_brute_force(frame.features.descriptors, kf.descriptors[with_pt], ratio=0.8)
        frame.point_ids[ia] = kf.point_ids[with_pt[ib]]
        return len(ia)

    def _optimise(self, frame: Frame, T_cw0: F64, rounds: int = 4) -> int:
        """Optimise the pose on the current matches (`rounds` outlier rounds); outliers lose their map point; inliers."""
        idx = np.flatnonzero(frame.point_ids >= 0)
        if len(idx) < 3:
            return 0
        f = frame.features
        obs = PoseObservations(
            self.map.points.positions[frame.point_ids[idx]], f.keypoints_px[idx], f.u_right[idx],
            self.inv_sigma2[f.octaves[idx]],
        )
        cam = frame.camera
        stereo = PinholeStereo(cam.fx, cam.fy, cam.cx, cam.cy, self.fcfg.bf_m_px)
        res = optimize_pose(T_cw0, obs, stereo, rounds=rounds, iterations=self.cfg.pose_iterations_per_round)
        if self.state == TrackingState.OK:  # a still camera held against a mover (`still_camera`)
            res = self.still.check(obs, stereo, res, self.cfg.pose_iterations_per_round)
        frame.T_world_cam = invert(res.T_cam_world)
        frame.point_ids[idx[~res.inliers]] = -1
        frame.outliers[:] = False
        return res.n_inliers

    # 3. Local map ---------------------------------------------------------------------------------
    def _local_keyframes(self, frame: Frame) -> list[int]:
        m = self.map
        ids = frame.point_ids[frame.point_ids >= 0]
        obs = m.points.observations
        # Keyframes in first-seen order with their counts (Counter counts in C); the stable sort keeps
        # first-seen order among equal counts.
        counts = Counter(chain.from_iterable(obs[pid] for pid in ids.tolist()))
        ranked = sorted(counts, key=lambda k: -counts[k])
        if not ranked:
            return [self.ref_kf_id] if self.ref_kf_id in m.keyframes else []
        self.ref_kf_id = ranked[0]
        local = ranked[: self.cfg.n_local_keyframes]
        seen = set(local)
        for k in ranked[:3]:
            for c in m.covisible(k, 10):
                if c not in seen and len(local) < self.cfg.n_local_keyframes + 10:
                    local.append(c)
                    seen.add(c)
        return local

    def _track_local_map(self, frame: Frame, min_inliers: int) -> bool:
        assert frame.T_world_cam is not None
        m = self.map
        local_ids = m.local_point_ids(self._local_keyframes(frame))
        matched = frame.point_ids[frame.point_ids >= 0]
        local_ids = local_ids[~np.isin(local_ids, matched)]
        radius = self.cfg.radius_local_px * (2.0 if frame.index - self.last_reloc_index < 2 else 1.0)
        self._visible_rows = np.zeros(0, np.int64)
        T_cw = invert(frame.T_world_cam)
        self._search(frame, T_cw, local_ids, radius, ratio=0.8)
        visible = np.concatenate([matched, self._visible_rows])
        n = self._optimise(frame, T_cw)
        if not self.localization:  # the points' found ratio (culling) and recency belong to mapping
            found = frame.point_ids[frame.point_ids >= 0]
            m.points.n_visible[visible] += 1
            m.points.n_found[found] += 1
            m.points.last_seen_frame[found] = frame.index
        return n >= min_inliers

    # 4. Relocalisation ----------------------------------------------------------------------------
    def _relocalise(self, frame: Frame) -> bool:
        m = self.map
        if len(frame) < 50 or not m.keyframes:
            return False
        cam = frame.camera
        hint = self.pose_hint
        source = self.candidates if hint is None else \
            HintedCandidates(self.candidates, hint, self.cfg.n_reloc_candidates)  # fmt: skip
        for kf_id in source.candidates(frame, m):
            if kf_id not in m.keyframes:
                continue
            frame.point_ids[:] = -1
            frame.outliers[:] = False
            kf = m.keyframes[kf_id]
            if self._match_keyframe(frame, kf) < 15:
                continue
            idx = np.flatnonzero(frame.point_ids >= 0)
            pw = m.points.positions[frame.point_ids[idx]]
            ok, rvec, tvec, inl = cv2.solvePnPRansac(
                pw.astype(np.float64), frame.features.keypoints_px[idx].astype(np.float64), cam.K, None,
                iterationsCount=200, reprojectionError=5.0, confidence=0.99, flags=cv2.SOLVEPNP_EPNP,
            )
            if not ok or inl is None or len(inl) < 12:
                continue
            # The pose is optimised on the PnP inliers only: with the outliers, which repetitive textures and
            # a mover in view make the majority, the robust optimisation walks off the PnP pose.
            outl = np.ones(len(idx), dtype=bool)
            outl[inl.ravel()] = False
            frame.point_ids[idx[outl]] = -1
            T_cw = np.eye(4)
            T_cw[:3, :3] = cv2.Rodrigues(rvec)[0]
            T_cw[:3, 3] = tvec.ravel()
            if self._optimise(frame, T_cw) < 10:
                continue
            if hint is not None and not self._near_hint(frame, hint):
                continue  # the place looks the same, but it is not where the hint says
            self.ref_kf_id = kf_id
            frame.ref_kf_id = kf_id
            self.last_reloc_index = frame.index
            # Local map (wider window right after relocalisation), stricter threshold.
            # A hint says where the camera is; without one, the pose must be reachable from the last accepted one.
            if self._track_local_map(frame, self.cfg.min_reloc_inliers) and (
                    self._near_hint(frame, hint) if hint is not None else self._plausible_after_loss(frame)):
                self.pose_hint = None
                return True
        frame.point_ids[:] = -1
        frame.T_world_cam = None
        return False

    def _plausible(self, frame: Frame, count: bool = True) -> bool:
        """The motion gate on a tracked pose (frame-to-frame and local-map tracking)."""
        if frame.T_world_cam is None:
            return True
        check = self.gate.check(frame.T_world_cam, frame.stamp_ns)
        if check.ok:
            return True
        self.n_gated += int(count)
        return False

    def _track_from_prediction(self, frame: Frame) -> bool:
        """A second try when the gate refused the pose: matched points moved with something in view (a mover
        that filled the view pulled the pose along). Matches are searched again around the motion model's
        prediction in the local-map window only, so that points which moved away from where the prediction puts
        them find no partner, and the pose is optimised from the prediction; accepted when it passes the gate."""
        frame.point_ids[:] = -1
        frame.outliers[:] = False
        frame.T_world_cam = self._T_wc_pred.copy()
        if not self._track_local_map(frame, self.cfg.min_local_inliers):
            return False
        return self._plausible(frame, count=False) and not self._jumped(frame, count=False)

    def _refuse(self, frame: Frame) -> TrackResult:
        """A frame whose pose the gate refused gets none; tracking stays OK and the next frame is tracked from
        the last accepted one with the motion model stretched over the longer step."""
        self.n_refused += 1
        frame.T_world_cam = None
        frame.point_ids[:] = -1
        return TrackResult(TrackingState.LOST, None, 0, None)

    def _plausible_after_loss(self, frame: Frame) -> bool:
        """The motion gate from the last accepted pose, within `motion_gate.window_s` of it (relocalisation;
        not in a loaded map that tracking has not yet relocalised in: that pose is in another frame)."""
        if self.last_good_stamp_ns is None or self.awaiting_loaded_map or frame.T_world_cam is None:
            return True
        dt = (frame.stamp_ns - self.last_good_stamp_ns) * 1e-9
        if dt > self.cfg.motion_gate.window_s:
            return True
        if check_speed(self.cfg.motion_gate, self.last_good_pose, frame.T_world_cam, dt, relocalised=True).ok:
            return True
        self.n_gated += 1
        return False

    @staticmethod
    def _near_hint(frame: Frame, hint: PoseHint) -> bool:
        return frame.T_world_cam is not None and hint.admits(frame.T_world_cam)

    # 5. Accept the frame, keyframe decision -------------------------------------------------------
    def _accept(self, frame: Frame) -> TrackResult:
        assert frame.T_world_cam is not None
        last = self.last_frame
        skipped, self.n_refused = self.n_refused, 0
        if last is not None and last.T_world_cam is not None and 1 <= frame.index - last.index <= 1 + skipped:
            self.velocity = orthonormalised(invert(last.T_world_cam) @ frame.T_world_cam)
            self.velocity_dt_s = (frame.stamp_ns - last.stamp_ns) * 1e-9
        else:
            self.velocity = None
        frame.ref_kf_id = self.ref_kf_id
        n_inliers = int((frame.point_ids >= 0).sum())
        kf = self._make_keyframe(frame) if not self.localization and self._need_keyframe(frame, n_inliers) else None
        self.last_frame = frame
        self.last_good_pose = frame.T_world_cam
        self.last_good_stamp_ns = frame.stamp_ns
        self.gate.accept(frame.T_world_cam, frame.stamp_ns)
        self.still.accept(self.velocity, invert(frame.T_world_cam))
        return TrackResult(TrackingState.OK, frame.T_world_cam, n_inliers, kf)

    def request_keyframe(self) -> None:
        """Ask for a keyframe at the next tracked frame that is `object_keyframe_min_frames` after the last one."""
        self.keyframe_requested = True

    def _need_keyframe(self, frame: Frame, n_inliers: int) -> bool:
        cfg = self.cfg
        since = frame.index - self.last_kf_index
        if since < cfg.min_frames_between_keyframes or self.ref_kf_id not in self.map.keyframes:
            return False
        if self.keyframe_requested and since >= max(1, cfg.object_keyframe_min_frames) and n_inliers > 15:
            return True
        n_kfs = len(self.map.keyframes)
        # ORB-SLAM counts a stereo observation twice (min 3 / 2); with single counts: 2 / 1.
        n_ref = self.map.n_tracked_points(self.ref_kf_id, min_obs=2 if n_kfs > 2 else 1)
        th_close = self.fcfg.close_depth_factor * self.fcfg.bf_m_px / frame.camera.fx
        d = frame.features.depths_m
        close = (d > 0) & (d < th_close)
        tracked = frame.point_ids >= 0
        need_close = (close & tracked).sum() < cfg.close_tracked_min and (close & ~tracked).sum() > cfg.close_untracked_min
        ratio = cfg.keyframe_ratio if n_kfs >= 2 else 0.4
        c1 = since >= cfg.max_frames_between_keyframes or since >= cfg.min_frames_between_keyframes
        if not self.mapping_idle and cfg.busy_mapping_weak_ratio > 0.0:  # ORB-SLAM: c1b needs an idle mapper
            c1 = since >= cfg.max_frames_between_keyframes or n_inliers < n_ref * cfg.busy_mapping_weak_ratio or need_close
        c2 = (n_inliers < n_ref * ratio or need_close) and n_inliers > 15
        return bool(c1 and c2) or since >= cfg.max_frames_between_keyframes

    def _make_keyframe(self, frame: Frame) -> Keyframe:
        assert frame.T_world_cam is not None
        f = frame.features
        kf = Keyframe(
            id=self.next_kf_id,
            stamp_ns=frame.stamp_ns,
            T_world_cam=frame.T_world_cam.copy(),
            camera=frame.camera,
            keypoints_px=f.keypoints_px.astype(np.float32),
            octaves=f.octaves.astype(np.int8),
            descriptors=f.descriptors.copy(),
            depths_m=f.depths_m.astype(np.float32),
            point_ids=frame.point_ids.copy(),
            map_id=self.map.id,
        )
        self.next_kf_id += 1
        self.ref_kf_id = kf.id
        frame.ref_kf_id = kf.id
        self.last_kf_index = frame.index
        self.keyframe_requested = False
        return kf
