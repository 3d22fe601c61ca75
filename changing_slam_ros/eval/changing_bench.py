"""Scoring the semantic map of a changing-room run against the final lap's ground truth (`changing_truth.json`).

The run's MapObjects are moved into the ground-truth frame with the run's own trajectory alignment (the
object-placing alignment of `changing-slam run`), turned into the semantic map the run publishes (belief >=
`semantic_min_belief`: the active objects a subscriber sees), and matched one to one to the objects present
at the end of the last lap (`score_semantic_map`: recall, precision, stale and spurious objects). Camera ATE
comes from the run's metrics.json, against the control run's (the seed rendered without changes). Each
missed object gets a reason (`missed_reasons`). With the two-session mode a seed also carries the score of its
change report (`eval/change_sessions.py`, `eval/change_scores.py`), summarised under `changes`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import ObjectMapConfig
from changing_slam_ros.core.objects.semantic_map import SemanticObject
from changing_slam_ros.errors import EvalError

if TYPE_CHECKING:
    from changing_slam_ros.eval.change_sessions import SessionResult

F64 = npt.NDArray[np.float64]
MAX_DISTANCE_M = 0.3
STRUCTURE_CLASS_IDS = (60,)  # dining table: fixed background for the object layer
TRUTH_FORMAT_PREFIX = "changing_slam_ros changing-room truth"
ATE_RATIO_TARGET = 1.3
RECALL_TARGET = 0.9
PRECISION_TARGET = 0.9


@dataclass(frozen=True)
class TruthObject:
    """A ground-truth object at one lap's end: class, world box (min, max) and its centre, all (3,)."""

    name: str
    class_id: int
    class_name: str
    centre_w: F64
    box_min_w: F64
    box_max_w: F64


@dataclass(frozen=True)
class WallItem:
    """Something on a wall: a picture (`is_object` False) or a hung object (a clock, a screen)."""

    name: str
    is_object: bool
    box_min_w: F64
    box_max_w: F64
    depicts: str = ""


@dataclass(frozen=True)
class ChangingTruth:
    """The per-lap ground truth of one family render."""

    seed: int
    laps: tuple[tuple[TruthObject, ...], ...]
    wall_items: tuple[WallItem, ...]
    changes: tuple[dict[str, Any], ...]
    initial: tuple[TruthObject, ...] = ()  # the objects at the start, before any change


def _vec(v: Any) -> F64:
    return np.asarray(v, dtype=np.float64).reshape(3)


