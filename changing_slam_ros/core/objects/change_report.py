"""What changed between two object maps of one room (ours): objects moved, removed, added and replaced.

Both maps share a frame (the later continued the earlier, `--map-in`, or both were aligned). `compare_maps`
decides, in order: (1) the same object (same id, class and first keyframe) present in both is unchanged within
`same_place_m`, else moved; (2) an earlier present object without such a twin is unchanged when a present later
object of its class lies within `same_place_m`, else gone; (3) later present objects not matched so far are new
at their place (one per place: within `same_place_m` of a matched or a better-supported new object of its class
is the object mapped twice); (4) gone and new objects of one class pair up nearest first: moved (two objects of
different classes swapped are two moves); (5) a gone object and a new one of another class within
`replace_radius_m`: replaced; (6) the rest: removed, added. Every change carries the records it rests on: the
earlier object, the later one, and for a gone object its own record in the later map when that map continued
it (its belief history shows the misses that took it out). With `absent_is_withdrawn` (the later map continued
the earlier and lists every object it holds, of any belief) an earlier object with no record in the later map was
withdrawn by the map itself (found to be a picture on a wall, or merged into another), which says nothing of the
room: it is listed as withdrawn, not removed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.objects.object_evidence import EvidenceConfig, ObjectEvidence, evidence_of
from changing_slam_ros.errors import ConfigError


class ChangeKind(Enum):
    MOVED = "moved"
    REMOVED = "removed"
    ADDED = "added"
    REPLACED = "replaced"


@dataclass(frozen=True)
class ChangeReportConfig:
    """`same_place_m`: centroids closer than this are one place (the object did not move); `replace_radius_m`: a
    gone object and a new one of another class closer than this were replaced; `max_move_m`: gone and new
    objects of one class farther apart than this are a removal and an addition (0: any distance is a move)."""

    same_place_m: float = 0.3
    replace_radius_m: float = 0.5
    max_move_m: float = 0.0

    def __post_init__(self) -> None:
        if self.same_place_m <= 0.0 or self.replace_radius_m < 0.0 or self.max_move_m < 0.0:
            raise ConfigError("change report: expected same_place_m > 0, replace_radius_m >= 0, max_move_m >= 0, got "
                              f"{self.same_place_m}, {self.replace_radius_m}, {self.max_move_m}")


@dataclass(frozen=True)
class Change:
    """One change. `before`: the earlier map's object (None when added); `after`: the later map's object at the
    new place (None when removed); `before_later`: the earlier object's own record in the later map when that map
    continued it (its misses); `distance_m`: from `before` to `after` (moved, replaced), else None."""

    kind: ChangeKind
    before: ObjectEvidence | None
    after: ObjectEvidence | None
    before_later: ObjectEvidence | None = None
    distance_m: float | None = None


@dataclass(frozen=True)
class ChangeReport:
    """The changes (moved, removed, added, replaced, each ordered by the earlier then the later object id), the
    unchanged pairs (earlier, later) and the earlier objects the later map withdrew (see the module doc)."""

    changes: tuple[Change, ...]
    unchanged: tuple[tuple[ObjectEvidence, ObjectEvidence], ...]
    withdrawn: tuple[ObjectEvidence, ...] = ()

    def of_kind(self, kind: ChangeKind) -> list[Change]:
        return [c for c in self.changes if c.kind == kind]

    def counts(self) -> dict[str, int]:
        out = {k.value: len(self.of_kind(k)) for k in ChangeKind}
        out["unchanged"] = len(self.unchanged)
        return out


def _dist(a: ObjectEvidence, b: ObjectEvidence) -> float:
    return float(np.linalg.norm(np.subtract(a.centroid_w, b.centroid_w)))


def _pairs(left: Sequence[ObjectEvidence], right: Sequence[ObjectEvidence], same_class: bool,
           limit_m: float) -> list[tuple[ObjectEvidence, ObjectEvidence, float]]:
    """Greedy nearest-first one-to-one pairs within `limit_m` (inf: any), of one class or of different classes."""
    cand = sorted(((_dist(a, b), a.id, b.id, a, b) for a in left for b in right
                   if (a.class_id == b.class_id) == same_class and _dist(a, b) <= limit_m), key=lambda t: t[:3])
    used_l: set[int] = set()
    used_r: set[int] = set()
    out = []
    for d, _, _, a, b in cand:
        if id(a) in used_l or id(b) in used_r:
            continue
        used_l.add(id(a))
        used_r.add(id(b))
        out.append((a, b, d))
    return out


def compare_maps(before: Sequence[ObjectEvidence], after: Sequence[ObjectEvidence],
                 config: ChangeReportConfig = ChangeReportConfig(), absent_is_withdrawn: bool = False) -> ChangeReport:
    """The change report from the earlier map's objects to the later map's (see the module doc)."""
    later_of = {(a.id, a.class_id, a.first_keyframe): a for a in after}
    after_present = [a for a in after if a.present]
    unchanged: list[tuple[ObjectEvidence, ObjectEvidence]] = []
    changes: list[Change] = []
    gone: list[tuple[ObjectEvidence, ObjectEvidence | None]] = []  # (earlier object, its own later record)
    used: set[int] = set()  # id() of the later objects taken
    unresolved = []
    withdrawn = []
    for b in sorted((b for b in before if b.present), key=lambda o: o.id):  # 1. the same object, continued
        twin = later_of.get((b.id, b.class_id, b.first_keyframe))
        if twin is None and absent_is_withdrawn:
            withdrawn.append(b)
        elif twin is None:
            unresolved.append(b)
        elif twin.present:
            used.add(id(twin))
            d = _dist(b, twin)
            if d <= config.same_place_m:
                unchanged.append((b, twin))
            else:
                changes.append(Change(ChangeKind.MOVED, b, twin, twin, d))
        else:
            gone.append((b, twin))
    for b in unresolved:  # 2. by place
        near = [a for a in after_present if id(a) not in used and a.class_id == b.class_id
                and _dist(a, b) <= config.same_place_m]
        if near:
            a = min(near, key=lambda a: (_dist(a, b), a.id))
            used.add(id(a))
            unchanged.append((b, a))
        else:
            gone.append((b, None))
    kept = [a for a in after_present if id(a) in used]
    new: list[ObjectEvidence] = []
    for a in sorted((a for a in after_present if id(a) not in used), key=lambda a: (-a.n_points, a.id)):
        if not any(k.class_id == a.class_id and _dist(k, a) <= config.same_place_m for k in kept + new):
            new.append(a)  # 3. the best-supported record of a place; others there are the object mapped twice
    limit = config.max_move_m if config.max_move_m > 0.0 else math.inf
    gone_b = [b for b, _ in gone]
    later_rec = {id(b): rec for b, rec in gone}
    for b, a, d in _pairs(gone_b, new, True, limit):  # 4. moved
        if d <= config.same_place_m:
            unchanged.append((b, a))
        else:
            changes.append(Change(ChangeKind.MOVED, b, a, later_rec[id(b)], d))
        gone_b.remove(b)
        new.remove(a)
    for b, a, d in _pairs(gone_b, new, False, config.replace_radius_m):  # 5. replaced
        changes.append(Change(ChangeKind.REPLACED, b, a, later_rec[id(b)], d))
        gone_b.remove(b)
        new.remove(a)
    changes += [Change(ChangeKind.REMOVED, b, None, later_rec[id(b)]) for b in gone_b]  # 6.
    changes += [Change(ChangeKind.ADDED, None, a) for a in new]
    order = {k: i for i, k in enumerate(ChangeKind)}
    changes.sort(key=lambda c: (order[c.kind], -1 if c.before is None else c.before.id,
                                -1 if c.after is None else c.after.id))
    return ChangeReport(tuple(changes), tuple(sorted(unchanged, key=lambda p: p[0].id)), tuple(withdrawn))


def compare_object_maps(before: Sequence[MapObject], after: Sequence[MapObject],
                        evidence: EvidenceConfig = EvidenceConfig(),
                        config: ChangeReportConfig = ChangeReportConfig()) -> ChangeReport:
    """`compare_maps` on two lists of MapObjects (each turned into its evidence record)."""
    return compare_maps([evidence_of(o, evidence) for o in before], [evidence_of(o, evidence) for o in after], config)
