"""Scoring a "what changed" report against the changing-room ground truth's list of changes.

Two sessions of one render: the first session ends before the first change (`session_split`), the second session
continues its map over the remaining frames, and the report compares the first session's objects with the second
session's. The ground truth's changes become the verdicts a report should state (`truth_changes`): `moved_short` and
`moved_long` one move, `swapped` two moves (one per object, as `compare_maps` reports a swap of two classes), `removed`
and `added` one each, `replaced` one replacement (the removed object's class and place, the new object's class and
place). Places are box centres in the ground-truth frame: at the start for the earlier side (no change happens before
the split), at the end of the last lap for the later side (an object changes at most once).

`score_changes` matches reported changes to these, per kind, one to one and nearest first: the same kind, and
every side the truth has (before, after) present in the report with the same class and its position within
`radius_m` (0.3 m, the semantic-map benchmark's reach: a map object's centroid is the mean of the points seen,
biased towards the camera by up to half the object's depth) of the truth's place. For a matched move the
displacement error is |reported distance - true distance|, and the place error the distance from the reported
new position to the true one; both are held to `DISPLACEMENT_TOLERANCE_M`.

A change can only be reported when the map holds its objects: the earlier object in the first session's map, the
later one in the second session's. Each truth says whether it was `mapped_before` (a present session-1 object of its
class within twice the radius of its old place, `mapped_reach`: an object mapped but misplaced is mapped, and
its miss is the map's, not the detector's; vacuous for an addition) and `mapped_after` (likewise in the second session's
map at its new place), so recall comes over all truths, over those mapped before, and over those mapped on both
sides: the last separates what the change logic and the map's accuracy got wrong from what the detector never
named. A missed truth's reason (MISS_REASONS, first that applies): not mapped before, not mapped after, `off`
(a report of its kind and classes within the mapped reach but beyond the radius), `other_kind` (an unmatched
report of another kind with an object of its class within the mapped reach), else not reported. A reported addition of
an object that was in the room all along but that the first session never mapped (the first lap's frames before the
split show part of the room only, and the detector misses some views) is `first_seen`: right from the map's
point of view, a change of the room only in the truth's, so it counts for neither precision nor recall.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.changing_bench import ChangingTruth, TruthObject

F64 = npt.NDArray[np.float64]
KINDS = ("moved", "removed", "added", "replaced")
TRUTH_KINDS = {"moved_short": "moved", "moved_long": "moved", "swapped": "moved", "removed": "removed",
               "added": "added", "replaced": "replaced"}  # ground-truth change kind -> the report's verdict
PLACE_RADIUS_M = 0.3
DISPLACEMENT_TOLERANCE_M = 0.2
PRECISION_TARGET = RECALL_TARGET = 0.9
MISS_REASONS = ("not_mapped_before", "not_mapped_after", "off", "other_kind", "not_reported")
COUNTS = ("truths", "matched", "mapped_before", "matched_mapped_before", "mapped_both", "matched_mapped_both",
          "reported", "correct")  # `ChangeScore.counts`


@dataclass(frozen=True)
class Side:
    """An object at one end of a change: `label` (ground-truth name or map object id), class, position (3,) in the
    ground-truth frame (m)."""

    label: str
    class_id: int
    class_name: str
    position_w: F64

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "class_id": self.class_id, "class_name": self.class_name,
                "position_w": [round(float(v), 4) for v in self.position_w]}


@dataclass(frozen=True)
class TruthChange:
    """One verdict the report should state: `kind` (KINDS), the ground truth's own kind (`truth_kind`), its time,
    and the object before (None when added) and after (None when removed)."""

    kind: str
    truth_kind: str
    t_s: float
    before: Side | None
    after: Side | None

    @property
    def distance_m(self) -> float | None:
        if self.before is None or self.after is None:
            return None
        return float(np.linalg.norm(self.after.position_w - self.before.position_w))

    def describe(self) -> str:
        ref = self.before if self.before is not None else self.after
        assert ref is not None
        text = f"{self.truth_kind} {ref.class_name} {ref.label}"
        if self.kind == "replaced" and self.after is not None:
            text += f" -> {self.after.class_name}"
        if self.kind == "moved":
            text += f" {self.distance_m:.2f} m"
        return text


@dataclass(frozen=True)
class ReportedChange:
    """One change as a report states it, its objects moved into the ground-truth frame: `kind` (KINDS), the earlier
    and the later object (labels are map object ids) and the distance the report gives (map frame; moved and
    replaced)."""

    kind: str
    before: Side | None
    after: Side | None
    distance_m: float | None = None

    def describe(self) -> str:
        ref = self.before if self.before is not None else self.after
        assert ref is not None
        text = f"{self.kind} {ref.class_name} #{ref.label}"
        if self.kind == "replaced" and self.after is not None:
            text += f" -> {self.after.class_name} #{self.after.label}"
        if self.distance_m is not None:
            text += f" {self.distance_m:.2f} m"
        return text


def truth_changes(truth: ChangingTruth, until_s: float = math.inf) -> list[TruthChange]:
    """The verdicts of `truth`'s changes that happen before `until_s` (the render's last frame), in time order."""
    start = {o.name: o for o in truth.initial}
    end = {o.name: o for o in truth.laps[-1]}

    def side(objects: dict[str, TruthObject], name: str, where: str) -> Side:
        if name not in objects:
            raise EvalError(f"changing-room truth, seed {truth.seed}: change of {name!r}: not among the objects "
                            f"{where}")
        o = objects[name]
        return Side(o.name, o.class_id, o.class_name, o.centre_w)

    out = []
    for c in sorted(truth.changes, key=lambda c: float(c["t_s"])):
        kind, t_s = str(c["kind"]), float(c["t_s"])
        if kind not in TRUTH_KINDS:
            raise EvalError(f"changing-room truth, seed {truth.seed}: unknown change kind {kind!r}")
        if t_s >= until_s:
            continue
        actor, other = str(c["object"]), str(c.get("other") or "")
        if kind == "swapped":
            for name in (actor, other):
                out.append(TruthChange("moved", kind, t_s, side(start, name, "at the start"),
                                       side(end, name, "at the end")))
        elif kind == "removed":
            out.append(TruthChange("removed", kind, t_s, side(start, actor, "at the start"), None))
        elif kind == "added":
            out.append(TruthChange("added", kind, t_s, None, side(end, actor, "at the end")))
        elif kind == "replaced":
            out.append(TruthChange("replaced", kind, t_s, side(start, actor, "at the start"),
                                   side(end, other, "at the end")))
        else:
            out.append(TruthChange("moved", kind, t_s, side(start, actor, "at the start"),
                                   side(end, actor, "at the end")))
    return out


def session_split(change_times_s: Sequence[float], frame_times_s: Sequence[float]) -> int:
    """How many frames the first session gets: those before the first change (frame times from the first frame, s).

    EvalError when there is no change, no frame before the first change, or no frame after it (a render cut
    before the first change)."""
    if not change_times_s:
        raise EvalError("session split: the truth lists no change")
    first = min(change_times_s)
    n = int(np.searchsorted(np.asarray(frame_times_s, float), first, side="left"))
    if n == 0 or n >= len(frame_times_s):
        raise EvalError(f"session split: the first change at {first:.2f} s leaves "
                        f"{'no frame before it' if n == 0 else 'no frame after it'} ({len(frame_times_s)} frames)")
    return n


@dataclass(frozen=True)
class ChangeScore:
    """One seed's report against its truths. `truth_match[i]`: the index of the report matched to truth i (None:
    missed) and `miss_reasons[i]` why (MISS_REASONS, "" when matched); `mapped_before` / `mapped_after[i]`: whether the
    maps held truth i's objects; `first_seen`: indices of reported additions of objects that were there all along but
    not in the first session's map; `moves`: per matched move (truth index, displacement error m, place error m)."""

    truths: tuple[TruthChange, ...]
    reported: tuple[ReportedChange, ...]
    truth_match: tuple[int | None, ...]
    mapped_before: tuple[bool, ...]
    mapped_after: tuple[bool, ...]
    miss_reasons: tuple[str, ...]
    first_seen: tuple[int, ...]
    moves: tuple[tuple[int, float, float], ...]
    radius_m: float = PLACE_RADIUS_M

    def counts(self, kind: str | None = None) -> dict[str, int]:
        """Truths, matched, over the truths mapped before and mapped on both sides, and reports (first-seen
        additions left out), of one kind (None: all)."""
        idx = [i for i, t in enumerate(self.truths) if kind is None or t.kind == kind]
        matched = [i for i in idx if self.truth_match[i] is not None]
        before = [i for i in idx if self.mapped_before[i]]
        both = [i for i in before if self.mapped_after[i]]
        reports = [j for j, r in enumerate(self.reported) if (kind is None or r.kind == kind)
                   and j not in self.first_seen]
        return {"truths": len(idx), "matched": len(matched), "mapped_before": len(before),
                "matched_mapped_before": sum(1 for i in matched if self.mapped_before[i]),
                "mapped_both": len(both),
                "matched_mapped_both": sum(1 for i in matched if self.mapped_before[i] and self.mapped_after[i]),
                "reported": len(reports), "correct": len(matched)}

    def to_dict(self) -> dict[str, Any]:
        used = {j for j in self.truth_match if j is not None}
        return {
            "radius_m": self.radius_m,
            "truths": [{"kind": t.kind, "truth_kind": t.truth_kind, "t_s": t.t_s,
                        "before": None if t.before is None else t.before.to_dict(),
                        "after": None if t.after is None else t.after.to_dict(), "distance_m": t.distance_m,
                        "reported": self.truth_match[i], "mapped_before": self.mapped_before[i],
                        "mapped_after": self.mapped_after[i], "miss_reason": self.miss_reasons[i]}
                       for i, t in enumerate(self.truths)],
            "reported": [{"kind": r.kind, "before": None if r.before is None else r.before.to_dict(),
                          "after": None if r.after is None else r.after.to_dict(), "distance_m": r.distance_m,
                          "verdict": "correct" if j in used else "first_seen" if j in self.first_seen else "false"}
                         for j, r in enumerate(self.reported)],
            "moves": [{"truth": i, "displacement_error_m": d, "place_error_m": p} for i, d, p in self.moves],
            "counts": {k: self.counts(k) for k in KINDS} | {"all": self.counts()},
        }


