"""Keyframe database: an inverted index word -> keyframes over BoW vectors (ORB-SLAM's KeyFrameDatabase).

Queries follow ORB-SLAM2 `DetectLoopCandidates` / `DetectRelocalizationCandidates`:
1. keyframes sharing at least one word with the query (excluding its covisible keyframes for loops);
2. keep those sharing more than 80 % of the best shared-word count, score them (L1), drop scores < min_score;
3. accumulate each survivor's score with its best covisible keyframes that also scored ("covisibility
   groups"), and return the best keyframe of every group whose accumulated score exceeds 75 % of the best.

Keyframes carry a `map_id` (ORB-SLAM3 Atlas): loop candidates come from the query's own map; relocalisation
and merge queries can name the map. Features can be left out of a keyframe's BoW with a mask (dynamic
keypoints, or points of MapObjects whose belief dropped - Changing-SLAM §4.6). Each keyframe is quantised
once (`KeyframeWords`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from itertools import chain
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.map.keyframe import Keyframe, KeypointClass
from changing_slam_ros.core.features.vocabulary import I32, U8, BowVector, Quantised, Vocabulary, l1_score

Covisibility = Mapping[int, Iterable[int]]
"""keyframe id -> covisible keyframe ids, best (most shared points) first where the caller knows the order."""


@dataclass(frozen=True)
class PlaceCandidate:
    """A keyframe proposed by the database: its own `score` with the query and its group's `accumulated_score`."""

    keyframe_id: int
    score: float
    accumulated_score: float


@dataclass(frozen=True)
class KeyframeWords:
    """A keyframe's quantisation, every descriptor (N,): `words` and direct-index `nodes` (int32), and the
    `descriptors` (N, 32) they were computed from (a keyframe re-added with other descriptors is quantised again).

    A keyframe's descriptors never change, so the database quantises each keyframe once and keeps the word (and
    direct-index node) of every descriptor: re-indexing under a new mask is a tf-idf histogram over the masked
    words, equal bit for bit to quantising the masked descriptors again."""

    descriptors: U8
    words: I32
    nodes: I32

    def matches(self, descriptors: U8) -> bool:
        return self.descriptors is descriptors or (
            self.descriptors.shape == descriptors.shape and np.array_equal(self.descriptors, descriptors)
        )


def loop_feature_mask(kf: Keyframe, inactive_object_ids: Iterable[int] = ()) -> npt.NDArray[np.bool_]:
    """Which keypoints of `kf` (N,) may describe the place: not DYNAMIC, not UNUSED, not on an inactive object."""
    classes = np.asarray(kf.kp_classes)
    mask: npt.NDArray[np.bool_] = (classes != KeypointClass.DYNAMIC) & (classes != KeypointClass.UNUSED)
    inactive = np.fromiter(inactive_object_ids, np.int64)
    if len(inactive):
        mask &= ~np.isin(kf.object_ids, inactive)
    return mask