def load_changing_truth(path: str | Path) -> ChangingTruth:
    """Read `changing_truth.json`; EvalError names the file on malformed input."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as err:
        raise EvalError(f"{p}: cannot read changing-room truth ({err.strerror})") from err
    except json.JSONDecodeError as err:
        raise EvalError(f"{p}: not valid JSON ({err})") from err
    try:
        if not str(doc["format"]).startswith(TRUTH_FORMAT_PREFIX):
            raise EvalError(f"{p}: format: expected {TRUTH_FORMAT_PREFIX!r}, got {doc['format']!r}")
        laps = tuple(tuple(TruthObject(str(o["name"]), int(o["class_id"]), str(o["class_name"]), _vec(o["centre_w"]),
                                       _vec(o["box_min_w"]), _vec(o["box_max_w"])) for o in lap["objects"])
                     for lap in doc["laps"])
        walls = tuple(WallItem(str(w["name"]), bool(w["is_object"]), _vec(w["box_min_w"]), _vec(w["box_max_w"]),
                               str(w.get("depicts", ""))) for w in doc["wall_items"])
        if not laps:
            raise EvalError(f"{p}: laps: empty")
        initial = tuple(TruthObject(str(o["name"]), int(o["class_id"]), str(o["class_name"]), _vec(o["centre_w"]),
                                    _vec(o["box_min_w"]), _vec(o["box_max_w"])) for o in doc.get("initial", []))
        return ChangingTruth(int(doc["seed"]), laps, walls, tuple(doc.get("changes", [])), initial)
    except (KeyError, TypeError, ValueError) as err:
        raise EvalError(f"{p}: malformed changing-room truth ({type(err).__name__}: {err})") from err


def _box_distance(p: F64, lo: F64, hi: F64) -> float:
    """Distance (m) from point `p` to the axis-aligned box [lo, hi] (0 inside)."""
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(lo - p, p - hi))))


@dataclass(frozen=True)
class MapScore:
    """The semantic map against one lap: matches (estimate id, ground-truth name, distance m), the missed
    ground truth (names), stale (estimate id, name of the object that left), spurious pictures (estimate id,
    picture name) and other spurious estimates (ids)."""

    n_present: int
    n_active: int
    matches: tuple[tuple[int, str, float], ...]
    missed: tuple[str, ...]
    stale: tuple[tuple[int, str], ...]
    spurious_pictures: tuple[tuple[int, str], ...]
    spurious_other: tuple[int, ...]
    structure_ids: frozenset[str] = field(default_factory=frozenset)

    @property
    def n_matched_present(self) -> int:
        return sum(1 for _, name, _ in self.matches if name not in self.structure_ids)

    @property
    def recall(self) -> float:
        return self.n_matched_present / self.n_present if self.n_present else 1.0

    @property
    def precision(self) -> float:
        return len(self.matches) / self.n_active if self.n_active else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "present": self.n_present, "active": self.n_active, "recall": self.recall, "precision": self.precision,
            "matches": [{"estimate_id": e, "gt_name": n, "distance_m": d} for e, n, d in self.matches],
            "missed": list(self.missed), "stale": [{"estimate_id": e, "gt_name": n} for e, n in self.stale],
            "spurious_pictures": [{"estimate_id": e, "picture": n} for e, n in self.spurious_pictures],
            "spurious_other": list(self.spurious_other),
        }


def score_semantic_map(objects: Iterable[SemanticObject], truth: ChangingTruth, lap: int = -1,
                       max_distance_m: float = MAX_DISTANCE_M, match_on: str = "centroid") -> MapScore:
    """Score the active objects `objects` (ground-truth frame) against the objects present at the end of `lap`.

    Matching is greedy by increasing distance: same class, estimated centroid within `max_distance_m`
    (0.3 m) of the ground-truth box centre. Figures:
    - recall: matched present objects / present objects (tables excluded: the object layer treats them as
      structure by design, see `eval.object_metrics`; a table an estimate matches still makes that estimate right);
    - precision: matched active objects / active objects;
    - stale: unmatched active objects within reach of a place a same-class object occupied at the start or at
      the end of an earlier lap and has left; spurious: the other unmatched ones, split into pictures (within
      reach of a picture's box on a wall) and other (structure, furniture of another class, nothing).
    """
    if match_on not in ("centroid", "box_center"):
        raise EvalError(f"match_on: expected 'centroid' or 'box_center', got {match_on!r}")
    if not -len(truth.laps) <= lap < len(truth.laps):
        raise EvalError(f"lap {lap}: the truth has {len(truth.laps)} laps")
    k = lap % len(truth.laps)
    present = truth.laps[k]
    est = list(objects)
    where = [np.asarray(e.centroid_w if match_on == "centroid" else e.box_center_w, float) for e in est]
    pairs = sorted((float(np.linalg.norm(where[i] - o.centre_w)), i, j) for i, e in enumerate(est)
                   for j, o in enumerate(present) if o.class_id == e.class_id)
    used_e: set[int] = set()
    used_g: set[int] = set()
    matches = []
    for d, i, j in pairs:
        if d > max_distance_m or i in used_e or j in used_g:
            continue
        used_e.add(i)
        used_g.add(j)
        matches.append((est[i].id, present[j].name, d))
    structure = frozenset(o.name for o in present if o.class_id in STRUCTURE_CLASS_IDS)
    missed = tuple(o.name for j, o in enumerate(present) if j not in used_g and o.name not in structure)
    stale, pictures, other = [], [], []
    for i, e in enumerate(est):
        if i in used_e:
            continue
        left = _left_place(where[i], e.class_id, truth, k, max_distance_m)
        if left is not None:
            stale.append((e.id, left))
            continue
        picture = next((w.name for w in truth.wall_items if not w.is_object
                        and _box_distance(where[i], w.box_min_w, w.box_max_w) <= max_distance_m), None)
        if picture is not None:
            pictures.append((e.id, picture))
        else:
            other.append(e.id)
    return MapScore(len(present) - len(structure), len(est), tuple(sorted(matches)), missed, tuple(stale),
                    tuple(pictures), tuple(other), structure)


MISSED_REASONS = ("inactive", "off", "wrong_class", "unmapped")


def missed_reasons(score: MapScore, truth: ChangingTruth, active: Sequence[SemanticObject],
                   everything: Sequence[SemanticObject], lap: int = -1, max_distance_m: float = MAX_DISTANCE_M,
                   match_on: str = "centroid") -> dict[str, str]:
    """Ground-truth name -> why `score` missed it (MISSED_REASONS, first that applies): `everything` holds the
    active objects and those below the semantic map's belief.

    Reasons: a same-class map object lies within reach but its belief keeps it out of the semantic map
    (inactive), a same-class active object lies within twice the reach (off), an active object of another
    class lies within reach (wrong class), or nothing (unmapped).
    """
    present = {o.name: o for o in truth.laps[lap]}
    active_ids = {e.id for e in active}

    def where(e: SemanticObject) -> F64:
        return np.asarray(e.centroid_w if match_on == "centroid" else e.box_center_w, float)

    out = {}
    for name in score.missed:
        o = present[name]
        near = [(e, float(np.linalg.norm(where(e) - o.centre_w))) for e in everything]
        if any(e.class_id == o.class_id and e.id not in active_ids and d <= max_distance_m for e, d in near):
            out[name] = "inactive"
        elif any(e.class_id == o.class_id and e.id in active_ids and d <= 2 * max_distance_m for e, d in near):
            out[name] = "off"
        elif any(e.class_id != o.class_id and e.id in active_ids and d <= max_distance_m for e, d in near):
            out[name] = "wrong_class"
        else:
            out[name] = "unmapped"
    return out


def _left_place(p: F64, class_id: int, truth: ChangingTruth, lap: int, max_distance_m: float) -> str | None:
    """Name of a same-class object whose place at an earlier lap's end lies within reach of `p`, where no
    same-class object stands at the end of `lap`."""
    if any(o.class_id == class_id and np.linalg.norm(p - o.centre_w) <= max_distance_m for o in truth.laps[lap]):
        return None
    for earlier in (truth.initial, *truth.laps[:lap]):
        for o in earlier:
            if o.class_id == class_id and np.linalg.norm(p - o.centre_w) <= max_distance_m:
                return o.name
    return None


@dataclass(frozen=True)
class SeedResult:
    """One seed: the semantic-map score, camera ATE (m) of the run and of its control, loops."""

    seed: int
    score: MapScore | None
    frames: int
    frames_tracked: int
    ate_m: float
    control_ate_m: float
    loops: int
    wrong_loops: int
    changes: tuple[str, ...] = ()
    error: str = ""
    missed_reasons: tuple[tuple[str, str], ...] = ()  # (ground-truth name, reason), see `missed_reasons`
    sessions: SessionResult | None = None  # the change report of the two-session runs, when they ran

    @property
    def ate_ratio(self) -> float:
        return self.ate_m / self.control_ate_m if self.control_ate_m > 0 else math.nan

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k not in ("score", "sessions")}
        d["ate_ratio"] = self.ate_ratio
        d["score"] = None if self.score is None else self.score.to_dict()
        if self.sessions is not None:
            d["sessions"] = self.sessions.to_dict()
        return d


def summarise(results: Sequence[SeedResult]) -> dict[str, Any]:
    """Means over the scored seeds, totals, and how many seeds meet each target."""
    scored = [r for r in results if r.score is not None]
    ratios = [r.ate_ratio for r in results if math.isfinite(r.ate_ratio)]

    def mean(values: list[float]) -> float:
        return float(np.mean(values)) if values else math.nan

    s = [r.score for r in scored if r.score is not None]
    present = sum(x.n_present for x in s)
    active = sum(x.n_active for x in s)
    out = {
        "seeds": len(results), "scored": len(scored), "failed": [r.seed for r in results if r.score is None],
        "recall_mean": mean([x.recall for x in s]), "precision_mean": mean([x.precision for x in s]),
        "recall_pooled": sum(x.n_matched_present for x in s) / present if present else math.nan,
        "precision_pooled": sum(len(x.matches) for x in s) / active if active else math.nan,
        "present": present, "active": active, "stale": sum(len(x.stale) for x in s),
        "spurious_pictures": sum(len(x.spurious_pictures) for x in s),
        "spurious_other": sum(len(x.spurious_other) for x in s),
        "ate_cm_median": 100 * float(np.median([r.ate_m for r in results])) if results else math.nan,
        "ate_ratio_median": float(np.median(ratios)) if ratios else math.nan,
        "ate_ratio_max": max(ratios) if ratios else math.nan,
        "wrong_loops": sum(r.wrong_loops for r in results),
        "missed_reasons": {k: sum(reason == k for r in results for _, reason in r.missed_reasons)
                           for k in MISSED_REASONS},
        "seeds_meeting": {
            "recall": sum(x.recall >= RECALL_TARGET for x in s),
            "precision": sum(x.precision >= PRECISION_TARGET for x in s),
            "no_stale": sum(not x.stale for x in s), "no_picture": sum(not x.spurious_pictures for x in s),
            "ate_ratio": sum(r <= ATE_RATIO_TARGET for r in ratios),
            "no_wrong_loop": sum(r.wrong_loops == 0 for r in results),
        },
    }
    sessions = [r.sessions for r in results if r.sessions is not None]
    if sessions:
        from changing_slam_ros.eval.change_scores import summarise_change_scores

        out["changes"] = summarise_change_scores([x.score for x in sessions if x.score is not None])
        out["changes"]["failed"] = [x.seed for x in sessions if x.score is None]
        out["changes"]["not_relocalised"] = [x.seed for x in sessions if x.relocalised is False]
    return out


def _read_json(path: Path) -> dict[str, Any]:
    try:
        doc: dict[str, Any] = json.loads(path.read_text())
    except OSError as err:
        raise EvalError(f"{path}: cannot read ({err.strerror})") from err
    except json.JSONDecodeError as err:
        raise EvalError(f"{path}: not valid JSON ({err})") from err
    return doc


def run_association_config(run_dir: Path) -> ObjectMapConfig:
    """The object-association settings of the config a run used (metrics.json `config`; the defaults when it
    used none): the semantic map's belief and point thresholds."""
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.core.objects.object_layer import object_layer_config

    config = str(_read_json(run_dir / "metrics.json").get("config", "defaults"))
    data = {} if config == "defaults" else load_yaml(find_config(config))
    return object_layer_config(data.get("objects"), f"{config}: objects").association


def run_semantic_map(scene_dir: Path, run_dir: Path, include_inactive: bool = False) -> list[SemanticObject]:
    """The run's semantic map in the ground-truth frame: its MapObjects moved by the run's object-placing
    trajectory alignment, selected and boxed with the object-map settings of the run's config (with
    `include_inactive`, also the objects whose belief keeps them out of it)."""
    from changing_slam_ros.eval.object_alignment import aligned_objects, aligned_planes, trajectory_alignment
    from changing_slam_ros.core.objects.semantic_map import build_semantic_map
    from changing_slam_ros.errors import SlamError
    from changing_slam_ros.io.semantic_map_file import read_object_map_file
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    cfg = run_association_config(run_dir)
    try:
        gt = read_tum_trajectory(scene_dir / "groundtruth.txt")
        est = read_tum_trajectory(run_dir / "trajectory.txt")
        objects, planes = read_object_map_file(run_dir / "object_map.json")
    except SlamError as err:
        raise EvalError(str(err)) from err
    T = trajectory_alignment(gt, est)
    if T is None:
        raise EvalError(f"{run_dir}: no trajectory alignment with ground truth (fewer than 3 matched poses)")
    smap = build_semantic_map(aligned_objects(objects, T), cfg, include_inactive=include_inactive,
                              planes=aligned_planes(planes, T))
    return list(smap.objects)


def score_run(seed: int, scene_dir: Path, run_dir: Path, control_run_dir: Path | None = None,
              max_distance_m: float = MAX_DISTANCE_M, match_on: str = "centroid") -> SeedResult:
    """Score one seed's run folder (and its control's ATE) against the scene's `changing_truth.json`."""
    truth = load_changing_truth(scene_dir / "changing_truth.json")
    metrics = _read_json(run_dir / "metrics.json")
    control = math.nan
    if control_run_dir is not None and (control_run_dir / "metrics.json").is_file():
        control = float(_read_json(control_run_dir / "metrics.json").get("ate_rmse_m", math.nan))
    loops = metrics.get("loops", {})
    active = run_semantic_map(scene_dir, run_dir)
    score = score_semantic_map(active, truth, -1, max_distance_m, match_on)
    everything = run_semantic_map(scene_dir, run_dir, include_inactive=True)
    reasons = missed_reasons(score, truth, active, everything, -1, max_distance_m, match_on)
    return SeedResult(seed, score, int(metrics.get("frames", 0)), int(metrics.get("frames_tracked", 0)),
                      float(metrics.get("ate_rmse_m", math.nan)), control, int(loops.get("accepted", 0)),
                      int(loops.get("wrong", 0)), tuple(str(c["kind"]) for c in truth.changes),
                      missed_reasons=tuple(sorted(reasons.items())))
