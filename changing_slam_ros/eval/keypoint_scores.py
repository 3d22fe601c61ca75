"""Moving-keypoint precision and recall against a simulated sequence's instance masks, per cue.

Ground truth, per frame: a keypoint is *moving* when it lies on an object that moves at that frame (its pose
changes by more than `MOVING_SPEED_M_S` or `MOVING_TURN_DEG_S` towards the previous or next frame, or it
appears or vanishes there), *static* when on the room or on an object that stays put all sequence long, and
*ignored* when on a mover standing still (a person waiting counts neither as a miss nor as a false alarm)
or within `BORDER_PX` of a moving object's outline (where a corner mixes both). Cues, from `KeypointLog`:
`any` (the keypoint was dropped), `detector` (dynamic class from a box), `object_ekf` (movable class,
dropped while the class-agnostic cue did not fire), `class_agnostic` (segmentation or mover tracking).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.se3 import quat_to_rot
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.tum_folder import format_stamp

MOVING_SPEED_M_S = 0.05
MOVING_TURN_DEG_S = 5.0
BORDER_PX = 2
CUES = ("any", "detector", "object_ekf", "class_agnostic")


@dataclass(frozen=True)
class CueScore:
    """Counts of one cue over a sequence: flagged moving (tp), flagged static (fp), missed moving (fn)."""

    tp: int
    fp: int
    fn: int

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else math.nan

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else math.nan

    def as_dict(self) -> dict[str, Any]:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": _r(self.precision), "recall": _r(self.recall)}


def _r(v: float) -> float | None:
    return None if math.isnan(v) else round(v, 4)


def _pose(row: list[float] | None) -> npt.NDArray[np.float64] | None:
    if row is None:
        return None
    T = np.eye(4)
    T[:3, :3] = quat_to_rot(np.array(row[3:7]))
    T[:3, 3] = row[:3]
    return T


def _step_moves(a: list[float] | None, b: list[float] | None, dt_s: float) -> bool:
    if (a is None) != (b is None):
        return True  # appears or vanishes
    if a is None or b is None:
        return False
    Ta, Tb = _pose(a), _pose(b)
    assert Ta is not None and Tb is not None
    if np.linalg.norm(Tb[:3, 3] - Ta[:3, 3]) > MOVING_SPEED_M_S * dt_s:
        return True
    c = (np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c)))) > MOVING_TURN_DEG_S * dt_s


def moving_table(objects_doc: dict[str, Any]) -> tuple[list[int], npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """From objects.json: stamps (F,), moving (F, n_objects + 1) per instance id (column 0 the room), and
    ever_moves (n_objects + 1,)."""
    stamps = [int(s) for s in objects_doc["stamps_ns"]]
    objs = objects_doc["objects"]
    F = len(stamps)
    moving = np.zeros((F, len(objs) + 1), dtype=bool)
    for o in objs:
        poses = o["poses"]
        for k in range(1, F):
            dt = (stamps[k] - stamps[k - 1]) * 1e-9
            if _step_moves(poses[k - 1], poses[k], dt):
                moving[k, o["id"]] = moving[k - 1, o["id"]] = True
    return stamps, moving, moving.any(axis=0)


def score_keypoints(sequence_dir: Path, keypoint_log: Path) -> dict[str, CueScore]:
    """Per-cue counts of a run's keypoint log against the sequence's masks and objects.json."""
    seq = Path(sequence_dir)
    try:
        doc = json.loads((seq / "objects.json").read_text())
        log = np.load(keypoint_log)
    except (OSError, ValueError) as err:
        raise EvalError(f"keypoint scores: cannot read {seq / 'objects.json'} or {keypoint_log} ({err})") from err
    stamps, moving, ever = moving_table(doc)
    row_of = {s: k for k, s in enumerate(stamps)}
    counts = {c: [0, 0, 0] for c in CUES}
    offsets = log["offsets"]
    kernel = np.ones((2 * BORDER_PX + 1, 2 * BORDER_PX + 1), np.uint8)
    for f, stamp in enumerate(log["stamps_ns"]):
        k = row_of.get(int(stamp))
        if k is None:
            continue
        mask = cv2.imread(str(seq / "masks" / f"{format_stamp(int(stamp))}.png"), cv2.IMREAD_UNCHANGED)
        if mask is None:
            raise EvalError(f"keypoint scores: no mask for stamp {stamp} in {seq / 'masks'}")
        mv_ids = moving[k]
        lut_moving = np.zeros(256, dtype=bool)
        lut_moving[: len(mv_ids)] = mv_ids
        lut_still_mover = np.zeros(256, dtype=bool)
        lut_still_mover[: len(ever)] = ever & ~mv_ids
        on_moving = lut_moving[mask]
        band = cv2.dilate(on_moving.astype(np.uint8), kernel).astype(bool) & ~on_moving
        ignore_px = lut_still_mover[mask] | band
        a, b = int(offsets[f]), int(offsets[f + 1])
        kp = np.rint(log["keypoints_px"][a:b]).astype(np.int64)
        h, w = mask.shape
        u = np.clip(kp[:, 0], 0, w - 1)
        v = np.clip(kp[:, 1], 0, h - 1)
        truth = on_moving[v, u]
        use = ~ignore_px[v, u]
        keep, mov, cls = log["keep"][a:b], log["moving"][a:b], log["kp_classes"][a:b]
        flags = {
            "any": ~keep,
            "detector": cls == 2,
            "object_ekf": ((cls == 1) | (cls == 3)) & ~keep & ~mov,
            "class_agnostic": mov,
        }
        for c, flag in flags.items():
            counts[c][0] += int(np.sum(flag & truth & use))
            counts[c][1] += int(np.sum(flag & ~truth & use))
            counts[c][2] += int(np.sum(~flag & truth & use))
    return {c: CueScore(*v) for c, v in counts.items()}


def mover_coverage(sequence_dir: Path) -> tuple[float, float]:
    """(median, max) over frames of the image fraction covered by objects that move at some time."""
    seq = Path(sequence_dir)
    doc = json.loads((seq / "objects.json").read_text())
    stamps, _, ever = moving_table(doc)
    lut = np.zeros(256, dtype=bool)
    lut[: len(ever)] = ever
    fractions = []
    for stamp in stamps[:: max(1, len(stamps) // 60)]:  # about 60 frames are plenty for a median and a maximum
        mask = cv2.imread(str(seq / "masks" / f"{format_stamp(stamp)}.png"), cv2.IMREAD_UNCHANGED)
        if mask is not None:
            fractions.append(float(lut[mask].mean()))
    return (float(np.median(fractions)), float(np.max(fractions))) if fractions else (0.0, 0.0)
