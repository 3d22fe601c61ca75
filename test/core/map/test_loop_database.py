"""Keyframe database queries, candidate consistency and relocalisation on real frames."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FR1_XYZ_10, REDKITCHEN, require

from changing_slam_ros.core.map.keyframe import Keyframe, KeypointClass
from changing_slam_ros.core.map.keyframe_database import KeyframeDatabase, PlaceCandidate, loop_feature_mask
from changing_slam_ros.core.features.orb_features import FeatureConfig, OrbExtractor
from changing_slam_ros.core.slam.place_recognition import ConsistencyChecker, relocalise
from changing_slam_ros.core.geometry.se3 import invert, rotation_angle_rad
from changing_slam_ros.core.features.vocabulary import Vocabulary, l1_score
from changing_slam_ros.io.dataset import open_dataset


def keyframes_from(folder, config_name: str, indices: list[int], first_id: int = 0, map_id: int = 0) -> list[Keyframe]:
    """Keyframes (features + depth, ground-truth pose) of the given frames of a TUM-layout folder."""
    source = open_dataset(folder, config_name)
    extractor = OrbExtractor(FeatureConfig(), source.camera)
    out = []
    for n, i in enumerate(indices):
        frame = source.frame(i)
        f = extractor.extract(frame.rgb, frame.depth_m)
        out.append(
            Keyframe(
                id=first_id + n, stamp_ns=frame.stamp_ns, T_world_cam=frame.T_world_cam_gt, camera=source.camera,
                keypoints_px=f.keypoints_px.astype(np.float32), octaves=f.octaves.astype(np.int8),
                descriptors=f.descriptors, depths_m=f.depths_m.astype(np.float32),
                point_ids=np.full(len(f), -1, np.int64), map_id=map_id,
            )
        )
    return out


@pytest.fixture(scope="module")
def vocab() -> Vocabulary:
    return Vocabulary.load()


@pytest.fixture(scope="module")
def fr1() -> list[Keyframe]:
    return keyframes_from(require(FR1_XYZ_10), "tum_fr1", list(range(9)))


@pytest.fixture(scope="module")
def kitchen() -> list[Keyframe]:
    # ids 100.. ; frames far apart in the kitchen walk
    return keyframes_from(require(REDKITCHEN), "7scenes", [0, 150, 300, 450], first_id=100, map_id=1)


def test_relocalisation_candidates_come_from_the_same_place(vocab, fr1, kitchen):
    db = KeyframeDatabase(vocab)
    for kf in fr1[::2] + kitchen:
        db.add(kf)
    query = vocab.bow(fr1[3].descriptors)
    cands = db.relocalisation_candidates(query, covisibility={})
    assert cands and all(c.keyframe_id in {0, 2, 4, 6, 8} for c in cands)
    # restricted to the kitchen map, nothing there looks like fr1 as much
    kitchen_only = db.relocalisation_candidates(query, covisibility={}, map_id=1)
    assert all(c.keyframe_id >= 100 for c in kitchen_only)
    assert max(c.score for c in kitchen_only) < 0.5 * max(c.score for c in cands)


def test_loop_candidates_skip_covisible_keyframes_and_respect_min_score(vocab, fr1):
    db = KeyframeDatabase(vocab)
    for kf in fr1:
        db.add(kf)
    covisible = [7, 6]
    cands = db.loop_candidates(8, covisible, min_score=0.0, covisibility={})
    ids = {c.keyframe_id for c in cands}
    assert ids and not ids & {8, 7, 6}
    best = max(c.score for c in cands)
    assert db.loop_candidates(8, covisible, min_score=best + 1e-3, covisibility={}) == []


def test_covisibility_groups_accumulate_scores_and_return_each_groups_best(vocab, fr1):
    db = KeyframeDatabase(vocab)
    for kf in fr1:
        db.add(kf)
    scores = {k: l1_score(db.bow(8), db.bow(k)) for k in range(6)}
    covisibility = {k: [j for j in range(6) if j != k] for k in range(6)}  # one group: 0..5
    cands = db.loop_candidates(8, [7, 6], min_score=0.0, covisibility=covisibility)
    # every member reports the group's best keyframe; the accumulated score sums the members that scored
    assert len(cands) == 1
    assert cands[0].keyframe_id == max(scores, key=scores.get)
    assert cands[0].accumulated_score > cands[0].score


def test_erase_and_masks_remove_words_from_the_index(vocab, fr1):
    db = KeyframeDatabase(vocab)
    kf = fr1[0]
    classes = np.full(len(kf), KeypointClass.STATIC, np.int8)
    classes[: len(kf) // 2] = KeypointClass.DYNAMIC
    dynamic = Keyframe(**{**kf.__dict__, "id": 50, "kp_classes": classes})
    mask = loop_feature_mask(dynamic)
    assert mask.sum() == len(kf) - len(kf) // 2
    q = db.add(dynamic, mask)
    np.testing.assert_array_equal(q.bow.word_ids, vocab.bow(kf.descriptors[mask]).word_ids)
    assert len(q.word_of_descriptor) == mask.sum()
    # objects whose belief dropped are excluded too
    objects = np.where(np.arange(len(kf)) % 3 == 0, 7, -1)
    with_obj = Keyframe(**{**kf.__dict__, "id": 51, "object_ids": objects})
    assert loop_feature_mask(with_obj, inactive_object_ids=[7]).sum() == np.sum(objects != 7)
    db.erase(50)
    assert 50 not in db and len(db) == 0
    assert db.relocalisation_candidates(vocab.bow(kf.descriptors), covisibility={}) == []


def _same_bow(a, b) -> bool:
    return a.word_ids.tobytes() == b.word_ids.tobytes() and a.weights.tobytes() == b.weights.tobytes()


def test_reindexing_from_cached_words_equals_quantising_the_masked_descriptors(vocab, fr1, kitchen):
    """Each keyframe is quantised once; re-adding it under a new mask (points deactivated, classes changed)
    builds the BoW from its cached words. Vectors and every query must equal a database fed with
    `vocabulary.bow(descriptors[mask])`, the computation the cache replaces, on real frames."""
    keyframes = fr1 + kitchen
    cached, reference = KeyframeDatabase(vocab), KeyframeDatabase(vocab)
    rng = np.random.default_rng(0)
    masks = {kf.id: np.ones(len(kf), bool) for kf in keyframes}
    covisibility = {kf.id: [o.id for o in keyframes if o.id != kf.id and o.map_id == kf.map_id][:3] for kf in keyframes}
    quantised = 0
    real_transform = vocab.transform

    def counting_transform(*args, **kwargs):
        nonlocal quantised
        quantised += 1
        return real_transform(*args, **kwargs)

    for round_ in range(4):  # round 0 indexes; later rounds drop (and bring back) random features
        for kf in keyframes:
            if round_:
                masks[kf.id] = rng.random(len(kf)) < 0.7
            vocab.transform = counting_transform  # instance attribute: only this test's calls
            try:
                q = cached.add(kf, masks[kf.id])
            finally:
                del vocab.transform
            expected = vocab.transform(kf.descriptors[masks[kf.id]])
            reference.add_bow(kf.id, expected.bow, kf.map_id)
            assert _same_bow(q.bow, expected.bow) and _same_bow(cached.bow(kf.id), expected.bow)
            np.testing.assert_array_equal(q.word_of_descriptor, expected.word_of_descriptor)
            np.testing.assert_array_equal(q.node_of_descriptor, expected.node_of_descriptor)
        for kf in keyframes:
            assert cached.loop_candidates(kf.id, covisibility[kf.id], 0.0, covisibility) == \
                reference.loop_candidates(kf.id, covisibility[kf.id], 0.0, covisibility)
            assert cached.merge_candidates(kf.id, covisibility) == reference.merge_candidates(kf.id, covisibility)
        for kf in keyframes[::3]:
            query = vocab.bow(kf.descriptors)
            found = cached.relocalisation_candidates(query, covisibility)
            assert found and found == reference.relocalisation_candidates(query, covisibility)
    assert quantised == len(keyframes)  # once per keyframe, whatever the masks did
    # a keyframe re-added with other descriptors under the same id is quantised again; erase forgets it
    other = Keyframe(**{**fr1[0].__dict__, "descriptors": np.bitwise_not(fr1[0].descriptors)})
    assert _same_bow(cached.add(other).bow, vocab.bow(other.descriptors))
    cached.erase(other.id)
    assert other.id not in cached and _same_bow(cached.add(fr1[0]).bow, vocab.bow(fr1[0].descriptors))


def test_consistency_checker_accepts_after_three_consistent_keyframes_and_resets():
    chk = ConsistencyChecker(threshold=3)
    cov = {10: [11], 11: [10, 12], 12: [11], 40: [41], 41: [40]}
    c = lambda k: PlaceCandidate(k, 0.1, 0.2)  # noqa: E731
    assert chk.update([c(10)], cov) == []  # count 0
    assert chk.update([c(11)], cov) == []  # shares 10/11: count 1
    assert chk.update([c(12), c(40)], cov) == []  # count 2; 40 starts its own group
    assert [x.keyframe_id for x in chk.update([c(11), c(41)], cov)] == [11]  # count 3 -> accepted
    chk.update([c(40)], cov)  # the 10-12 group is not seen: its count is lost
    assert chk.update([c(12)], cov) == []


def test_relocalisation_recovers_the_pose_of_a_frame_not_in_the_map(vocab, fr1, kitchen):
    db = KeyframeDatabase(vocab)
    keyframes, points = {}, {}
    for kf in [fr1[0], fr1[2], fr1[6], fr1[8]]:  # a map built from ground-truth poses and depth
        kf = Keyframe(**{**kf.__dict__, "point_ids": kf.point_ids.copy()})
        for i in np.flatnonzero(kf.depths_m > 0):
            pid = len(points)
            kf.point_ids[i] = pid
            p = kf.camera.backproject(kf.keypoints_px[i : i + 1].astype(np.float64), kf.depths_m[i : i + 1].astype(np.float64))[0]
            points[pid] = kf.T_world_cam[:3, :3] @ p + kf.T_world_cam[:3, 3]
        keyframes[kf.id] = kf
        db.add(kf)
    covisibility = {k: [j for j in keyframes if j != k] for k in keyframes}
    lost = fr1[4]
    r = relocalise(lost.keypoints_px, lost.descriptors, lost.camera, db, keyframes, points, covisibility)
    assert r is not None
    e = invert(lost.T_world_cam) @ r.T_world_cam
    print(f"relocalised with {r.num_inliers} inliers: {100 * np.linalg.norm(e[:3, 3]):.2f} cm, "
          f"{np.degrees(rotation_angle_rad(e[:3, :3])):.2f} deg")
    assert r.num_inliers > 100
    assert np.linalg.norm(e[:3, 3]) < 0.015 and np.degrees(rotation_angle_rad(e[:3, :3])) < 1.5
    # a frame from another place does not relocalise
    other = kitchen[1]
    assert relocalise(other.keypoints_px, other.descriptors, other.camera, db, keyframes, points, covisibility) is None
