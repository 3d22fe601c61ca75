#!/usr/bin/env python3
"""Write the shipped ORB vocabulary (changing_slam_ros/models/orb_vocabulary.npz) as a DBoW2 text vocabulary, the
format ORB-SLAM3 loads (`ORBvoc.txt`), for the side-by-side benchmark `bench/bench_orbslam3.py`.

ORB-SLAM3's own vocabulary is a download; this one is derived from images we may redistribute (see
`tools/train_vocabulary.py` and `models/PROVENANCE.md`), so the comparison needs nothing from the network. The same
tree is written: branching k and depth L in the header with L1 scoring and TF-IDF weighting (`k L 0 0`), then one
line per node after the root, parents before children, each `parent is_leaf d0 .. d31 weight` (the 32 descriptor
bytes as integers; the word's idf as the weight of a leaf, 0 for an inner node). Node ids are the line numbers, the
root 0. No newline after the last line: the loader reads until end of file and would take an empty line for a
node. Deterministic: the same vocabulary gives the same file (its SHA-256 is printed, to pin it in results).

    .venv/bin/python tools/orbslam3_vocabulary.py --out /tmp/orbslam3/vocabulary.txt
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from collections import deque
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.io.atomic import atomic_write_bytes  # noqa: E402

DEFAULT_VOCABULARY = REPO / "changing_slam_ros" / "models" / "orb_vocabulary.npz"


def dbow2_text(vocabulary_npz: Path) -> str:
    """The DBoW2 text form of a vocabulary file of ours (`core.features.vocabulary`)."""
    with np.load(vocabulary_npz) as d:
        k, depth = int(d["branching"]), int(d["depth"])
        desc, children = d["node_descriptors"], d["children"]
        word, idf = d["node_word"], d["word_idf"]
    if not (1 < k <= 20 and 1 <= depth <= 10):  # the loader refuses other trees
        raise SystemExit(f"{vocabulary_npz}: branching {k} / depth {depth} outside DBoW2's 2-20 / 1-10")
    if len(desc) > (k ** (depth + 1) - 1) // (k - 1):  # it reserves this many nodes and keeps pointers into them
        raise SystemExit(f"{vocabulary_npz}: {len(desc)} nodes, more than a {k}-ary tree of depth {depth} holds")
    lines = [f"{k} {depth} 0 0"]
    file_id = {0: 0}
    queue = deque([0])
    while queue:  # breadth first: a parent's line comes before its children's
        node = queue.popleft()
        for child in children[node]:
            if child < 0:
                continue
            child = int(child)
            file_id[child] = len(file_id)
            leaf = word[child] >= 0
            weight = float(idf[word[child]]) if leaf else 0.0
            lines.append(f"{file_id[node]} {int(leaf)} {' '.join(map(str, desc[child].tolist()))} {weight:.6f}")
            queue.append(child)
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vocabulary", type=Path, default=DEFAULT_VOCABULARY, help="our vocabulary (.npz)")
    parser.add_argument("--out", type=Path, required=True, help="the DBoW2 text file to write")
    a = parser.parse_args(argv)
    text = dbow2_text(a.vocabulary).encode()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(a.out, text)
    n = text.count(b"\n")
    print(f"wrote {a.out}: {n} nodes, sha256 {hashlib.sha256(text).hexdigest()[:16]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
