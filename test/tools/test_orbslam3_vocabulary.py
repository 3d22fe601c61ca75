"""tools/orbslam3_vocabulary.py writes the shipped vocabulary as the DBoW2 text file ORB-SLAM3 loads: read back the
way DBoW2 reads it (node ids are line numbers, parents first), it is the same tree with the same words and weights."""

from __future__ import annotations

import importlib.util

import numpy as np

from helpers import REPO


def _tool():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("orbslam3_vocabulary", REPO / "tools" / "orbslam3_vocabulary.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_the_dbow2_text_is_the_shipped_tree_read_back_as_dbow2_reads_it() -> None:
    tool = _tool()
    text = tool.dbow2_text(tool.DEFAULT_VOCABULARY)
    assert not text.endswith("\n")  # the loader would take a trailing empty line for a node
    lines = text.split("\n")
    k, depth, scoring, weighting = map(int, lines[0].split())
    with np.load(tool.DEFAULT_VOCABULARY) as d:
        assert (k, depth) == (int(d["branching"]), int(d["depth"])) and (scoring, weighting) == (0, 0)
        n_nodes, idf = len(d["node_descriptors"]), d["word_idf"]
        ours = {tuple(row) for row in d["node_descriptors"][1:]}
    parents, leaves, weights, level = [], 0, [], [0]
    for nid, line in enumerate(lines[1:], start=1):
        fields = line.split()
        assert len(fields) == 2 + 32 + 1
        parent, leaf = int(fields[0]), int(fields[1])
        assert 0 <= parent < nid  # a parent is defined before its children
        level.append(level[parent] + 1)
        assert tuple(int(v) for v in fields[2:34]) in ours
        parents.append(parent)
        if leaf:
            leaves += 1
            weights.append(float(fields[34]))
        else:
            assert float(fields[34]) == 0.0
    assert len(lines) == n_nodes and len(lines) - 1 <= (k ** (depth + 1) - 1) // (k - 1)
    assert max(np.bincount(parents)) <= k and max(level) == depth
    assert leaves == len(idf)
    np.testing.assert_allclose(sorted(weights), sorted(idf.tolist()), atol=1e-6)
