"""The changing-room scoring on a constructed semantic map with known answers."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from changing_slam_ros.core.objects.semantic_map import SemanticObject
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.changing_bench import (
    SeedResult, load_changing_truth, missed_reasons, score_semantic_map, summarise,
)
from changing_slam_ros.eval.seed_bench import parse_seeds


def _obj(name: str, class_id: int, class_name: str, centre: tuple[float, float, float],
         half: float = 0.2) -> dict[str, object]:
    lo = [c - half for c in centre]
    hi = [c + half for c in centre]
    return {"name": name, "class_id": class_id, "class_name": class_name, "centre_w": list(centre),
            "box_min_w": lo, "box_max_w": hi}


def _truth(tmp_path: Path) -> Path:
    chair0, chair1 = _obj("chair_a", 56, "chair", (1.0, 0.0, 0.5)), _obj("chair_a", 56, "chair", (1.0, 1.5, 0.5))
    plant = _obj("plant_b", 58, "potted plant", (2.0, 1.0, 0.6))
    suitcase = _obj("suitcase_c", 28, "suitcase", (0.0, 2.0, 0.35))
    tv = _obj("tv_d", 62, "tv", (3.0, 0.0, 1.0))
    clock = _obj("clock_w", 74, "clock", (-2.9, 0.5, 1.3), 0.15)
    table = _obj("table", 60, "dining table", (-1.0, -1.8, 0.38), 0.5)
    doc = {
        "format": "changing_slam_ros changing-room truth v1", "seed": 7,
        "laps": [{"objects": [chair0, plant, suitcase, clock, table]},
                 {"objects": [chair1, plant, tv, clock, table]}],
        "wall_items": [
            {"name": "picture_0", "is_object": False, "depicts": "potted plant", "box_min_w": [2.99, -1.4, 0.9],
             "box_max_w": [3.0, -0.6, 1.5]},
            {**clock, "is_object": True},
        ],
        "changes": [{"kind": "moved_long"}, {"kind": "removed"}, {"kind": "added"}],
    }
    path = tmp_path / "changing_truth.json"
    path.write_text(json.dumps(doc))
    return path


def _est(i: int, class_id: int, centre: tuple[float, float, float]) -> SemanticObject:
    return SemanticObject(i, class_id, "x", centre, centre, (0.3, 0.3, 0.3), 0.7, True, 40, 0, 5)


def test_score_counts_matches_stale_pictures_and_other_spurious_on_a_constructed_map(tmp_path: Path) -> None:
    truth = load_changing_truth(_truth(tmp_path))
    estimates = [
        _est(1, 56, (1.05, 1.45, 0.5)),   # the moved chair at its new place: a match (7.1 cm)
        _est(2, 58, (2.1, 1.0, 0.6)),     # the plant: a match (10 cm)
        _est(3, 62, (3.0, 0.5, 1.0)),     # the added tv, 0.5 m off: not a match, spurious (other)
        _est(4, 56, (1.0, 0.05, 0.5)),    # the chair's old place: stale
        _est(5, 28, (0.0, 2.0, 0.35)),    # the removed suitcase: stale
        _est(6, 58, (2.95, -1.0, 1.2)),   # the photo of a plant on the east wall: a picture mapped as an object
        _est(7, 74, (-2.8, 0.5, 1.3)),    # the wall clock: a match (10 cm)
        _est(8, 60, (-1.0, -1.7, 0.4)),   # the table: matches structure, counts for precision only
    ]
    s = score_semantic_map(estimates, truth)
    assert s.n_present == 4 and s.n_active == 8
    assert [m[:2] for m in s.matches] == [(1, "chair_a"), (2, "plant_b"), (7, "clock_w"), (8, "table")]
    assert s.matches[0][2] == pytest.approx(math.hypot(0.05, 0.05))
    assert s.missed == ("tv_d",)
    assert s.stale == ((4, "chair_a"), (5, "suitcase_c"))
    assert s.spurious_pictures == ((6, "picture_0"),)
    assert s.spurious_other == (3,)
    assert s.recall == pytest.approx(3 / 4)
    assert s.precision == pytest.approx(4 / 8)


def test_score_against_the_first_lap_finds_the_old_places_present(tmp_path: Path) -> None:
    truth = load_changing_truth(_truth(tmp_path))
    s = score_semantic_map([_est(4, 56, (1.0, 0.05, 0.5)), _est(5, 28, (0.0, 2.0, 0.35))], truth, lap=0)
    assert [m[1] for m in s.matches] == ["chair_a", "suitcase_c"]
    assert s.stale == () and s.recall == pytest.approx(2 / 4) and s.precision == 1.0


def test_match_on_box_center_uses_the_box_centre(tmp_path: Path) -> None:
    truth = load_changing_truth(_truth(tmp_path))
    far_centroid = SemanticObject(1, 58, "x", (2.5, 1.0, 0.6), (2.05, 1.0, 0.6), (0.4, 0.4, 0.6), 0.7, True, 40, 0, 5)
    assert score_semantic_map([far_centroid], truth).matches == ()
    assert [m[1] for m in score_semantic_map([far_centroid], truth, match_on="box_center").matches] == ["plant_b"]


def test_summary_pools_seeds_and_counts_targets(tmp_path: Path) -> None:
    truth = load_changing_truth(_truth(tmp_path))
    good = score_semantic_map([_est(1, 56, (1.0, 1.5, 0.5)), _est(2, 58, (2.0, 1.0, 0.6)),
                               _est(3, 62, (3.0, 0.0, 1.0)), _est(7, 74, (-2.9, 0.5, 1.3))], truth)
    bad = score_semantic_map([_est(6, 58, (2.95, -1.0, 1.2))], truth)
    results = [SeedResult(1, good, 100, 100, 0.010, 0.009, 1, 0), SeedResult(2, bad, 100, 90, 0.030, 0.010, 2, 1),
               SeedResult(3, None, 0, 0, math.nan, math.nan, 0, 0, error="boom")]
    s = summarise(results)
    assert s["scored"] == 2 and s["failed"] == [3]
    assert s["recall_pooled"] == pytest.approx(4 / 8) and s["precision_pooled"] == pytest.approx(4 / 5)
    assert s["recall_mean"] == pytest.approx(0.5) and s["precision_mean"] == pytest.approx(0.5)
    assert s["spurious_pictures"] == 1 and s["stale"] == 0 and s["wrong_loops"] == 1
    assert s["ate_ratio_max"] == pytest.approx(3.0)
    assert s["seeds_meeting"] == {"recall": 1, "precision": 1, "no_stale": 2, "no_picture": 1, "ate_ratio": 1,
                                  "no_wrong_loop": 2}


def test_truth_loader_names_the_file_on_bad_input(tmp_path: Path) -> None:
    bad = tmp_path / "changing_truth.json"
    bad.write_text('{"format": "something else"}')
    with pytest.raises(EvalError, match="changing_truth.json: format"):
        load_changing_truth(bad)
    bad.write_text('{"format": "changing_slam_ros changing-room truth v1", "seed": 1}')
    with pytest.raises(EvalError, match="malformed changing-room truth"):
        load_changing_truth(bad)
    with pytest.raises(EvalError, match="lap 5"):
        score_semantic_map([], load_changing_truth(_truth(tmp_path)), lap=5)


def test_seed_ranges_parse_and_bad_ones_fail() -> None:
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("200-202,7") == [200, 201, 202, 7]
    for text in ("3-1", "a", "-2"):
        with pytest.raises(EvalError, match="--seeds"):
            parse_seeds(text)


def test_a_perfect_map_of_a_family_seed_scores_one_and_its_pictures_count_as_pictures(tmp_path: Path) -> None:
    from changing_slam_ros.sim.random_changing import random_changing

    path = tmp_path / "changing_truth.json"
    path.write_text(dict(random_changing(2).extra_files)["changing_truth.json"])
    truth = load_changing_truth(path)
    final = [o for o in truth.laps[-1] if o.class_id != 60]
    perfect = [_est(i, o.class_id, tuple(o.centre_w)) for i, o in enumerate(final)]
    s = score_semantic_map(perfect, truth)
    assert s.recall == 1.0 and s.precision == 1.0 and s.n_present == len(final)
    pictures = [w for w in truth.wall_items if not w.is_object]
    on_walls = [_est(100 + k, 58, tuple((w.box_min_w + w.box_max_w) / 2)) for k, w in enumerate(pictures)]
    s = score_semantic_map(perfect + on_walls, truth)
    assert len(s.spurious_pictures) == len(pictures) and s.spurious_other == ()
    assert s.precision == pytest.approx(len(final) / (len(final) + len(pictures)))


def test_the_plot_is_written(tmp_path: Path) -> None:
    from changing_slam_ros.eval.changing_bench_plot import plot_changing_bench

    truth = load_changing_truth(_truth(tmp_path))
    score = score_semantic_map([_est(1, 56, (1.0, 1.5, 0.5))], truth)
    png = tmp_path / "bench.png"
    plot_changing_bench([SeedResult(1, score, 10, 10, 0.01, 0.01, 0, 0),
                         SeedResult(2, None, 0, 0, math.nan, math.nan, 0, 0, error="x")], png, title="t")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_changing_refuses_bad_seeds_on_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from changing_slam_ros.cli import main

    assert main(["bench", "changing", "--seeds", "9-1", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seeds '9-1'" in err[0]


def test_missed_objects_get_their_reason(tmp_path: Path) -> None:
    truth = load_changing_truth(_truth(tmp_path))
    active = [_est(1, 62, (3.0, 0.45, 1.0)),   # the tv, 0.45 m off: "off"
              _est(2, 41, (1.0, 1.5, 0.5))]    # a cup where the chair stands: the chair is "wrong_class"
    inactive = [_est(3, 58, (2.0, 1.05, 0.6))]  # the plant, belief too low: "inactive"
    score = score_semantic_map(active, truth)
    reasons = missed_reasons(score, truth, active, active + inactive)
    assert reasons == {"chair_a": "wrong_class", "plant_b": "inactive", "tv_d": "off", "clock_w": "unmapped"}
    s = summarise([SeedResult(1, score, 10, 10, 0.01, 0.01, 0, 0, missed_reasons=tuple(sorted(reasons.items())))])
    assert s["missed_reasons"] == {"inactive": 1, "off": 1, "wrong_class": 1, "unmapped": 1}
