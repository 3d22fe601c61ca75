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
