"""The change-report scoring on constructed truths and reports with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from changing_slam_ros.core.objects.change_report import compare_maps
from changing_slam_ros.core.objects.object_evidence import ObjectEvidence
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.change_scores import (
    ReportedChange, Side, score_changes, session_split, summarise_change_scores, truth_changes,
)
from changing_slam_ros.eval.change_sessions import read_reported_changes
from changing_slam_ros.eval.changing_bench import ChangingTruth, TruthObject
from changing_slam_ros.io.change_report_file import write_change_report

NAMES = {56: "chair", 58: "potted plant", 28: "suitcase", 39: "bottle", 57: "couch", 62: "tv", 41: "cup"}


def _o(name: str, class_id: int, centre: tuple[float, float, float]) -> TruthObject:
    c = np.array(centre, float)
    return TruthObject(name, class_id, NAMES[class_id], c, c - 0.2, c + 0.2)


def _truth() -> ChangingTruth:
    """One change of each kind: chair_a moved 2 m, suitcase_c removed, a tv added, bottle_d replaced by a cup, and
    plant_b and chair_f swapped; couch_e and suitcase_g stay."""
    start = (_o("chair_a", 56, (1, 0, 0.5)), _o("plant_b", 58, (2, 1, 0.6)), _o("suitcase_c", 28, (0, 2, 0.35)),
             _o("bottle_d", 39, (-1, -1.5, 0.8)), _o("couch_e", 57, (3, 2, 0.4)), _o("chair_f", 56, (-2, 1, 0.5)),
             _o("suitcase_g", 28, (-2, -2, 0.35)))
    end = (_o("chair_a", 56, (1, 2, 0.5)), _o("plant_b", 58, (-2, 1, 0.6)), _o("added_x", 62, (3, 0, 1.0)),
           _o("added_y", 41, (-1, -1.5, 0.8)), _o("couch_e", 57, (3, 2, 0.4)), _o("chair_f", 56, (2, 1, 0.5)),
           _o("suitcase_g", 28, (-2, -2, 0.35)))
    changes = ({"t_s": 40.0, "kind": "swapped", "object": "plant_b", "other": "chair_f"},
               {"t_s": 30.0, "kind": "moved_long", "object": "chair_a", "other": ""},
               {"t_s": 31.0, "kind": "removed", "object": "suitcase_c", "other": ""},
               {"t_s": 32.0, "kind": "added", "object": "added_x", "other": ""},
               {"t_s": 33.0, "kind": "replaced", "object": "bottle_d", "other": "added_y"})
    return ChangingTruth(3, (start, end), (), changes, start)


def _s(label: str, class_id: int, p: tuple[float, float, float]) -> Side:
    return Side(label, class_id, NAMES[class_id], np.array(p, float))


def _mapped_before() -> list[Side]:
    return [_s("1", 56, (1.05, 0.05, 0.5)), _s("2", 58, (2, 1, 0.6)), _s("3", 28, (0.1, 2, 0.35)),
            _s("4", 39, (-1, -1.5, 0.8)), _s("6", 56, (-2, 1, 0.5)), _s("7", 57, (3, 2, 0.4))]


def _mapped_after() -> list[Side]:
    return [_s("1", 56, (1, 1.9, 0.5)), _s("2", 58, (-1.9, 1, 0.6)), _s("9", 62, (3, 0.2, 1.0)),
            _s("10", 41, (-1, -1.45, 0.8)), _s("6", 56, (2, 1.25, 0.5)), _s("11", 28, (-2, -2, 0.35))]


def _unchanged() -> list[Side]:
    return [_s("couch_e", 57, (3, 2, 0.4)), _s("suitcase_g", 28, (-2, -2, 0.35))]


def test_the_truths_changes_become_one_verdict_each_and_a_swap_two_moves() -> None:
    truths = truth_changes(_truth())
    assert [(t.kind, t.truth_kind) for t in truths] == [
        ("moved", "moved_long"), ("removed", "removed"), ("added", "added"), ("replaced", "replaced"),
        ("moved", "swapped"), ("moved", "swapped")]
    assert [t.before.label if t.before else None for t in truths] == [
        "chair_a", "suitcase_c", None, "bottle_d", "plant_b", "chair_f"]
    assert [t.after.label if t.after else None for t in truths] == [
        "chair_a", None, "added_x", "added_y", "plant_b", "chair_f"]
    assert truths[0].distance_m == pytest.approx(2.0)
    assert truths[3].before.class_id == 39 and truths[3].after.class_id == 41  # type: ignore[union-attr]
    assert [t.truth_kind for t in truth_changes(_truth(), until_s=32.0)] == ["moved_long", "removed"]


def test_one_report_of_each_kind_scores_exact_precision_recall_and_move_errors() -> None:
    b, a = _mapped_before(), _mapped_after()
    reported = [
        ReportedChange("moved", b[0], a[0], 1.95),   # chair_a: 5 cm short, new place 10 cm off
        ReportedChange("removed", b[2], None),        # suitcase_c
        ReportedChange("added", None, a[2]),          # the tv
        ReportedChange("replaced", b[3], a[3], 0.05),  # bottle -> cup
        ReportedChange("moved", b[1], a[1], 3.9),     # the swap: plant_b, 10 cm short
        ReportedChange("moved", b[4], a[4], 4.35),    # and chair_f: 35 cm long, new place 25 cm off
        ReportedChange("removed", b[5], None),        # the couch never left: false
        ReportedChange("added", None, a[5]),          # suitcase_g, there all along, unseen by the first session
        ReportedChange("added", None, _s("12", 56, (0, -2, 0.5))),  # nothing there: false
    ]
    s = score_changes(reported, truth_changes(_truth()), b, a, _unchanged())
    assert s.truth_match == (0, 1, 2, 3, 4, 5)
    assert s.first_seen == (7,)
    assert all(s.mapped_before) and all(s.mapped_after) and s.miss_reasons == ("",) * 6
    assert s.counts("moved") == {"truths": 3, "matched": 3, "mapped_before": 3, "matched_mapped_before": 3,
                                 "mapped_both": 3, "matched_mapped_both": 3, "reported": 3, "correct": 3}
    assert s.counts("removed")["reported"] == 2 and s.counts("removed")["correct"] == 1
    assert s.counts("added")["reported"] == 2 and s.counts("added")["correct"] == 1  # the first-seen one left out
    assert s.counts("replaced")["reported"] == s.counts("replaced")["correct"] == 1
    (i0, d0, p0), (i1, d1, p1), (i2, d2, p2) = s.moves
    assert (i0, i1, i2) == (0, 4, 5)
    assert (d0, d1, d2) == pytest.approx((0.05, 0.1, 0.35))
    assert (p0, p1, p2) == pytest.approx((0.1, 0.1, 0.25))
    summary = summarise_change_scores([s])
    k = summary["kinds"]
    assert (k["moved"]["precision"], k["moved"]["recall"]) == (1.0, 1.0)
    assert (k["removed"]["precision"], k["removed"]["recall"]) == (0.5, 1.0)
    assert (k["added"]["precision"], k["added"]["recall"]) == (0.5, 1.0)
    assert (k["replaced"]["precision"], k["replaced"]["recall"]) == (1.0, 1.0)
    assert k["all"]["precision"] == pytest.approx(6 / 8) and k["all"]["recall"] == 1.0
    assert summary["moves"]["displacement_error"]["within_tolerance"] == 2
    assert summary["moves"]["place_error"]["max_m"] == pytest.approx(0.25)
    assert summary["first_seen"] == 1
    assert summary["targets_met"] == {"moved": True, "removed": False, "added": False, "replaced": True,
                                      "displacement": False}


def test_a_wrong_class_or_a_place_beyond_the_radius_is_no_match() -> None:
    b, a = _mapped_before(), _mapped_after()
    truths = truth_changes(_truth())
    far = _s("1", 56, (1.0, 2.35, 0.5))  # 35 cm from chair_a's new place
    s = score_changes([ReportedChange("moved", b[0], far, 2.3), ReportedChange("removed", _s("3", 39, (0, 2, 0.35)),
                                                                               None)], truths, b, a)
    assert s.truth_match[:2] == (None, None)
    assert s.miss_reasons[:2] == ("off", "not_reported")  # the move within twice the radius; the removal's class
    assert s.counts()["correct"] == 0 and s.counts()["reported"] == 2


def test_an_object_mapped_within_twice_the_radius_counts_as_mapped() -> None:
    """The first session mapped suitcase_c 0.5 m off and the second the tv 0.7 m off: mapped before, not after."""
    b = [_s("3", 28, (0.5, 2, 0.35))]
    a = [_s("9", 62, (3, 0.7, 1.0))]
    s = score_changes([], truth_changes(_truth())[1:3], b, a)
    assert s.mapped_before == (True, True) and s.mapped_after == (True, False)
    assert s.miss_reasons == ("not_reported", "not_mapped_after")


def test_recall_is_split_by_what_the_maps_held_and_misses_say_why() -> None:
    """suitcase_c never mapped by the first session; plant_b not mapped at its new place; chair_a reported as a removal
    and an addition; the tv mapped but not reported. chair_a's move is all the change logic could have got."""
    b = [o for o in _mapped_before() if o.label != "3"]
    a = [o for o in _mapped_after() if o.label != "2"]
    truths = truth_changes(_truth())
    reported = [ReportedChange("removed", b[0], None), ReportedChange("added", None, a[0]),
                ReportedChange("replaced", b[2], a[2], 0.1), ReportedChange("moved", b[3], a[3], 4.0)]
    s = score_changes(reported, truths, b, a, _unchanged())
    assert s.mapped_before == (True, False, True, True, True, True)
    assert s.mapped_after == (True, True, True, True, False, True)
    assert s.miss_reasons == ("other_kind", "not_mapped_before", "not_reported", "", "not_mapped_after", "")
    c = s.counts()
    assert (c["truths"], c["matched"], c["mapped_before"], c["matched_mapped_before"]) == (6, 2, 5, 2)
    assert (c["mapped_both"], c["matched_mapped_both"]) == (4, 2)
    f = summarise_change_scores([s])["kinds"]["all"]
    assert (f["recall"], f["recall_mapped_before"], f["recall_mapped_both"]) == pytest.approx((2 / 6, 2 / 5, 2 / 4))
    assert summarise_change_scores([s])["miss_reasons"] == {"not_mapped_before": 1, "not_mapped_after": 1, "off": 0,
                                                            "other_kind": 1, "not_reported": 1}