def _near(side: Side, objects: Sequence[Side], radius_m: float) -> bool:
    return any(o.class_id == side.class_id and np.linalg.norm(o.position_w - side.position_w) <= radius_m
               for o in objects)


def _agreement(t: TruthChange, r: ReportedChange, radius_m: float) -> float | None:
    """Sum of the place distances (m) when report `r` states truth `t` (same kind; each side the truth has: same
    class, within `radius_m`), else None."""
    if t.kind != r.kind:
        return None
    total = 0.0
    for ts, rs in ((t.before, r.before), (t.after, r.after)):
        if ts is None:
            continue
        if rs is None or rs.class_id != ts.class_id:
            return None
        d = float(np.linalg.norm(rs.position_w - ts.position_w))
        if d > radius_m:
            return None
        total += d
    return total


def score_changes(reported: Sequence[ReportedChange], truths: Sequence[TruthChange], mapped_before: Sequence[Side],
                  mapped_after: Sequence[Side], present_at_split: Sequence[Side] = (),
                  radius_m: float = PLACE_RADIUS_M) -> ChangeScore:
    """Match `reported` to `truths` (see the module doc). `mapped_before` / `mapped_after`: the present objects of
    the first and the second session's maps (ground-truth frame); `present_at_split`: the truth objects in the room
    at the split and left unchanged, each at its place (for first-seen additions)."""
    pairs = sorted((d, i, j) for i, t in enumerate(truths) for j, r in enumerate(reported)
                   if (d := _agreement(t, r, radius_m)) is not None)
    match: list[int | None] = [None] * len(truths)
    used: set[int] = set()
    for _, i, j in pairs:
        if match[i] is None and j not in used:
            match[i] = j
            used.add(j)
    reach = 2.0 * radius_m  # mapped_reach
    before = [t.before is None or _near(t.before, mapped_before, reach) for t in truths]
    after = [t.after is None or _near(t.after, mapped_after, reach) for t in truths]
    reasons = []
    for i, t in enumerate(truths):
        if match[i] is not None:
            reasons.append("")
        elif not before[i]:
            reasons.append("not_mapped_before")
        elif not after[i]:
            reasons.append("not_mapped_after")
        elif any(j not in used and _agreement(t, r, reach) is not None for j, r in enumerate(reported)):
            reasons.append("off")
        elif any(j not in used and r.kind != t.kind and _touches(t, r, reach) for j, r in enumerate(reported)):
            reasons.append("other_kind")
        else:
            reasons.append("not_reported")
    # An unmatched addition where an object stood all along (unchanged, or a truth whose earlier side the first session
    # never mapped) is the map seeing it for the first time.
    there = list(present_at_split) + [t.after for i, t in enumerate(truths) if t.after is not None and not before[i]]
    first_seen = tuple(j for j, r in enumerate(reported) if j not in used and r.kind == "added"
                       and r.after is not None and _near(r.after, there, radius_m)
                       and not _near(r.after, mapped_before, reach))
    moves = []
    for i, t in enumerate(truths):
        j = match[i]
        if t.kind != "moved" or j is None:
            continue
        r = reported[j]
        assert r.before is not None and r.after is not None and t.after is not None and t.distance_m is not None
        said = r.distance_m if r.distance_m is not None else float(np.linalg.norm(r.after.position_w
                                                                                  - r.before.position_w))
        moves.append((i, abs(said - t.distance_m), float(np.linalg.norm(r.after.position_w - t.after.position_w))))
    return ChangeScore(tuple(truths), tuple(reported), tuple(match), tuple(before), tuple(after), tuple(reasons),
                       first_seen, tuple(moves), radius_m)


