"""`changing-slam changes`: two object-map files in, the change report and its plan out."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.cli import main
from changing_slam_ros.io.semantic_map_file import write_object_map
from object_maps import changed_room_maps


def test_changes_command_writes_json_and_plan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before, after = changed_room_maps()
    write_object_map(tmp_path / "before.json", before)
    write_object_map(tmp_path / "after.json", after)
    out = tmp_path / "report"
    assert main(["changes", str(tmp_path / "before.json"), str(tmp_path / "after.json"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "moved chair #1 #4: 2.00 m" in printed and "1 moved, 1 removed, 1 added, 1 replaced, 1 unchanged" in printed
    doc = json.loads((out / "changes.json").read_text())
    assert doc["counts"] == {"moved": 1, "removed": 1, "added": 1, "replaced": 1, "unchanged": 1}
    moved = next(c for c in doc["changes"] if c["kind"] == "moved")
    np.testing.assert_allclose(moved["from_m"], [1.0, 0.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(moved["to_m"], [1.0, 0.0, 4.0], atol=1e-12)
    assert moved["before_later"]["belief_history"][-1] == [29, 0.18, "missed"]
    assert (out / "changes.png").read_bytes()[:4] == b"\x89PNG"


def test_changes_command_names_a_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["changes", str(tmp_path / "nope.json"), str(tmp_path / "nope.json")]) == 1
    err = capsys.readouterr().err
    assert "nope.json" in err and len(err.strip().splitlines()) == 1


def test_a_run_from_a_saved_map_reports_against_the_map_it_loaded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`run --map-in`'s end-of-run report (`SessionChanges`): the earlier beliefs are those of the file, not the
    ones the layer pulled toward 0.5 at the session start; the thumbnails of both sessions reach the plan."""
    from changing_slam_ros.commands.run import SessionChanges
    from changing_slam_ros.core.map.slam_map import Atlas
    from changing_slam_ros.core.objects.object_layer import ObjectLayer, SavedObjectMap
    from changing_slam_ros.io.map_file import LoadedMap

    before, after = changed_room_maps()
    thumb = np.full((72, 96, 3), 200, np.uint8)
    saved = SavedObjectMap(before, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), -2, {2: thumb})
    layer = ObjectLayer()
    session = SessionChanges.start(LoadedMap(Atlas(), {0: saved}, 28), layer)
    assert session is not None and [e.belief for e in session.before] == [0.7, 0.7, 0.5, 0.6]
    layer.load_objects(0, saved, 28)  # what the run does next: beliefs decay toward 0.5
    assert layer.objects(0)[0].belief == pytest.approx(0.6)
    lta = layer.association(0)
    for obj in after:  # the end of the second session
        lta.objects[obj.id] = obj
    out = tmp_path / "run"
    counts = session.finish(layer, out, ("first/map.npz", "second/map.npz"), no_plot=False)
    assert counts == {"moved": 1, "removed": 1, "added": 1, "replaced": 1, "unchanged": 1}
    assert "change: moved chair #1 #4: 2.00 m" in capsys.readouterr().out
    doc = json.loads((out / "changes.json").read_text())
    assert doc["before"] == "first/map.npz" and doc["counts"] == counts
    assert (out / "changes.png").is_file()


def test_changes_command_reads_semantic_map_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from changing_slam_ros.core.objects.map_object import ObjectMapConfig
    from changing_slam_ros.core.objects.semantic_map import build_semantic_map
    from changing_slam_ros.io.semantic_map_file import write_semantic_map

    before, after = changed_room_maps()
    cfg = ObjectMapConfig()
    write_semantic_map(tmp_path / "before.yaml", build_semantic_map(before, cfg, include_inactive=True))
    write_semantic_map(tmp_path / "after.json", build_semantic_map(after, cfg, include_inactive=True))
    assert main(["changes", str(tmp_path / "before.yaml"), str(tmp_path / "after.json"), "--out", str(tmp_path / "r")]) == 0
    assert "1 moved, 1 removed, 1 added, 1 replaced, 1 unchanged" in capsys.readouterr().out
    doc = json.loads((tmp_path / "r" / "changes.json").read_text())
    assert doc["changes"][0]["before"]["belief_history"] == []  # a semantic map keeps no history
