"""Semantic map files: build from MapObjects, write-then-read (JSON and YAML), corrupt files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.semantic_map_file import (
    read_object_map, read_semantic_map, write_object_map, write_semantic_map,
)


def _objects() -> list[MapObject]:
    rng = np.random.default_rng(0)
    out = []
    for oid, cls, centre, belief in ((3, 56, [1.0, 2.0, 0.45], 0.9), (1, 62, [-1.0, 0.5, 1.0], 0.75),
                                     (2, 41, [0.0, 0.0, 0.8], 0.2)):
        pts = np.asarray(centre) + rng.uniform(-0.2, 0.2, (30, 3))
        out.append(MapObject(oid, cls, (1, 2, 30, 40), (5, 6, 35, 46), 2, 9, belief=belief, active=belief >= 0.6,
                             point_ids=np.arange(30) + 100 * oid, points_w=pts))
    return out


def test_semantic_map_keeps_only_high_belief_objects_ordered_by_id() -> None:
    smap = build_semantic_map(_objects(), ObjectMapConfig(belief_threshold=0.6), min_belief=0.6)
    assert [(o.id, o.class_name) for o in smap.objects] == [(1, "tv"), (3, "chair")]
    chair = smap.by_id(3)
    assert chair is not None and chair.n_points == 30 and chair.belief == 0.9
    assert chair.centroid_w == pytest.approx(tuple(_objects()[0].centroid_w))
    assert all(0.3 < s < 0.41 for s in chair.box_size_m)
    everything = build_semantic_map(_objects(), ObjectMapConfig(), include_inactive=True)
    assert [o.id for o in everything.objects] == [1, 2, 3]


@pytest.mark.parametrize("name", ["map.json", "map.yaml"])
def test_write_then_read_round_trip(tmp_path: Path, name: str) -> None:
    smap = build_semantic_map(_objects(), ObjectMapConfig(), include_inactive=True)
    write_semantic_map(tmp_path / name, smap)
    back = read_semantic_map(tmp_path / name)
    assert back == smap  # frozen dataclasses of floats: exact (JSON and YAML keep repr precision)
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary file left behind


def _write(tmp_path: Path, doc: object) -> Path:
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(doc))
    return p


def test_corrupt_files_raise_map_file_errors_naming_file_and_field(tmp_path: Path) -> None:
    good = tmp_path / "good.json"
    write_semantic_map(good, build_semantic_map(_objects(), ObjectMapConfig()))
    doc = json.loads(good.read_text())

    truncated = tmp_path / "truncated.json"
    truncated.write_text(good.read_text()[:50])
    with pytest.raises(MapFileError, match=r"truncated\.json: not valid JSON"):
        read_semantic_map(truncated)
    with pytest.raises(MapFileError, match=r"missing\.json: cannot read semantic map"):
        read_semantic_map(tmp_path / "missing.json")
    with pytest.raises(MapFileError, match=r"bad\.json: version: expected 1, got 7"):
        read_semantic_map(_write(tmp_path, {**doc, "version": 7}))
    with pytest.raises(MapFileError, match=r"bad\.json: format"):
        read_semantic_map(_write(tmp_path, {**doc, "format": "something else"}))
    broken = json.loads(json.dumps(doc))
    broken["objects"][1]["centroid_m"] = [1.0, "x", 2.0]
    with pytest.raises(MapFileError, match=r"bad\.json: objects\[1\]\.centroid_m: expected 3 finite numbers"):
        read_semantic_map(_write(tmp_path, broken))
    broken = json.loads(json.dumps(doc))
    del broken["objects"][0]["belief"]
    with pytest.raises(MapFileError, match=r"objects\[0\]\.belief: missing"):
        read_semantic_map(_write(tmp_path, broken))
    broken = json.loads(json.dumps(doc))
    broken["objects"][0]["belief"] = 1.5
    with pytest.raises(MapFileError, match=r"objects\[0\]\.belief: expected within \[0, 1\]"):
        read_semantic_map(_write(tmp_path, broken))
    broken = json.loads(json.dumps(doc))
    broken["objects"][1]["id"] = broken["objects"][0]["id"]
    with pytest.raises(MapFileError, match="duplicated ids"):
        read_semantic_map(_write(tmp_path, broken))
    with pytest.raises(MapFileError, match="expected a mapping at top level"):
        read_semantic_map(_write(tmp_path, [1, 2]))


def test_object_map_round_trip_keeps_points_and_persistence_state(tmp_path: Path) -> None:
    objs = _objects()
    objs[0].last_belief_update_keyframe = 7
    objs[0].n_observations = 4
    write_object_map(tmp_path / "objects.json", objs)
    back = {o.id: o for o in read_object_map(tmp_path / "objects.json")}
    assert sorted(back) == [1, 2, 3]
    for o in objs:
        b = back[o.id]
        assert (b.class_id, b.belief, b.active, b.first_keyframe, b.last_seen_keyframe) == \
            (o.class_id, o.belief, o.active, o.first_keyframe, o.last_seen_keyframe)
        assert b.first_box_xyxy == o.first_box_xyxy and b.current_box_xyxy == o.current_box_xyxy
        np.testing.assert_array_equal(b.point_ids, o.point_ids)
        np.testing.assert_array_equal(b.points_w, o.points_w)  # repr-exact floats
        np.testing.assert_array_equal(b.centroid_w, o.centroid_w)
    assert (back[3].last_belief_update_keyframe, back[3].n_observations) == (7, 4)
    doc = json.loads((tmp_path / "objects.json").read_text())
    doc["objects"][2]["points"][5] = [1, 2, "x", 4]
    with pytest.raises(MapFileError, match=r"objects\[2\]\.points: expected a list of \[id, x, y, z\]"):
        read_object_map(_write(tmp_path, doc))
    doc = json.loads((tmp_path / "objects.json").read_text())
    del doc["objects"][0]["current_box_xyxy"]
    with pytest.raises(MapFileError, match=r"objects\[0\]\.current_box_xyxy: expected 4 numbers"):
        read_object_map(_write(tmp_path, doc))
    with pytest.raises(MapFileError, match="format: expected 'changing_slam_ros object map'"):
        read_object_map(_write(tmp_path, {"format": "changing_slam_ros semantic map", "version": 1, "objects": []}))