def _touches(t: TruthChange, r: ReportedChange, radius_m: float) -> bool:
    """Whether report `r` has a side of a truth side's class within reach of that side's place."""
    return any(rs is not None and rs.class_id == ts.class_id
               and np.linalg.norm(rs.position_w - ts.position_w) <= radius_m
               for ts in (t.before, t.after) if ts is not None for rs in (r.before, r.after))


def _ratio(a: int, b: int) -> float:
    return a / b if b else math.nan


@dataclass
class _Pool:
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTS, 0))

    def add(self, c: dict[str, int]) -> None:
        for k, v in c.items():
            self.counts[k] = self.counts.get(k, 0) + v

    def figures(self) -> dict[str, Any]:
        c = self.counts
        return {**c, "recall": _ratio(c["matched"], c["truths"]),
                "recall_mapped_before": _ratio(c["matched_mapped_before"], c["mapped_before"]),
                "recall_mapped_both": _ratio(c["matched_mapped_both"], c["mapped_both"]),
                "precision": _ratio(c["correct"], c["reported"])}


def summarise_change_scores(scores: Sequence[ChangeScore]) -> dict[str, Any]:
    """Per kind and over all kinds, pooled over seeds: counts, recall (over all truths, over those mapped before,
    over those mapped on both sides) and precision; the matched moves' displacement and place errors; why truths
    were missed; whether each kind meets precision and recall >= 0.9 and the moves 0.2 m."""
    pools = {k: _Pool() for k in (*KINDS, "all")}
    for s in scores:
        for k in KINDS:
            pools[k].add(s.counts(k))
        pools["all"].add(s.counts())
    disp = [d for s in scores for _, d, _ in s.moves]
    place = [p for s in scores for _, _, p in s.moves]
    per_kind = {k: p.figures() for k, p in pools.items()}

    def stats(values: list[float]) -> dict[str, Any]:
        return {"median_m": float(np.median(values)) if values else math.nan,
                "max_m": max(values) if values else math.nan,
                "within_tolerance": sum(v <= DISPLACEMENT_TOLERANCE_M for v in values)}

    return {
        "radius_m": scores[0].radius_m if scores else PLACE_RADIUS_M, "seeds": len(scores), "kinds": per_kind,
        "moves": {"matched": len(disp), "tolerance_m": DISPLACEMENT_TOLERANCE_M, "displacement_error": stats(disp),
                  "place_error": stats(place)},
        "first_seen": sum(len(s.first_seen) for s in scores),
        "miss_reasons": {why: sum(r == why for s in scores for r in s.miss_reasons) for why in MISS_REASONS},
        "targets_met": {k: _met(per_kind[k]) for k in KINDS}
        | {"displacement": bool(disp) and max(disp) <= DISPLACEMENT_TOLERANCE_M if disp else None},
    }


def _met(figures: dict[str, Any]) -> bool | None:
    """Precision and recall >= 0.9; None when the kind had neither a truth nor a report (nothing to judge)."""
    if not figures.get("truths") and not figures.get("reported"):
        return None
    p, r = figures["precision"], figures["recall"]
    return bool((math.isnan(p) or p >= PRECISION_TARGET) and (math.isnan(r) or r >= RECALL_TARGET))
