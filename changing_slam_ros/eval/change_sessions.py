"""One seed's two sessions read back and scored: where the render is cut, the report the second session wrote, and the
objects each session's map holds, all moved into the ground-truth frame for `change_scores.score_changes`.

The first session runs the frames before the first change (`changing-slam run --max-frames K`), the second session the
rest from the first session's map (`--start-frame K --map-in S1/map.npz`) and ends with the run's own change report
(`changes.json`: the first session's objects as loaded against the second session's). Each side of a reported change is
moved into the ground-truth frame by the alignment of the session that mapped it: the earlier object by the first
session's trajectory, the later by the second session's (which is in the first session's map frame once it relocalised,
and follows any correction the second session made to that map). The reported distance stays the report's own, measured
in the map.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import EvalError, SlamError
from changing_slam_ros.eval.change_scores import (
    KINDS, PLACE_RADIUS_M, ChangeScore, ReportedChange, Side, score_changes, session_split, truth_changes,
)
from changing_slam_ros.eval.changing_bench import ChangingTruth, load_changing_truth, run_association_config

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SessionResult:
    """One seed's sessions: the cut (`split_frame` of `frames`), whether the second session relocalised in the first
    session's map (None when unknown), the score (None when a session failed: `error`)."""

    seed: int
    split_frame: int
    frames: int
    relocalised: bool | None
    score: ChangeScore | None
    error: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"split_frame": self.split_frame, "frames": self.frames, "relocalised": self.relocalised,
                "error": self.error, "score": None if self.score is None else self.score.to_dict()}


def frame_times_s(scene_dir: Path) -> list[float]:
    """Each frame's time after the first (s), from the render's rgb.txt (the simulator pairs every colour frame
    with the depth frame of its stamp, so these are the frames `run` numbers)."""
    from changing_slam_ros.io.tum_folder import read_file_list

    try:
        stamps = sorted(f.stamp_ns for f in read_file_list(Path(scene_dir) / "rgb.txt"))
    except (OSError, SlamError) as err:
        raise EvalError(f"{scene_dir}: cannot read the render's frames ({err})") from err
    return [(s - stamps[0]) * 1e-9 for s in stamps]


def split_of(scene_dir: Path) -> tuple[int, int, ChangingTruth]:
    """(frames of the first session, frames of the render, the truth) of a render with changes."""
    truth = load_changing_truth(Path(scene_dir) / "changing_truth.json")
    times = frame_times_s(scene_dir)
    return session_split([float(c["t_s"]) for c in truth.changes], times), len(times), truth


def _alignment(scene_dir: Path, run_dir: Path) -> F64:
    from changing_slam_ros.eval.object_alignment import trajectory_alignment
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    T = trajectory_alignment(read_tum_trajectory(Path(scene_dir) / "groundtruth.txt"),
                             read_tum_trajectory(Path(run_dir) / "trajectory.txt"))
    if T is None:
        raise EvalError(f"{run_dir}: no trajectory alignment with ground truth (fewer than 3 matched poses)")
    return T


def _moved(p: Any, T: F64) -> F64:
    return np.asarray(T[:3, :3] @ np.asarray(p, float).reshape(3) + T[:3, 3], dtype=np.float64)


def _side(record: dict[str, Any] | None, T: F64) -> Side | None:
    if record is None:
        return None
    return Side(str(record["id"]), int(record["class_id"]), str(record["class_name"]), _moved(record["centroid_m"], T))


def read_reported_changes(path: Path, T_before: F64, T_after: F64) -> list[ReportedChange]:
    """The changes of a report file (`changes.json`), the earlier objects moved by T_before (4, 4), the later by
    T_after."""
    try:
        doc = json.loads(Path(path).read_text())
        out = []
        for c in doc["changes"]:
            if c["kind"] not in KINDS:
                raise EvalError(f"{path}: unknown change kind {c['kind']!r}")
            out.append(ReportedChange(str(c["kind"]), _side(c["before"], T_before), _side(c["after"], T_after),
                                      None if c.get("distance_m") is None else float(c["distance_m"])))
        return out
    except OSError as err:
        raise EvalError(f"{path}: cannot read the change report ({err.strerror})") from err
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise EvalError(f"{path}: malformed change report ({type(err).__name__}: {err})") from err


def present_objects(run_dir: Path, T: F64) -> list[Side]:
    """The objects a run's map holds as there (the report's own test: belief and points, with the run's config),
    moved by T (4, 4)."""
    from changing_slam_ros.core.objects.object_evidence import EvidenceConfig
    from changing_slam_ros.io.change_report_file import read_report_objects

    cfg = run_association_config(run_dir)
    try:
        objects = read_report_objects(Path(run_dir) / "map.npz").evidence(
            EvidenceConfig(cfg.semantic_min_belief, cfg.min_points))
    except SlamError as err:
        raise EvalError(str(err)) from err
    return [Side(str(e.id), e.class_id, e.class_name, _moved(e.centroid_w, T)) for e in objects if e.present]


def score_sessions(seed: int, scene_dir: Path, first: Path, second: Path,
                   radius_m: float = PLACE_RADIUS_M) -> SessionResult:
    """Score the second session's change report (`second`/changes.json) against the truth's changes in the render."""
    split, n_frames, truth = split_of(scene_dir)
    metrics = json.loads((Path(second) / "metrics.json").read_text())
    relocalised = metrics.get("multi_session", {}).get("relocalised")
    if not (Path(second) / "changes.json").is_file():
        raise EvalError(f"{second}: no changes.json (the object layer off, or no object map in {first})")
    T1, T2 = _alignment(scene_dir, first), _alignment(scene_dir, second)
    reported = read_reported_changes(Path(second) / "changes.json", T1, T2)
    truths = truth_changes(truth, until_s=frame_times_s(scene_dir)[-1])
    involved = {s.label for t in truths for s in (t.before, t.after) if s is not None}
    unchanged = [Side(o.name, o.class_id, o.class_name, o.centre_w) for o in truth.initial if o.name not in involved]
    score = score_changes(reported, truths, present_objects(first, T1), present_objects(second, T2), unchanged,
                          radius_m)
    return SessionResult(seed, split, n_frames, None if relocalised is None else bool(relocalised), score)


def failed_sessions(seed: int, error: str, split: int = 0, frames: int = 0) -> SessionResult:
    """A seed whose sessions could not be run or scored."""
    return SessionResult(seed, split, frames, None, None, error)
