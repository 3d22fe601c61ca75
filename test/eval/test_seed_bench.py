"""The seed benchmark: seed ranges, the summary over seeds (ATE statistics, ratios, the 20x rule), the
printed report, and the whole harness on two tiny seeds (render cached, four runs each, bench.json, plot)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.commands.bench import format_report
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.keypoint_scores import CueScore
from changing_slam_ros.eval.seed_bench import (
    RunResult, SeedBenchSpec, SeedResult, parse_seeds, render_cached, run_seed_bench, summarise,
)


def test_seed_ranges_parse_and_bad_ones_name_the_option() -> None:
    assert parse_seeds("100-103") == [100, 101, 102, 103]
    assert parse_seeds("0-2, 7,9") == [0, 1, 2, 7, 9]
    for bad in ("", "a-b", "5-3", "1,,2"):
        with pytest.raises(EvalError, match="--seeds"):
            parse_seeds(bad)


def _seed(seed: int, plain: float | None, full: float | None, c_plain: float, c_full: float, lost: int = 0) -> SeedResult:
    r = SeedResult(seed, {
        "plain": RunResult(plain, 100, 100, 20.0, 10.0), "full": RunResult(full, 100, 100 - lost, 60.0, 30.0),
        "control_plain": RunResult(c_plain, 100, 100, 20.0, 10.0),
        "control_full": RunResult(c_full, 100, 100, 60.0, 30.0),
    })
    r.keypoints = {c: CueScore(8, 2, 2) for c in ("any", "detector", "object_ekf", "class_agnostic")}
    return r


def test_summary_gives_ate_statistics_ratios_and_the_twenty_times_rule() -> None:
    results = [_seed(1, 0.40, 0.01, 0.010, 0.010), _seed(2, 0.05, 0.02, 0.010, 0.0115, lost=3),
               _seed(3, 0.30, 0.03, 0.020, 0.020), _seed(4, None, 0.04, 0.010, 0.010)]
    s = summarise(results)
    assert s["full"]["ate_rmse_m"] == {"median": 0.025, "p90": pytest.approx(0.037), "worst": 0.04}
    assert s["plain"]["not_evaluated"] == 1 and s["full"]["lost_frames"] == 3
    assert s["full"]["seeds_with_lost_frames"] == 1
    assert s["plain_over_20cm"] == {"seeds": [1, 3], "full_20x_lower": [1]}  # 0.03 / 0.30 is only 10x
    assert s["ratio_control_full_to_plain"]["worst"] == pytest.approx(1.15)
    assert s["keypoints"]["any"] == {"tp": 32, "fp": 8, "fn": 8, "precision": 0.8, "recall": 0.8}


def test_report_prints_a_row_per_seed_and_the_summary() -> None:
    from changing_slam_ros.eval.seed_bench import _seed_dict

    results = [_seed(1, 0.40, 0.01, 0.010, 0.010), _seed(2, 0.05, None, 0.010, 0.012)]
    doc = {"per_seed": [_seed_dict(r) for r in results], "summary": summarise(results),
           "cpu_ms_per_frame": {"source": "test", "plain_median": 20.0, "full_median": 60.0}}
    text = format_report(doc)
    assert "  40.00" in text and "   n/a" in text and "0.80/0.80" in text
    assert "CPU ms per frame (test): plain 20.0, full 60.0" in text


def test_bench_command_rejects_bad_seeds_and_jobs(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["bench", "dynamic", "--seeds", "x-y", "--out", "/nonexistent/b"]) == 1
    assert "--seeds 'x-y'" in capsys.readouterr().err
    assert cli_main(["bench", "dynamic", "--jobs", "0", "--out", "/nonexistent/b"]) == 1


@pytest.mark.slow
def test_harness_on_two_tiny_seeds_writes_figures_for_every_run(tmp_path: Path) -> None:
    spec = SeedBenchSpec("random_dynamic", "random_dynamic_control", width=160, height=120, frames=6)
    doc = run_seed_bench(spec, [3, 4], tmp_path / "out", tmp_path / "cache", jobs=2, timing_seeds=1)
    assert doc["complete"] and [r["seed"] for r in doc["per_seed"]] == [3, 4]
    for row in doc["per_seed"]:
        assert set(row["runs"]) == {"plain", "full", "control_plain", "control_full"}
        assert all(run["frames"] == 6 for run in row["runs"].values())
        assert set(row["keypoints"]) == {"any", "detector", "object_ekf", "class_agnostic"}
    cpu = doc["cpu_ms_per_frame"]
    assert cpu["source"] == "serial re-runs of seeds [3]" and cpu["full_median"] > 0
    assert json.loads((tmp_path / "out" / "bench.json").read_text())["seeds"] == [3, 4]
    cached = render_cached(spec, "random_dynamic", 3, tmp_path / "cache")  # already there: not rendered again
    assert (cached / ".complete").stat().st_mtime < (tmp_path / "out" / "bench.json").stat().st_mtime
    from changing_slam_ros.eval.seed_bench_plot import plot_seed_bench

    plot_seed_bench(doc, tmp_path / "ate.png")
    assert (tmp_path / "ate.png").stat().st_size > 1000
    assert not math.isnan(doc["summary"]["ratio_control_full_to_plain"]["median"] or 0.0)
