"""Bag-of-words vocabulary over binary ORB descriptors (a DBoW2-style tree, written for numpy).

A vocabulary is a tree with `branching` children per node and `depth` levels below the root. Each node holds
a 256-bit descriptor (the bitwise majority of the training descriptors that fell into it, "k-majority").
A descriptor is quantised by descending from the root to the closest child (Hamming distance) at every
level; the leaf it reaches is its *word*. Each word carries an idf weight, log(N_docs / n_docs_with_word),
learned from the training images. A keyframe's BoW vector is the tf-idf histogram of its words, L1
normalised, and two BoW vectors are compared with DBoW2's L1 score (1 for identical, 0 for disjoint).

The *direct index* gives, for every descriptor, the node it passed through at a chosen level; matching
restricted to descriptors sharing a node there is ORB-SLAM's "BoW-guided" search.

The tree is stored as flat arrays (see `Vocabulary`), so quantising 1000 descriptors is a handful of
vectorised numpy operations per level rather than a Python loop per descriptor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import MapFileError

U8 = npt.NDArray[np.uint8]
I32 = npt.NDArray[np.int32]
F32 = npt.NDArray[np.float32]

DEFAULT_VOCABULARY_PATH = Path(__file__).resolve().parents[2] / "models" / "orb_vocabulary.npz"
VOCABULARY_FORMAT_VERSION = 1
DESCRIPTOR_BYTES = 32


_FAR = np.int32(1 << 20)
"""Distance given to a padded (missing) child in the descent: above any Hamming distance (<= 256)."""


def _popcount256(x: npt.NDArray[np.uint64]) -> npt.NDArray[np.int32]:
    """Set bits of 256-bit rows x (..., 4) uint64 -> (...) int32. Four lane adds: a fraction of the time of
    `.sum(axis=-1)` over a length-4 axis."""
    c = np.bitwise_count(x)  # (..., 4) uint8, each <= 64
    out: npt.NDArray[np.int32] = c[..., 0].astype(np.int32)
    out += c[..., 1]
    out += c[..., 2]
    out += c[..., 3]
    return out


def hamming_distances(a: U8, b: U8) -> npt.NDArray[np.int32]:
    """All pairwise Hamming distances between descriptors a (N, 32) and b (M, 32) uint8 -> (N, M) int32."""
    a64 = np.ascontiguousarray(a, dtype=np.uint8).view(np.uint64)
    b64 = np.ascontiguousarray(b, dtype=np.uint8).view(np.uint64)
    x = a64[:, None, :] ^ b64[None, :, :]
    out: npt.NDArray[np.int32] = np.bitwise_count(x).sum(axis=2, dtype=np.int32)
    return out


@dataclass(frozen=True)
class BowVector:
    """A sparse tf-idf vector: `word_ids` (M,) int32 sorted and unique, `weights` (M,) float32 summing to 1."""

    word_ids: I32
    weights: F32

    def __len__(self) -> int:
        return len(self.word_ids)

    @staticmethod
    def empty() -> BowVector:
        return BowVector(np.zeros(0, np.int32), np.zeros(0, np.float32))


def l1_score(a: BowVector, b: BowVector) -> float:
    """DBoW2 L1 score 1 - 0.5 * |a - b|_1 of two L1-normalised vectors; equals sum of min(a_w, b_w) over shared words."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    _, ia, ib = np.intersect1d(a.word_ids, b.word_ids, assume_unique=True, return_indices=True)
    if len(ia) == 0:
        return 0.0
    return float(np.minimum(a.weights[ia], b.weights[ib]).sum())


@dataclass(frozen=True)
class Quantised:
    """Result of `Vocabulary.transform`: the BoW vector, each descriptor's word (N,) and its node at
    the direct-index level (N,), both int32."""

    bow: BowVector
    word_of_descriptor: I32
    node_of_descriptor: I32


