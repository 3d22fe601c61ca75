"""moving_objects.json and the per-object TUM files: round trip and clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack
from changing_slam_ros.core.geometry.se3 import make_pose
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.moving_objects_file import read_moving_objects, write_moving_objects


def _track(obj_id: int, n: int, class_id: int = -1) -> MovingObjectTrack:
    c, s = np.cos(0.1), np.sin(0.1)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    poses = np.stack([make_pose(np.linalg.matrix_power(rot, k), np.array([0.01 * k, 0.5, 1.0])) for k in range(n)])
    return MovingObjectTrack(obj_id, class_id, 1_000_000_000 + 33_333_000 * np.arange(n, dtype=np.int64), poses, 40)


def test_moving_objects_round_trip(tmp_path: Path) -> None:
    tracks = [_track(3, 12), _track(7, 5, class_id=56)]
    summary = write_moving_objects(tmp_path, tracks)
    assert summary == {"file": "moving_objects.json", "objects": 2, "poses": 17}
    doc = json.loads((tmp_path / "moving_objects.json").read_text())
    assert [o["id"] for o in doc["objects"]] == [3, 7]
    assert doc["objects"][0]["first_stamp_ns"] == 1_000_000_000 and doc["objects"][1]["class_id"] == 56
    assert (tmp_path / "moving_objects" / "object_3.txt").exists()
    back = read_moving_objects(tmp_path / "moving_objects.json")
    for a, b in zip(tracks, back):
        assert (a.object_id, a.class_id, a.n_points) == (b.object_id, b.class_id, b.n_points)
        assert np.array_equal(a.stamps_ns, b.stamps_ns)
        assert np.allclose(a.T_world_obj, b.T_world_obj, atol=1e-8)
    assert not list(tmp_path.glob("**/*.tmp*"))  # atomic writes leave no temporaries


def test_bad_index_names_the_file_and_field(tmp_path: Path) -> None:
    write_moving_objects(tmp_path, [_track(1, 4)])
    index = tmp_path / "moving_objects.json"
    doc = json.loads(index.read_text())
    del doc["objects"][0]["class_id"]
    index.write_text(json.dumps(doc))
    with pytest.raises(EvalError, match=r"moving_objects.json: objects\[0\]"):
        read_moving_objects(index)
    index.write_text('{"format": "something else"}')
    with pytest.raises(EvalError, match="format"):
        read_moving_objects(index)


def test_track_rejects_unordered_stamps_and_wrong_shapes() -> None:
    good = _track(1, 3)
    with pytest.raises(ValueError, match="increasing"):
        MovingObjectTrack(1, -1, good.stamps_ns[::-1].copy(), good.T_world_obj, 1)
    with pytest.raises(ValueError, match="T_world_obj"):
        MovingObjectTrack(1, -1, good.stamps_ns, good.T_world_obj[:2], 1)