class KeyframeDatabase:
    """Inverted index over keyframe BoW vectors; owns nothing but ids, vectors and map ids."""

    def __init__(self, vocabulary: Vocabulary, group_size: int = 10) -> None:
        self.vocabulary = vocabulary
        self.group_size = group_size
        self._postings: dict[int, set[int]] = {}
        self._bow: dict[int, BowVector] = {}
        self._map_of: dict[int, int] = {}
        self._words: dict[int, KeyframeWords] = {}  # per indexed keyframe, all its descriptors quantised once

    def __len__(self) -> int:
        return len(self._bow)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._bow

    def add(self, kf: Keyframe, active_mask: npt.NDArray[np.bool_] | None = None) -> Quantised:
        """Index the keyframe with the BoW vector of `kf.descriptors[active_mask]`; returns that quantisation
        (BoW vector, per-descriptor word and direct-index node for the *kept* descriptors). Re-adding a
        keyframe (a new mask) reuses its words: only the histogram is recomputed."""
        kw = self.words(kf)
        if active_mask is None:
            words, nodes = kw.words, kw.nodes
        else:
            keep = np.asarray(active_mask, bool)
            words, nodes = kw.words[keep], kw.nodes[keep]
        bow = self.vocabulary.bow_from_words(words)
        self.add_bow(kf.id, bow, kf.map_id)
        self._words[kf.id] = kw
        return Quantised(bow, words, nodes)

    def words(self, kf: Keyframe) -> KeyframeWords:
        """Every descriptor of `kf` quantised: the database's copy when it holds one for these descriptors."""
        kw = self._words.get(kf.id)
        if kw is not None and kw.matches(kf.descriptors):
            return kw
        q = self.vocabulary.transform(kf.descriptors)
        return KeyframeWords(kf.descriptors, q.word_of_descriptor, q.node_of_descriptor)

    def add_bow(self, kf_id: int, bow: BowVector, map_id: int = 0) -> None:
        """Index a keyframe from an already computed BoW vector (re-adding replaces the old entry; words kept
        by `add` for this id stay, and are checked against the descriptors on the next `add`)."""
        old = self._bow.get(kf_id)
        if old is None:
            gained = bow.word_ids
        else:  # a new mask changes a few words: only their postings change
            self._drop_postings(kf_id, np.setdiff1d(old.word_ids, bow.word_ids, assume_unique=True))
            gained = np.setdiff1d(bow.word_ids, old.word_ids, assume_unique=True)
        self._bow[kf_id] = bow
        self._map_of[kf_id] = map_id
        for w in gained.tolist():
            self._postings.setdefault(w, set()).add(kf_id)

    def erase(self, kf_id: int) -> None:
        """Remove a keyframe (culled by local mapping); unknown ids are ignored."""
        self._words.pop(kf_id, None)
        self._unindex(kf_id)

    def _unindex(self, kf_id: int) -> None:
        bow = self._bow.pop(kf_id, None)
        self._map_of.pop(kf_id, None)
        if bow is not None:
            self._drop_postings(kf_id, bow.word_ids)

    def _drop_postings(self, kf_id: int, word_ids: I32) -> None:
        for w in word_ids.tolist():
            s = self._postings.get(w)
            if s is not None:
                s.discard(kf_id)
                if not s:
                    del self._postings[w]

    def set_map(self, kf_id: int, map_id: int) -> None:
        """Move a keyframe to another map (after a map merge)."""
        if kf_id in self._map_of:
            self._map_of[kf_id] = map_id

    def bow(self, kf_id: int) -> BowVector:
        return self._bow[kf_id]

    def map_of(self, kf_id: int) -> int:
        return self._map_of[kf_id]

    # ------------------------------------------------------------------ queries
    def loop_candidates(
        self,
        kf_id: int,
        covisible_ids: Iterable[int],
        min_score: float,
        covisibility: Covisibility,
    ) -> list[PlaceCandidate]:
        """Loop candidates for indexed keyframe `kf_id` in its own map, never one of `covisible_ids`.

        `min_score` is ORB-SLAM's: the lowest score between the keyframe and its covisible keyframes.
        """
        excluded = set(covisible_ids) | {kf_id}
        map_id = self._map_of[kf_id]
        return self._query(self._bow[kf_id], excluded, min_score, covisibility, map_id)

    def relocalisation_candidates(
        self, frame_bow: BowVector, covisibility: Covisibility, map_id: int | None = None
    ) -> list[PlaceCandidate]:
        """Keyframes that look like a frame (BoW vector), best first; `map_id` None searches every map."""
        return self._query(frame_bow, set(), 0.0, covisibility, map_id)

    def merge_candidates(self, kf_id: int, covisibility: Covisibility, min_score: float = 0.0) -> list[PlaceCandidate]:
        """Keyframes of *other* maps that look like indexed keyframe `kf_id` (ORB-SLAM3 map merging)."""
        return self._query(self._bow[kf_id], {kf_id}, min_score, covisibility, None, exclude_map=self._map_of[kf_id])

    def _query(
        self,
        bow: BowVector,
        excluded: set[int],
        min_score: float,
        covisibility: Covisibility,
        map_id: int | None,
        exclude_map: int | None = None,
    ) -> list[PlaceCandidate]:
        # 1. shared-word counts over the inverted index
        postings = self._postings
        counts = Counter(chain.from_iterable(postings.get(w, ()) for w in bow.word_ids.tolist()))
        common = {
            k: n for k, n in counts.items()
            if k not in excluded
            and (map_id is None or self._map_of[k] == map_id)
            and (exclude_map is None or self._map_of[k] != exclude_map)
        }
        if not common:
            return []
        # 2. keep keyframes sharing > 80 % of the best count, with score >= min_score
        min_common = 0.8 * max(common.values())
        scores: dict[int, float] = {}
        for other, n in common.items():
            if n > min_common:
                s = l1_score(bow, self._bow[other])
                if s >= min_score:
                    scores[other] = s
        if not scores:
            return []
        # 3. covisibility groups: accumulate scores, keep groups above 75 % of the best group
        groups: list[PlaceCandidate] = []
        for other, s in scores.items():
            best_id, best_s, acc = other, s, s
            neighbours = list(covisibility.get(other, ()))[: self.group_size]
            for nb in neighbours:
                if nb in scores and common.get(nb, 0) > min_common:
                    acc += scores[nb]
                    if scores[nb] > best_s:
                        best_id, best_s = nb, scores[nb]
            groups.append(PlaceCandidate(best_id, best_s, acc))
        best_acc = max(g.accumulated_score for g in groups)
        out: dict[int, PlaceCandidate] = {}
        for g in sorted(groups, key=lambda g: (-g.accumulated_score, g.keyframe_id)):
            if g.accumulated_score > 0.75 * best_acc and g.keyframe_id not in out:
                out[g.keyframe_id] = g
        return list(out.values())
