"""Loop closing end to end on real frames with injected drift: loops found at true revisits, ATE lowered."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pytest
from helpers import REDKITCHEN, require

from changing_slam_ros.config import section
from changing_slam_ros.core.backend.global_ba import GlobalBAConfig
from changing_slam_ros.core.features.frame import Frame
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
from changing_slam_ros.core.features.orb_features import FeatureConfig, Features, OrbExtractor
from changing_slam_ros.core.geometry.se3 import invert, make_pose, rotation_angle_rad
from changing_slam_ros.core.map.slam_map import SlamMap
from changing_slam_ros.core.features.vocabulary import Vocabulary
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.dataset import open_dataset


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rmse_position(poses: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    """ATE RMSE (m) without alignment: both trajectories start at the same pose (the fixed origin)."""
    return float(np.sqrt(np.mean([np.sum((poses[k][:3, 3] - truth[k][:3, 3]) ** 2) for k in truth])))


def test_loop_config_is_read_from_a_yaml_section():
    cfg = section(LoopConfig, {"consistency_threshold": 4, "verification": {"min_inliers": 60},
                               "pose_graph": {"loop_sigma_m": 0.05}}, "x.yaml: loop")
    assert cfg.consistency_threshold == 4
    assert cfg.verification.min_inliers == 60 and cfg.verification.ratio == 0.8
    assert cfg.pose_graph.loop_sigma_m == 0.05
    with pytest.raises(ConfigError, match="x.yaml: loop.verification: unknown key"):
        section(LoopConfig, {"verification": {"inliers": 3}}, "x.yaml: loop")


def test_loops_in_redkitchen_are_true_revisits_and_lower_the_ate_of_a_drifting_trajectory():
    source = open_dataset(require(REDKITCHEN), "7scenes")
    extractor = OrbExtractor(FeatureConfig(), source.camera)
    frames = list(range(0, len(source), 10))  # one keyframe every 10 frames: 100 keyframes, 7.4 m walk
    closer = LoopCloser(LoopConfig(), Vocabulary.load())
    truth: dict[int, np.ndarray] = {}
    online: dict[int, np.ndarray] = {}
    points: dict[int, np.ndarray] = {}
    points_truth: dict[int, np.ndarray] = {}
    points_online: dict[int, np.ndarray] = {}
    covisibility: dict[int, dict[int, int]] = {}
    parent: dict[int, int | None] = {}
    corrections = []
    loop_ms: list[float] = []
    process_ms: list[float] = []
    for kf_id, index in enumerate(frames):
        frame = source.frame(index)
        truth[kf_id] = frame.T_world_cam_gt
        # dead reckoning with a yaw bias of 0.4 deg and a length bias of 1 % per keyframe
        if kf_id == 0:
            online[kf_id] = truth[0].copy()
        else:
            # tracking goes on from the previous keyframe's pose as the map holds it (corrected after a loop)
            rel = invert(truth[kf_id - 1]) @ truth[kf_id]
            previous = closer.keyframes[kf_id - 1].T_world_cam
            online[kf_id] = previous @ make_pose(_rot_y(np.radians(0.4)) @ rel[:3, :3], rel[:3, 3] * 1.01)
        f = extractor.extract(frame.rgb, frame.depth_m)
        point_ids = np.full(len(f), -1, np.int64)
        with_depth = np.flatnonzero(f.depths_m > 0)[::20]  # a few map points per keyframe, from depth
        p_cam = source.camera.backproject(f.keypoints_px[with_depth], f.depths_m[with_depth])
        for i, p in zip(with_depth, p_cam):
            pid = len(points)
            point_ids[i] = pid
            points[pid] = online[kf_id][:3, :3] @ p + online[kf_id][:3, 3]
            points_online[pid] = points[pid].copy()
            points_truth[pid] = truth[kf_id][:3, :3] @ p + truth[kf_id][:3, 3]
        kf = Keyframe(
            id=kf_id, stamp_ns=frame.stamp_ns, T_world_cam=online[kf_id].copy(), camera=source.camera,
            keypoints_px=f.keypoints_px.astype(np.float32), octaves=f.octaves.astype(np.int8),
            descriptors=f.descriptors, depths_m=f.depths_m.astype(np.float32), point_ids=point_ids,
        )
        # the tracker's covisibility: the last three keyframes (it never re-finds old points: it drifted)
        covisibility[kf_id] = {j: 300 - 50 * (kf_id - j) for j in range(max(0, kf_id - 3), kf_id)}
        for j, w in covisibility[kf_id].items():
            covisibility[j][kf_id] = w
        parent[kf_id] = kf_id - 1 if kf_id else None
        t0 = time.perf_counter()
        correction = closer.process(kf, covisibility, parent, points)
        process_ms.append(1e3 * (time.perf_counter() - t0))
        if correction is not None:
            loop_ms.append(process_ms[-1])
            corrections.append(correction)
            closer.update_poses(correction.corrected_poses)  # the map owner applies the correction
            points.update(correction.corrected_points)
    final = {k: closer.keyframes[k].T_world_cam for k in truth}
    ate_online, ate_final = rmse_position(online, truth), rmse_position(final, truth)
    pts_online = float(np.sqrt(np.mean([np.sum((points_online[k] - points_truth[k]) ** 2) for k in points_truth])))
    pts_final = float(np.sqrt(np.mean([np.sum((points[k] - points_truth[k]) ** 2) for k in points_truth])))
    print(f"loops {[(c.query_kf_id, c.match_kf_id, c.num_inliers) for c in corrections]}, "
          f"ATE online {100 * ate_online:.1f} cm -> final {100 * ate_final:.1f} cm, "
          f"points {100 * pts_online:.1f} -> {100 * pts_final:.1f} cm; process() median {np.median(process_ms):.1f} ms, "
          f"p90 {np.percentile(process_ms, 90):.1f} ms, with a loop {np.round(loop_ms)} ms")
    assert len(corrections) >= 2
    for c in corrections:
        # every accepted loop is a real revisit: the cameras were near, looked the same way (the kitchen is
        # 2-3 m away, so 0.7 m apart still share the view) and the verified relative pose is the true one
        rel_truth = invert(truth[c.match_kf_id]) @ truth[c.query_kf_id]
        assert np.linalg.norm(rel_truth[:3, 3]) < 1.0
        assert np.degrees(rotation_angle_rad(rel_truth[:3, :3])) < 35
        e = invert(rel_truth) @ c.T_match_query
        assert np.linalg.norm(e[:3, 3]) < 0.08 and np.degrees(rotation_angle_rad(e[:3, :3])) < 3.0
        assert c.query_kf_id - c.match_kf_id > 10
        assert set(c.corrected_poses) == set(range(c.query_kf_id + 1))
        np.testing.assert_allclose(c.corrected_poses[0], truth[0], atol=1e-6)  # the origin is held fixed
    assert ate_final < 0.8 * ate_online  # measured 12.6 -> 9.0 cm
    assert pts_final < 0.7 * pts_online  # measured 52 -> 28 cm


class SyntheticRoom:
    """A camera walking a circle inside a cylindrical room whose wall carries 4000 points, each with its own
    random ORB descriptor (observed with a few flipped bits). Deterministic; exact ground truth."""

    def __init__(self, seed: int = 0, n_points: int = 4000, radius_m: float = 4.0) -> None:
        from changing_slam_ros.core.geometry.camera import CameraIntrinsics

        self.rng = np.random.default_rng(seed)
        a = self.rng.uniform(0, 2 * np.pi, n_points)
        self.points = np.stack([radius_m * np.cos(a), self.rng.uniform(-1.5, 1.5, n_points), radius_m * np.sin(a)], 1)
        self.descriptors = self.rng.integers(0, 256, (n_points, 32), dtype=np.uint8)
        self.camera = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)

    def pose(self, k: int, n_per_turn: int) -> np.ndarray:
        """Camera k on a 1.5 m circle, looking outward; optical y is down (world -y)."""
        theta = 2 * np.pi * k / n_per_turn
        z_axis = np.array([np.cos(theta), 0.0, np.sin(theta)])
        y_axis = np.array([0.0, -1.0, 0.0])
        x_axis = np.cross(y_axis, z_axis)
        return make_pose(np.stack([x_axis, y_axis, z_axis], 1), 1.5 * np.array([np.cos(theta + 0.3), 0, np.sin(theta + 0.3)]))

    def keyframe(self, kf_id: int, T_world_cam: np.ndarray, T_estimate: np.ndarray) -> tuple[Keyframe, np.ndarray]:
        """Keyframe observed from the true pose, carrying the estimated pose; and the ids of the points it sees."""
        p_cam = (self.points - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
        uv = self.camera.project(np.where(p_cam[:, 2:3] > 0.1, p_cam, 1.0))
        seen = np.flatnonzero((p_cam[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480))
        bits = np.unpackbits(self.descriptors[seen], axis=1)
        flips = self.rng.random(bits.shape) < 0.02
        kf = Keyframe(
            id=kf_id, stamp_ns=kf_id * 10**8, T_world_cam=T_estimate.copy(), camera=self.camera,
            keypoints_px=(uv[seen] + self.rng.normal(0, 0.5, (len(seen), 2))).astype(np.float32),
            octaves=np.zeros(len(seen), np.int8), descriptors=np.packbits(bits ^ flips, axis=1),
            depths_m=(p_cam[seen, 2] * (1 + self.rng.normal(0, 0.005, len(seen)))).astype(np.float32),
            point_ids=np.full(len(seen), -1, np.int64),
        )
        return kf, seen


def test_a_synthetic_loop_is_closed_and_the_final_ate_is_far_below_the_online_ate():
    room = SyntheticRoom()
    n_per_turn, n_kf = 48, 60  # one turn and a quarter: keyframes 48.. see again what 0.. saw
    closer = LoopCloser(LoopConfig(), Vocabulary.load())
    truth, online, covisibility, parent, corrections = {}, {}, {}, {}, []
    for k in range(n_kf):
        truth[k] = room.pose(k, n_per_turn)
        if k == 0:
            online[k] = truth[0].copy()
        else:  # odometry with a 1 deg yaw bias per keyframe, continuing from the map's (corrected) pose
            rel = invert(truth[k - 1]) @ truth[k]
            online[k] = closer.keyframes[k - 1].T_world_cam @ make_pose(_rot_y(np.radians(1.0)) @ rel[:3, :3], rel[:3, 3])
        kf, _ = room.keyframe(k, truth[k], online[k])
        covisibility[k] = {j: 300 - 50 * (k - j) for j in range(max(0, k - 3), k)}
        for j, w in covisibility[k].items():
            covisibility[j][k] = w
        parent[k] = k - 1 if k else None
        c = closer.process(kf, covisibility, parent, {})
        if c is not None:
            corrections.append(c)
            closer.update_poses(c.corrected_poses)
    final = {k: closer.keyframes[k].T_world_cam for k in truth}
    ate_online, ate_final = rmse_position(online, truth), rmse_position(final, truth)
    print(f"synthetic: loops {[(c.query_kf_id, c.match_kf_id, c.num_inliers) for c in corrections]}, "
          f"ATE online {100 * ate_online:.1f} cm -> final {100 * ate_final:.1f} cm")
    assert corrections, "the loop was not closed"
    assert closer.stats.keyframes == n_kf and closer.stats.loops == len(corrections)
    first = corrections[0]
    assert first.query_kf_id >= n_per_turn and (first.query_kf_id - first.match_kf_id) % n_per_turn <= 3
    rel_truth = invert(truth[first.match_kf_id]) @ truth[first.query_kf_id]
    e = invert(rel_truth) @ first.T_match_query
    assert np.linalg.norm(e[:3, 3]) < 0.01 and np.degrees(rotation_angle_rad(e[:3, :3])) < 0.2
    assert ate_final < 0.15 * ate_online  # measured 68.4 -> 6.8 cm


@dataclass
class DriftingMap:
    """The offline map built along the synthetic room by a tracker that re-uses points of the last 3 keyframes
    only: after a turn it maps the start again as new (duplicated, drifted) points."""

    room: SyntheticRoom
    slam_map: SlamMap
    closing: SlamMapLoopClosing
    truth: dict[int, np.ndarray]
    online: dict[int, np.ndarray]
    map_to_world: dict[int, int]
    created: np.ndarray  # (P, 3) point positions as first mapped (online)
    loops: int


def build_drifting_map(
    n_kf: int = 58, n_per_turn: int = 48, seed: int = 1, global_ba: GlobalBAConfig | None = None
) -> DriftingMap:
    room = SyntheticRoom(seed=seed)
    closing = SlamMapLoopClosing(LoopCloser(LoopConfig(), Vocabulary.load()), global_ba=global_ba)
    slam_map = SlamMap(0)
    truth: dict[int, np.ndarray] = {}
    online: dict[int, np.ndarray] = {}
    world_to_map: dict[int, tuple[int, int]] = {}  # world point -> (map point id, last keyframe that saw it)
    map_to_world: dict[int, int] = {}
    created: list[np.ndarray] = []
    scales = FeatureConfig().level_scales()
    loops = 0
    for k in range(n_kf):
        truth[k] = room.pose(k, n_per_turn)
        if k == 0:
            online[k] = truth[0].copy()
        else:
            rel = invert(truth[k - 1]) @ truth[k]
            online[k] = slam_map.keyframes[k - 1].T_world_cam @ make_pose(_rot_y(np.radians(1.0)) @ rel[:3, :3], rel[:3, 3])
        kf, seen = room.keyframe(k, truth[k], online[k])
        slam_map.add_keyframe(kf)
        new_rows = []
        for row, w in enumerate(seen.tolist()):
            known = world_to_map.get(w)
            if known is not None and k - known[1] <= 3 and not slam_map.points.bad[known[0]]:
                slam_map.add_observation(known[0], k, row)
                world_to_map[w] = (known[0], k)
            else:
                new_rows.append(row)
        rows = np.array(new_rows, np.int64)
        p_cam = kf.camera.backproject(kf.keypoints_px[rows].astype(np.float64), kf.depths_m[rows].astype(np.float64))
        p_w = p_cam @ online[k][:3, :3].T + online[k][:3, 3]
        ids = slam_map.points.add(p_w, kf.descriptors[rows], k, rows, online[k][:3, 3], np.zeros(len(rows), np.int64), scales)
        kf.point_ids[rows] = ids
        for pid, row in zip(ids.tolist(), rows.tolist()):
            world_to_map[int(seen[row])] = (pid, k)
            map_to_world[pid] = int(seen[row])
        created.append(p_w)
        slam_map.update_connections(k)
        closing.add(kf)  # the system feeds the index first, then offers the keyframe to loop closing
        loops += int(closing.process(kf, slam_map))
    return DriftingMap(room, slam_map, closing, truth, online, map_to_world, np.concatenate(created), loops)


def test_the_slam_map_binding_corrects_poses_fuses_duplicates_and_serves_relocalisation_candidates():
    """The loop must correct poses and points of the offline map and fuse the duplicated points."""
    d = build_drifting_map()
    room, slam_map, closing, truth, online, map_to_world = d.room, d.slam_map, d.closing, d.truth, d.online, d.map_to_world
    n_per_turn, loops = 48, d.loops
    assert loops >= 1
    c = closing.last_correction
    assert c is not None and c.match_kf_id < 5 and c.query_kf_id >= n_per_turn - 3  # views overlap a turn apart
    final = {k: slam_map.keyframes[k].T_world_cam for k in truth}
    ate_online, ate_final = rmse_position(online, truth), rmse_position(final, truth)
    usable = np.flatnonzero(slam_map.points.usable())
    usable = usable[slam_map.points.ref_kf[usable] <= c.query_kf_id]  # later keyframes drift on after the loop
    true_pos = room.points[[map_to_world[p] for p in usable]]
    pts_err = np.linalg.norm(slam_map.points.positions[usable] - true_pos, axis=1)
    pts_err_online = np.linalg.norm(d.created[usable] - true_pos, axis=1)
    print(f"slam map: loop {c.query_kf_id}->{c.match_kf_id}, {len(c.fused_points)} points fused, "
          f"ATE {100 * ate_online:.1f} -> {100 * ate_final:.1f} cm, point error median {100 * np.median(pts_err_online):.1f} -> {100 * np.median(pts_err):.1f} cm")
    assert ate_final < 0.2 * ate_online  # measured 66.6 -> 6.2 cm
    assert np.median(pts_err) < 0.25 * np.median(pts_err_online)  # measured 125 -> 10 cm
    # duplicates fused: the query now observes points first mapped at the start, and the two sides are linked
    assert len(c.fused_points) > 100
    query = slam_map.keyframes[c.query_kf_id]
    assert np.any(slam_map.points.first_kf[query.point_ids[query.point_ids >= 0]] < 5)
    assert c.match_kf_id in slam_map.covisibility[c.query_kf_id]
    assert c.query_kf_id in slam_map.loop_edges[c.match_kf_id]
    for dup, keep in c.fused_points:
        assert slam_map.points.bad[dup] and not slam_map.points.bad[keep]
    # relocalisation candidates for a frame taken where keyframe 10 was
    kf, _ = room.keyframe(999, truth[10], np.eye(4))
    feats = Features(
        kf.keypoints_px.astype(np.float64), kf.keypoints_px.astype(np.float64), kf.octaves.astype(np.int64),
        np.zeros(len(kf)), np.ones(len(kf)), kf.descriptors, kf.depths_m.astype(np.float64), np.full(len(kf), -1.0),
    )
    cands = closing.candidates(Frame(0, 0, kf.camera, feats), slam_map)
    assert cands and abs(cands[0] - 10) <= 2


def test_a_place_seen_in_two_maps_gives_the_transform_between_their_worlds():
    room = SyntheticRoom(seed=2)
    n_per_turn = 48
    closer = LoopCloser(LoopConfig(), Vocabulary.load())
    # map 1 started after tracking was lost: its own world frame, G = T_world1_world0
    G = make_pose(_rot_y(np.radians(70.0)), np.array([2.0, -0.5, 3.0]))
    covisibility: dict[int, dict[int, int]] = {}
    merges = []
    for k in range(62):
        in_map1 = k >= 25
        T_world_cam = room.pose(k, n_per_turn)
        kf, _ = room.keyframe(k, T_world_cam, G @ T_world_cam if in_map1 else T_world_cam)
        kf.map_id = int(in_map1)
        covisibility[k] = {j: 200 for j in range(max(25 if in_map1 else 0, k - 3), k)}
        for j in covisibility[k]:
            covisibility[j][k] = 200
        closer.add(kf)
        if in_map1:
            m = closer.detect_merge(kf, covisibility)
            if m is not None:
                merges.append(m)
    assert merges, "the shared place was not recognised"
    m = merges[0]
    assert (m.query_map_id, m.match_map_id) == (1, 0)
    # the new map overlaps the old one where it started (and again after a turn): views a few steps apart
    gap = (m.query_kf_id - m.match_kf_id) % n_per_turn
    assert m.match_kf_id < 25 and min(gap, n_per_turn - gap) <= 6
    e = m.T_matchworld_queryworld @ G  # should be the identity
    print(f"merge {m.query_kf_id}->{m.match_kf_id}: {m.num_inliers} inliers, world transform error "
          f"{100 * np.linalg.norm(e[:3, 3]):.2f} cm {np.degrees(rotation_angle_rad(e[:3, :3])):.3f} deg")
    # the first shared view is a narrow strip (76 points, 30 deg apart) with 0.5 % depth noise: measured 6 cm, 0.85 deg
    assert np.linalg.norm(e[:3, 3]) < 0.1 and np.degrees(rotation_angle_rad(e[:3, :3])) < 1.5
    # a keyframe moved to the other map after merging is found as a loop candidate there, not a merge
    closer.set_map(m.query_kf_id, 0)
    assert closer.database.map_of(m.query_kf_id) == 0


def test_global_ba_after_the_loop_refines_poses_and_points_further():
    plain = build_drifting_map(n_kf=49)
    refined = build_drifting_map(n_kf=49, global_ba=GlobalBAConfig(iterations=10))
    assert plain.loops == refined.loops == 1
    ba = refined.closing.last_global_ba
    assert ba is not None and ba.n_keyframes == refined.closing.last_correction.query_kf_id + 1 and ba.n_points > 1000
    ate_plain = rmse_position({k: plain.slam_map.keyframes[k].T_world_cam for k in plain.truth}, plain.truth)
    ate_ba = rmse_position({k: refined.slam_map.keyframes[k].T_world_cam for k in refined.truth}, refined.truth)
    print(f"global BA: reprojection RMS {ba.rms_before_px:.2f} -> {ba.rms_after_px:.2f} px over {ba.n_observations} "
          f"observations, ATE after pose graph {100 * ate_plain:.1f} cm -> after global BA {100 * ate_ba:.1f} cm")
    assert ba.rms_after_px < 0.5 * ba.rms_before_px  # measured 15.0 -> 0.72 px
    assert ate_ba < 0.7 * ate_plain  # measured 5.6 -> 1.2 cm


def test_keyframes_without_features_are_handled_quietly():
    room = SyntheticRoom(seed=3)
    closer = LoopCloser(LoopConfig(min_keyframes_in_map=0), Vocabulary.load())
    covisibility: dict[int, dict[int, int]] = {}
    for k in range(4):
        kf, _ = room.keyframe(k, room.pose(k, 48), room.pose(k, 48))
        covisibility[k] = {}
        assert closer.process(kf, covisibility, {k: k - 1 if k else None}, {}) is None
    empty = Keyframe(
        id=4, stamp_ns=0, T_world_cam=np.eye(4), camera=room.camera, keypoints_px=np.zeros((0, 2), np.float32),
        octaves=np.zeros(0, np.int8), descriptors=np.zeros((0, 32), np.uint8), depths_m=np.zeros(0, np.float32),
        point_ids=np.zeros(0, np.int64),
    )
    covisibility[4] = {}
    assert closer.process(empty, covisibility, {4: 3}, {}) is None  # an all-black frame: no words, no loop
    assert len(closer.database.bow(4)) == 0
    assert closer.relocalise(empty.keypoints_px, empty.descriptors, room.camera, {}, covisibility) is None
    closer.erase(4)
    assert 4 not in closer.database


def test_points_deactivated_later_leave_the_bow_of_keyframes_already_indexed():
    d = build_drifting_map(n_kf=12)
    kf = d.slam_map.keyframes[5]
    before = d.closing.closer.database.bow(5)
    seen = kf.point_ids[kf.point_ids >= 0]
    d.slam_map.points.active[seen[: len(seen) // 2]] = False  # an object's belief dropped: half the points
    assert d.closing.refresh_active_points(d.slam_map) >= 1
    after = d.closing.closer.database.bow(5)
    assert len(after) < 0.75 * len(before)
    kept = d.closing.closer.database.vocabulary.bow(kf.descriptors[np.isin(kf.point_ids, seen[len(seen) // 2 :])])
    np.testing.assert_array_equal(after.word_ids, kept.word_ids)
    assert d.closing.refresh_active_points(d.slam_map) == 0  # nothing changed since
