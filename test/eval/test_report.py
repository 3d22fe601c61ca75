"""`evaluate` gathers ATE and both RPEs for metrics.json, with clear errors for bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import TUM_REFERENCE, require

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.report import evaluate, evaluate_files

FIXTURE = json.loads((Path(__file__).parent / "evo_reference.json").read_text())


def _evo(tool: str, est: str, **match: object) -> dict:
    rows = [r for r in FIXTURE[tool] if r["est"] == est
            and all(r.get(k) == v for k, v in match.items())]
    assert len(rows) == 1
    return rows[0]


def test_report_on_fr1_rgbdslam_matches_evo_and_is_plain_json() -> None:
    data = require(TUM_REFERENCE)
    gt, est = data / "freiburg1_xyz-groundtruth.txt", data / "freiburg1_xyz-rgbdslam.txt"
    report = evaluate_files(gt, est)
    json.dumps(report)  # plain JSON types only
    ape = _evo("ape", est.name, max_diff_s=0.02, offset_s=0.0, sim3=False)
    assert report["ate"]["rmse"] == pytest.approx(ape["stats"]["rmse"], abs=1e-6)
    assert report["associated_poses"] == ape["count"] == 786
    rpe_t = _evo("rpe", est.name, delta_frames=1, all_pairs=False, relation="translation_m", sim3=False)
    rpe_r = _evo("rpe", est.name, delta_frames=1, all_pairs=False, relation="rotation_deg", sim3=False)
    assert report["rpe_per_frame"]["translation_m"]["rmse"] == pytest.approx(rpe_t["stats"]["rmse"], abs=1e-6)
    assert report["rpe_per_frame"]["rotation_deg"]["rmse"] == pytest.approx(rpe_r["stats"]["rmse"], abs=1e-6)
    per_s = report["rpe_per_second"]
    assert per_s["delta_unit"] == "seconds" and per_s["all_pairs"] is True
    # Over 1 s the drift of this estimate is larger than over one frame, and smaller than 10x.
    assert report["rpe_per_frame"]["translation_m"]["rmse"] < per_s["translation_m"]["rmse"] < 0.1
    assert report["gt"] == str(gt) and report["warnings"] == []


def test_report_on_a_half_second_estimate_has_no_per_second_rpe_and_says_why() -> None:
    stamps = np.arange(15) / 30.0
    rng = np.random.default_rng(0)
    gt = Trajectory(stamps, np.cumsum(rng.normal(size=(15, 3)), axis=0), np.tile([0, 0, 0, 1.0], (15, 1)))
    report = evaluate(gt, gt)
    assert report["ate"]["rmse"] == pytest.approx(0.0, abs=1e-12)
    assert report["rpe_per_frame"]["pairs"] == 14
    assert report["rpe_per_second"] is None
    assert "rpe_per_second" in report["warnings"][0] and "no pose pairs" in report["warnings"][0]


def test_report_needs_three_associated_poses() -> None:
    t = Trajectory(np.array([0.0, 1.0]), np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)))
    with pytest.raises(EvalError, match="only 2 associated poses between a.txt and b.txt"):
        evaluate(t, t, gt_name="a.txt", est_name="b.txt")


def test_report_names_an_empty_estimate_file(tmp_path: Path) -> None:
    require(TUM_REFERENCE)
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing here\n")
    with pytest.raises(EvalError, match=rf"{empty}: trajectory is empty"):
        evaluate_files(TUM_REFERENCE / "freiburg1_xyz-groundtruth.txt", empty)


def test_the_eval_library_and_cli_import_matplotlib_only_when_plotting() -> None:
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import changing_slam_ros.eval.report, changing_slam_ros.eval.ate, changing_slam_ros.eval.rpe\n"
        "import changing_slam_ros.commands.eval\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported eagerly'\n"
        "import changing_slam_ros.eval.plots\n"
        "assert 'matplotlib' not in sys.modules, 'plots imports matplotlib at module level'\n"
    )
    repo = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