def test_a_move_whose_old_place_session_1_never_mapped_reported_as_added_is_first_seen() -> None:
    b = [o for o in _mapped_before() if o.label != "1"]
    a = _mapped_after()
    s = score_changes([ReportedChange("added", None, a[0])], truth_changes(_truth()), b, a, _unchanged())
    assert s.first_seen == (0,) and s.counts()["reported"] == 0
    assert s.miss_reasons[0] == "not_mapped_before"


def test_summary_pools_seeds_and_leaves_kinds_without_truth_or_report_unjudged() -> None:
    b, a = _mapped_before(), _mapped_after()
    truths = truth_changes(_truth())
    one = score_changes([ReportedChange("moved", b[0], a[0], 2.0)], truths[:1], b, a)
    two = score_changes([], truths[:1], b, a)
    s = summarise_change_scores([one, two])
    assert s["seeds"] == 2 and s["kinds"]["moved"]["recall"] == 0.5 and s["kinds"]["moved"]["precision"] == 1.0
    assert s["targets_met"]["removed"] is None and s["targets_met"]["moved"] is False
    assert math.isnan(s["kinds"]["removed"]["recall"])


def test_the_split_gives_session_1_the_frames_before_the_first_change() -> None:
    times = [k / 5.0 for k in range(300)]  # 5 frames per second
    assert session_split([30.1, 12.3], times) == 62  # frames 0 .. 12.2 s
    assert session_split([12.2], times) == 61  # a change at a frame's own time: that frame is after it
    with pytest.raises(EvalError, match="lists no change"):
        session_split([], times)
    with pytest.raises(EvalError, match="no frame before it"):
        session_split([0.0], times)
    with pytest.raises(EvalError, match="no frame after it"):
        session_split([60.0], times)


