"""Moving-keypoint scores per cue on a hand-made sequence with known counts: a moving object, one that stops
(ignored while still), a static one (false alarms), the room, and a keypoint on a moving object's outline."""

from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.keypoint_scores import moving_table, mover_coverage, score_keypoints
from changing_slam_ros.io.tum_folder import format_stamp

STAMPS = [1_000_000_000 + k * 100_000_000 for k in range(4)]  # 10 Hz


def _row(x: float) -> list[float]:
    return [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]


@pytest.fixture
def sequence(tmp_path: Path) -> Path:
    objects = [
        {"id": 1, "poses": [_row(0.1 * k) for k in range(4)]},  # moves at 1 m/s all along
        {"id": 2, "poses": [_row(0.0), _row(0.1), _row(0.1), _row(0.1)]},  # moves, then stands still
        {"id": 3, "poses": [_row(0.0)] * 4},  # never moves
    ]
    (tmp_path / "objects.json").write_text(json.dumps({"stamps_ns": STAMPS, "objects": objects}))
    (tmp_path / "masks").mkdir()
    mask = np.zeros((40, 40), np.uint8)
    mask[0:10, 0:10] = 1
    mask[0:10, 20:30] = 2
    mask[20:30, 0:10] = 3
    for s in STAMPS:
        cv2.imwrite(str(tmp_path / "masks" / f"{format_stamp(s)}.png"), mask)
    return tmp_path


def _log(path: Path, frames: list[tuple[int, list[tuple[float, float, bool, bool, int]]]]) -> Path:
    """frames: (stamp, [(u, v, keep, moving, class)])."""
    rows = [r for _, kps in frames for r in kps]
    buf = io.BytesIO()
    np.savez(buf, stamps_ns=np.array([s for s, _ in frames]),
             offsets=np.concatenate([[0], np.cumsum([len(k) for _, k in frames])]),
             keypoints_px=np.array([(r[0], r[1]) for r in rows], np.float32),
             keep=np.array([r[2] for r in rows]), moving=np.array([r[3] for r in rows]),
             kp_classes=np.array([r[4] for r in rows], np.int8))
    path.write_bytes(buf.getvalue())
    return path


def test_moving_table_marks_objects_while_they_move_and_never_the_static_one(sequence: Path) -> None:
    stamps, moving, ever = moving_table(json.loads((sequence / "objects.json").read_text()))
    assert stamps == STAMPS
    assert moving[:, 1].all() and moving[:, 2].tolist() == [True, True, False, False]
    assert not moving[:, 3].any() and ever.tolist() == [False, True, True, False]


def test_each_cue_is_scored_against_the_masks_of_movers_while_they_move(sequence: Path, tmp_path: Path) -> None:
    log = _log(tmp_path / "kp.npz", [
        (STAMPS[1], [
            (5, 5, False, False, 2),  # on the mover, dropped by its detected class: a hit of any and detector
            (25, 5, True, False, 0),  # on the second mover while it moves, kept: missed by every cue
            (5, 25, False, False, 1),  # on the static object, dropped as movable: a false alarm (object_ekf)
            (35, 35, False, True, 0),  # on the room, flagged by segmentation: a false alarm (class_agnostic)
            (10, 5, False, False, 0),  # one pixel off the mover's outline: ignored
        ]),
        (STAMPS[2], [
            (25, 5, False, False, 2),  # on the second mover standing still: ignored
            (5, 5, False, True, 0),  # on the mover, flagged by segmentation only
        ]),
    ])
    scores = score_keypoints(sequence, log)
    got = {c: (s.tp, s.fp, s.fn) for c, s in scores.items()}
    assert got == {"any": (2, 2, 1), "detector": (1, 0, 2), "object_ekf": (0, 1, 3), "class_agnostic": (1, 1, 2)}
    assert scores["any"].precision == pytest.approx(0.5) and scores["any"].recall == pytest.approx(2 / 3)


def test_coverage_counts_the_objects_that_ever_move(sequence: Path) -> None:
    median, top = mover_coverage(sequence)
    assert median == pytest.approx(200 / 1600) and top == pytest.approx(200 / 1600)


def test_a_missing_log_raises_an_eval_error_naming_it(sequence: Path) -> None:
    with pytest.raises(EvalError, match="nope.npz"):
        score_keypoints(sequence, sequence / "nope.npz")
