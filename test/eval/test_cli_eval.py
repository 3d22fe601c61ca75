"""`changing-slam eval ate|rpe|report`: tables, JSON, plots and one-line errors."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers import TUM_REFERENCE, require

from changing_slam_ros.cli import main

FIXTURE = json.loads((Path(__file__).parent / "evo_reference.json").read_text())


def _paths() -> tuple[str, str]:
    data = require(TUM_REFERENCE)
    return str(data / "freiburg1_xyz-groundtruth.txt"), str(data / "freiburg1_xyz-rgbdslam_drift.txt")


def _evo_rmse(est: str, **match: object) -> float:
    rows = [r for r in FIXTURE["ape"] if r["est"] == est and all(r[k] == v for k, v in match.items())]
    assert len(rows) == 1
    return float(rows[0]["stats"]["rmse"])


def test_eval_ate_prints_a_table_with_evo_s_rmse(capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = _paths()
    assert main(["eval", "ate", gt, est]) == 0
    out = capsys.readouterr().out
    rmse = _evo_rmse(Path(est).name, max_diff_s=0.02, offset_s=0.0, sim3=False)
    assert f"rmse   {rmse:12.6f}" in out
    assert "associated  " in out and "alignment   se3" in out


def test_eval_ate_json_with_max_diff_and_offset_equals_evo(capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = _paths()
    assert main(["eval", "ate", gt, est, "--max-diff", "0.02", "--offset", "-0.012", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    expected = _evo_rmse(Path(est).name, max_diff_s=0.02, offset_s=-0.012, sim3=False)
    assert result["rmse"] == pytest.approx(expected, abs=1e-6)
    assert result["offset_s"] == -0.012 and result["est"] == est


def test_eval_ate_sim3_reports_the_scale_of_a_monocular_estimate(capsys: pytest.CaptureFixture[str]) -> None:
    data = require(TUM_REFERENCE)
    gt, est = data / "fr2_desk_groundtruth.txt", data / "fr2_desk_ORB_kf_mono.txt"
    assert main(["eval", "ate", str(gt), str(est), "--sim3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["alignment"] == "sim3"
    assert result["rmse"] == pytest.approx(_evo_rmse(est.name, max_diff_s=0.02, offset_s=0.0, sim3=True), abs=1e-6)
    assert result["transform"]["scale"] != pytest.approx(1.0, abs=0.05)


def test_eval_rpe_prints_translation_and_rotation(capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = _paths()
    assert main(["eval", "rpe", gt, est, "--delta", "10", "--pairs", "all", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    rows = {r["relation"]: r for r in FIXTURE["rpe"] if r["est"] == Path(est).name
            and r["delta_frames"] == 10 and r["all_pairs"] and not r["sim3"]}
    assert result["translation_m"]["rmse"] == pytest.approx(rows["translation_m"]["stats"]["rmse"], abs=1e-6)
    assert result["rotation_deg"]["rmse"] == pytest.approx(rows["rotation_deg"]["stats"]["rmse"], abs=1e-6)
    assert main(["eval", "rpe", gt, est, "--delta", "1", "--delta-unit", "seconds"]) == 0
    out = capsys.readouterr().out
    assert "(all), delta 1 seconds" in out and "trans (m)" in out and "rot (deg)" in out


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


def test_eval_ate_plot_shows_both_trajectories_and_the_error(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = _paths()
    png = tmp_path / "sub" / "ate.png"
    assert main(["eval", "ate", gt, est, "--plot", str(png)]) == 0
    assert _png_size(png) == (1200, 500)
    img = cv2.imread(str(png))  # BGR
    left, right = img[:, :600].astype(int), img[:, 600:].astype(int)

    def count(part: np.ndarray, rgb: tuple[int, int, int]) -> int:
        return int(np.sum(np.all(np.abs(part - np.array(rgb[::-1])) < 30, axis=2)))

    assert count(left, (31, 119, 180)) > 500  # estimate, tab:blue
    assert count(left, (0, 0, 0)) > 500  # ground truth, black
    assert count(right, (214, 39, 40)) > 500  # ATE curve, tab:red
    assert [p.name for p in png.parent.iterdir()] == ["ate.png"]  # no temporary left behind


def test_eval_rpe_plot_is_written(tmp_path: Path) -> None:
    gt, est = _paths()
    png = tmp_path / "rpe.png"
    assert main(["eval", "rpe", gt, est, "--plot", str(png)]) == 0
    assert _png_size(png) == (1000, 600)


def test_eval_report_writes_json_atomically_and_prints_a_summary(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    gt, est = _paths()
    out = tmp_path / "metrics.json"
    assert main(["eval", "report", gt, est, "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["ate"]["rmse"] == pytest.approx(
        _evo_rmse(Path(est).name, max_diff_s=0.02, offset_s=0.0, sim3=False), abs=1e-6)
    assert capsys.readouterr().out.startswith("ATE rmse ")


def test_an_empty_estimate_exits_1_with_one_line_naming_it(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    gt, _ = _paths()
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    for metric in ("ate", "rpe", "report"):
        assert main(["eval", metric, gt, str(empty)]) == 1
        captured = capsys.readouterr()
        assert captured.out == ""
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and str(empty) in lines[0] and "empty" in lines[0]
        assert "Traceback" not in captured.err


def test_no_overlap_in_time_exits_1_naming_both_files(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    gt, _ = _paths()
    late = tmp_path / "late.txt"
    late.write_text("".join(f"{2e9 + i} 0 0 {i} 0 0 0 1\n" for i in range(5)))
    assert main(["eval", "ate", gt, str(late)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "no associated stamps" in err and gt in err and str(late) in err


def test_a_failed_plot_keeps_an_existing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt, _ = _paths()
    png = tmp_path / "keep.png"
    png.write_bytes(b"old")
    bad = tmp_path / "bad.txt"
    bad.write_text("1.0 0 0 0 0 0 0\n")  # 7 columns
    assert main(["eval", "ate", gt, str(bad), "--plot", str(png)]) == 1
    assert png.read_bytes() == b"old"
    assert "expected 8 columns" in capsys.readouterr().err


def test_a_missing_or_empty_ground_truth_exits_1_naming_it(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    _, est = _paths()
    missing = tmp_path / "nope.txt"
    assert main(["eval", "ate", str(missing), est]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(missing) in err and "cannot read" in err
    comments = tmp_path / "only_comments.txt"
    comments.write_text("# timestamp tx ty tz qx qy qz qw\n\n")
    assert main(["eval", "rpe", str(comments), est]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(comments) in err and "empty" in err