def _ev(i: int, class_id: int, p: tuple[float, float, float]) -> ObjectEvidence:
    return ObjectEvidence(i, class_id, NAMES[class_id], p, (0.4, 0.4, 0.4), 0.9, 40, True, i, i)


def test_a_written_report_reads_back_with_each_side_in_its_sessions_frame(tmp_path) -> None:
    report = compare_maps([_ev(1, 56, (1, 0, 0.5)), _ev(2, 28, (0, 2, 0.35))],
                          [_ev(5, 56, (1, 2, 0.5)), _ev(6, 62, (3, 0, 1))])
    write_change_report(tmp_path / "changes.json", report)
    T1, T2 = np.eye(4), np.eye(4)
    T2[:3, 3] = (0.0, 0.0, 0.1)
    got = read_reported_changes(tmp_path / "changes.json", T1, T2)
    assert [c.kind for c in got] == ["moved", "removed", "added"]
    assert got[0].before is not None and got[0].after is not None and got[0].distance_m == pytest.approx(2.0)
    assert got[0].before.position_w == pytest.approx([1, 0, 0.5]) and got[0].after.position_w == pytest.approx([1, 2, 0.6])
    assert got[1].after is None and got[2].before is None and got[2].after.class_id == 62  # type: ignore[union-attr]
    (tmp_path / "bad.json").write_text('{"changes": [{"kind": "vanished"}]}')
    with pytest.raises(EvalError, match="bad.json: unknown change kind 'vanished'"):
        read_reported_changes(tmp_path / "bad.json", T1, T2)