class Vocabulary:
    """A trained vocabulary tree as flat arrays over M nodes (node 0 is the root, with no descriptor).

    - `node_descriptors` (M, 32) uint8: the k-majority centre of each node;
    - `children` (M, branching) int32: child node ids, -1 where a node has fewer children (or is a leaf);
    - `node_level` (M,) int8: 0 for the root, `depth` for the deepest leaves;
    - `node_word` (M,) int32: word id of a leaf node, -1 for inner nodes;
    - `word_idf` (W,) float32: idf weight of each word.
    """

    def __init__(
        self,
        branching: int,
        depth: int,
        node_descriptors: U8,
        children: I32,
        node_level: npt.NDArray[np.int8],
        node_word: I32,
        word_idf: F32,
    ) -> None:
        m = len(node_descriptors)
        if node_descriptors.shape != (m, DESCRIPTOR_BYTES) or children.shape != (m, branching):
            raise ValueError(
                f"vocabulary arrays disagree: descriptors {node_descriptors.shape}, children {children.shape}, "
                f"expected ({m}, {DESCRIPTOR_BYTES}) and ({m}, {branching})"
            )
        self.branching = int(branching)
        self.depth = int(depth)
        self.node_descriptors = np.ascontiguousarray(node_descriptors, dtype=np.uint8)
        self.children = np.ascontiguousarray(children, dtype=np.int32)
        self.node_level = np.asarray(node_level, dtype=np.int8)
        self.node_word = np.asarray(node_word, dtype=np.int32)
        self.word_idf = np.asarray(word_idf, dtype=np.float32)
        self._node_desc64 = self.node_descriptors.view(np.uint64)  # (M, 4)
        self._has_children: npt.NDArray[np.bool_] = np.asarray((self.children >= 0).any(axis=1))
        # Descent tables over the I inner nodes (those with children), so that one level of `transform` gathers
        # once: `_inner_of` (M,) row of a node in them or -1; `_inner_children` (I, branching) child ids
        # (-1 padded); `_inner_child_desc64` (I, branching, 4) their descriptors as uint64 (zeros where padded);
        # `_inner_child_penalty` (I, branching) int32, _FAR where padded (never the closest child).
        inner = np.flatnonzero(self._has_children)
        self._inner_of = np.full(m, -1, np.int32)
        self._inner_of[inner] = np.arange(len(inner), dtype=np.int32)
        self._inner_children = np.ascontiguousarray(self.children[inner])
        present = self._inner_children >= 0
        self._inner_child_desc64 = np.ascontiguousarray(self._node_desc64[np.where(present, self._inner_children, 0)])
        self._inner_child_desc64[~present] = 0
        self._inner_child_penalty = np.where(present, 0, _FAR).astype(np.int32)

    # ------------------------------------------------------------------ properties
    @property
    def num_words(self) -> int:
        return len(self.word_idf)

    @property
    def num_nodes(self) -> int:
        return len(self.node_descriptors)

    # ------------------------------------------------------------------ quantisation
    def transform(self, descriptors: U8, direct_index_level: int = 2) -> Quantised:
        """Quantise descriptors (N, 32) uint8 into a BoW vector plus per-descriptor word and direct-index node.

        `direct_index_level` counts from the root (1 = the first split); ORB-SLAM uses 4 levels up from the
        leaves of a 6-level tree, i.e. level 2.
        """
        d = np.ascontiguousarray(descriptors, dtype=np.uint8)
        n = len(d)
        if n == 0:
            z = np.zeros(0, np.int32)
            return Quantised(BowVector.empty(), z, z)
        if d.ndim != 2 or d.shape[1] != DESCRIPTOR_BYTES:
            raise ValueError(f"descriptors: expected (N, {DESCRIPTOR_BYTES}) uint8, got {d.shape}")
        d64 = d.view(np.uint64)[:, None, :]  # (N, 1, 4)
        node = np.zeros(n, np.int32)
        node_at_level = np.zeros(n, np.int32)
        for level in range(1, self.depth + 1):
            rows = self._inner_of[node]  # row in the inner-node tables, -1 at a leaf
            idx: npt.NDArray[np.intp] | None = None  # None: every descriptor descends (the usual case)
            d_rows = d64
            if rows.min() < 0:
                idx = np.flatnonzero(rows >= 0)
                if len(idx) == 0:
                    break
                rows, d_rows = rows[idx], d64[idx]
            dist = _popcount256(d_rows ^ self._inner_child_desc64[rows])  # (n_a, branching)
            dist += self._inner_child_penalty[rows]
            best = self._inner_children[rows, dist.argmin(axis=1)]
            if idx is None:
                node = best
            else:
                node[idx] = best
            if level <= direct_index_level:
                node_at_level[:] = node
        if direct_index_level <= 0:
            node_at_level[:] = node
        words = self.node_word[node]
        bow = self.bow_from_words(words)
        return Quantised(bow, words, node_at_level)

    def bow(self, descriptors: U8) -> BowVector:
        """The L1-normalised tf-idf BoW vector of descriptors (N, 32)."""
        return self.transform(descriptors).bow

    def bow_from_words(self, words: I32) -> BowVector:
        """The L1-normalised tf-idf BoW vector of per-descriptor word ids (N,) int32 (-1: no word): what
        `transform(descriptors).bow` gives for the descriptors these words came from, bit for bit (the words'
        idf weights are summed in the same order)."""
        valid = words >= 0
        if not valid.any():
            return BowVector.empty()
        w = words[valid]
        uniq, inverse = np.unique(w, return_inverse=True)
        weights = np.bincount(inverse, weights=self.word_idf[w]).astype(np.float32)
        total = float(weights.sum())
        if total <= 0.0:
            return BowVector.empty()
        return BowVector(uniq.astype(np.int32), (weights / total).astype(np.float32))

    @staticmethod
    def score(a: BowVector, b: BowVector) -> float:
        """DBoW2 L1 score in [0, 1]."""
        return l1_score(a, b)

    # ------------------------------------------------------------------ persistence (plain numpy arrays)
    def to_arrays(self) -> dict[str, npt.NDArray[np.generic]]:
        """The arrays `save`/`load` store; the npz keys are the names of `__init__`'s arguments."""
        return {
            "format_version": np.array(VOCABULARY_FORMAT_VERSION, np.int32),
            "branching": np.array(self.branching, np.int32),
            "depth": np.array(self.depth, np.int32),
            "node_descriptors": self.node_descriptors,
            "children": self.children,
            "node_level": self.node_level,
            "node_word": self.node_word,
            "word_idf": self.word_idf,
        }

    @classmethod
    def load(cls, path: str | Path = DEFAULT_VOCABULARY_PATH) -> Vocabulary:
        """Read a vocabulary written by `tools/train_vocabulary.py` (npz of `to_arrays()`)."""
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError) as err:
            raise MapFileError(f"{p}: cannot read vocabulary ({err})") from err
        missing = {"format_version", "branching", "depth", "node_descriptors", "children", "node_level",
                   "node_word", "word_idf"} - set(arrays)
        if missing:
            raise MapFileError(f"{p}: not a vocabulary file, missing array(s) {', '.join(sorted(missing))}")
        version = int(arrays["format_version"])
        if version != VOCABULARY_FORMAT_VERSION:
            raise MapFileError(f"{p}: vocabulary format version {version}, expected {VOCABULARY_FORMAT_VERSION}")
        return cls(
            int(arrays["branching"]),
            int(arrays["depth"]),
            arrays["node_descriptors"],
            arrays["children"],
            arrays["node_level"],
            arrays["node_word"],
            arrays["word_idf"],
        )