def test_a_family_seeds_truth_splits_before_its_change_and_lists_the_move(tmp_path) -> None:
    """Seed 30: one chair moved 1.2-4.5 m at 36.1 s (5 frames per second): the first session gets 0-180."""
    from changing_slam_ros.eval.changing_bench import load_changing_truth
    from changing_slam_ros.sim.random_changing import random_changing

    path = tmp_path / "changing_truth.json"
    path.write_text(dict(random_changing(30).extra_files)["changing_truth.json"])
    truth = load_changing_truth(path)
    (t,) = truth_changes(truth)
    assert (t.kind, t.truth_kind, t.before.class_name) == ("moved", "moved_long", "chair")  # type: ignore[union-attr]
    assert 1.2 - 0.3 <= t.distance_m <= 4.5 + 0.3  # type: ignore[operator]  # box centres: the turn moves them a little
    frames = [k / 5.0 for k in range(int(truth.changes[0]["t_s"] * 5) + 40)]
    assert session_split([float(c["t_s"]) for c in truth.changes], frames) == 181


def test_the_bench_prints_and_writes_each_seeds_verdicts_and_the_change_summary() -> None:
    import json as json_

    from changing_slam_ros.commands.bench_changing import format_seed, format_summary
    from changing_slam_ros.eval.change_sessions import SessionResult, failed_sessions
    from changing_slam_ros.eval.changing_bench import SeedResult, summarise

    b, a = _mapped_before(), _mapped_after()
    truths = truth_changes(_truth())
    score = score_changes([ReportedChange("moved", b[0], a[0], 1.95), ReportedChange("removed", b[5], None)],
                          truths, b, a, _unchanged())
    results = [SeedResult(1, None, 0, 0, math.nan, math.nan, 0, 0, error="x",
                          sessions=SessionResult(1, 150, 400, True, score)),
               SeedResult(2, None, 0, 0, math.nan, math.nan, 0, 0, error="y",
                          sessions=failed_sessions(2, "second session: exit 1", 100, 300))]
    lines = format_seed(results[0]).splitlines()
    assert lines[1].startswith("seed    1  sessions 150+250 frames  relocalised  truth: moved_long chair chair_a 2.00 m: "
                               "ok (distance off 0.05 m, place off 0.10 m); removed suitcase suitcase_c: missed "
                               "(not_reported);")
    assert lines[1].endswith("other reports: removed couch #7 (false)")
    assert format_seed(results[1]).splitlines()[1] == "seed    2  sessions 100+200 frames  failed: second session: exit 1"
    s = summarise(results)
    assert s["changes"]["seeds"] == 1 and s["changes"]["failed"] == [2]
    assert s["changes"]["kinds"]["moved"]["recall"] == pytest.approx(1 / 3)
    text = format_summary(s)
    assert "  moved    P 1/1 R 1/3 (mapped before 1/3, both sides 1/3)" in text
    assert "change-report targets (P and R >= 0.9, moves within 0.2 m): moved no, removed no" in text
    doc = json_.loads(json_.dumps([r.to_dict() for r in results]))
    assert doc[0]["sessions"]["score"]["reported"][1]["verdict"] == "false"


@pytest.mark.slow
def test_bench_changing_with_sessions_runs_and_scores_a_small_seed(tmp_path, capsys) -> None:
    """Seed 30 at 320x240, its first 198 frames, no control: the first session gets the 181 frames before the chair
    moves, the second the other 17 from its map; the JSON and the printed lines carry the sessions (a render and three
    runs: 90 s on two busy cores)."""
    import json as json_

    from changing_slam_ros.cli import main

    out = tmp_path / "bench"
    assert main(["bench", "changing", "--seeds", "30", "--frames", "198", "--width", "320", "--height", "240",
                 "--no-control", "--sessions", "--out", str(out), "--cache", str(tmp_path / "cache")]) == 0
    doc = json_.loads((out / "changing_bench.json").read_text())
    sessions = doc["per_seed"][0]["sessions"]
    assert doc["sessions"] is True and [sessions["split_frame"], sessions["frames"]] == [181, 198]
    assert sessions["error"] == "" and sessions["relocalised"] is True
    assert [t["truth_kind"] for t in sessions["score"]["truths"]] == ["moved_long"]
    assert doc["summary"]["changes"]["kinds"]["moved"]["truths"] == 1
    s2 = json_.loads((out / "runs" / "s30_session2" / "metrics.json").read_text())
    assert s2["frames"] == 17 and "changes" in s2
    assert "seed   30  sessions 181+17 frames  relocalised  truth: moved_long chair" in capsys.readouterr().out


def test_a_summary_of_no_scored_seed_has_every_count_at_zero() -> None:
    s = summarise_change_scores([])
    assert s["kinds"]["all"]["truths"] == 0 and math.isnan(s["kinds"]["all"]["recall"])
    assert all(v is None for v in s["targets_met"].values())