# ---------------------------------------------------------------------- training
def train_vocabulary(
    descriptors_per_image: list[U8],
    branching: int = 10,
    depth: int = 5,
    seed: int = 0,
    max_iterations: int = 10,
) -> Vocabulary:
    """Build a vocabulary by hierarchical k-majority clustering (k-means++ seeding, Hamming distance).

    `descriptors_per_image` holds one (n_i, 32) uint8 array per training image; the images are the
    documents the idf weights count. Deterministic for a given `seed`.
    """
    if branching < 2 or depth < 1:
        raise ValueError(f"branching must be >= 2 and depth >= 1, got {branching}, {depth}")
    rng = np.random.default_rng(seed)
    all_desc = np.concatenate([np.asarray(d, np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in descriptors_per_image])
    image_of = np.concatenate([np.full(len(d), i, np.int32) for i, d in enumerate(descriptors_per_image)])
    if len(all_desc) < branching:
        raise ValueError(f"need at least {branching} training descriptors, got {len(all_desc)}")

    node_desc: list[U8] = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    node_children: list[list[int]] = [[]]
    node_level: list[int] = [0]
    members: dict[int, npt.NDArray[np.int64]] = {0: np.arange(len(all_desc))}
    queue = [0]
    while queue:  # breadth first, so node ids grow level by level
        parent = queue.pop(0)
        idx = members.pop(parent)
        level = node_level[parent] + 1
        if len(idx) <= branching:
            groups = [idx[i : i + 1] for i in range(len(idx))]
            centres = [all_desc[i] for i in idx]
        else:
            centres_arr, assign = _k_majority(all_desc[idx], branching, rng, max_iterations)
            groups, centres = [], []
            for c in range(len(centres_arr)):
                g = idx[assign == c]
                if len(g):
                    groups.append(g)
                    centres.append(centres_arr[c])
        for g, centre in zip(groups, centres):
            child = len(node_desc)
            node_desc.append(np.asarray(centre, np.uint8))
            node_children.append([])
            node_level.append(level)
            node_children[parent].append(child)
            if level < depth and len(g) > 1:
                members[child] = g
                queue.append(child)
            else:
                members[child] = g  # kept for the idf count below
    m = len(node_desc)
    children = np.full((m, branching), -1, np.int32)
    for i, ch in enumerate(node_children):
        children[i, : len(ch)] = ch
    is_leaf: npt.NDArray[np.bool_] = np.asarray((children < 0).all(axis=1))
    is_leaf[0] = False
    node_word = np.full(m, -1, np.int32)
    leaves = np.nonzero(is_leaf)[0]
    node_word[leaves] = np.arange(len(leaves), dtype=np.int32)
    n_docs = len(descriptors_per_image)
    docs_with_word = np.array([len(np.unique(image_of[members[int(leaf)]])) for leaf in leaves], np.float64)
    word_idf = np.log(n_docs / np.maximum(docs_with_word, 1.0)).astype(np.float32)
    return Vocabulary(
        branching, depth, np.stack(node_desc), children, np.array(node_level, np.int8), node_word, word_idf
    )


def _k_majority(
    desc: U8, k: int, rng: np.random.Generator, max_iterations: int
) -> tuple[U8, npt.NDArray[np.int64]]:
    """Cluster descriptors (n, 32) into k groups: k-means++ seeds, then assign / bitwise-majority update.

    Returns centres (k, 32) uint8 and assignments (n,)."""
    n = len(desc)
    centres = np.empty((k, DESCRIPTOR_BYTES), np.uint8)
    centres[0] = desc[rng.integers(n)]
    nearest = _min_distances(desc, centres[:1]).astype(np.float64)
    for c in range(1, k):
        w = nearest**2
        total = w.sum()
        pick = rng.integers(n) if total <= 0 else rng.choice(n, p=w / total)
        centres[c] = desc[pick]
        nearest = np.minimum(nearest, _min_distances(desc, centres[c : c + 1]))
    bits = np.unpackbits(desc, axis=1)  # (n, 256)
    assign = np.full(n, -1, np.int64)
    for _ in range(max_iterations):
        new_assign = _argmin_distances(desc, centres)
        if np.array_equal(new_assign, assign):
            break
        assign = new_assign
        for c in range(k):
            sel = assign == c
            cnt = int(sel.sum())
            if cnt:
                centres[c] = np.packbits(2 * bits[sel].sum(axis=0, dtype=np.int64) > cnt)
    return centres, assign


def _min_distances(desc: U8, centres: U8, chunk: int = 65536) -> npt.NDArray[np.float64]:
    out = np.empty(len(desc), np.float64)
    for s in range(0, len(desc), chunk):
        out[s : s + chunk] = hamming_distances(desc[s : s + chunk], centres).min(axis=1)
    return out


def _argmin_distances(desc: U8, centres: U8, chunk: int = 65536) -> npt.NDArray[np.int64]:
    out = np.empty(len(desc), np.int64)
    for s in range(0, len(desc), chunk):
        out[s : s + chunk] = hamming_distances(desc[s : s + chunk], centres).argmin(axis=1)
    return out
