"""What a run records about itself: `changing-slam --version`, the git commit of a checkout (None elsewhere, never
an error), the configuration as resolved (every section, defaults filled), in metrics.json and graph_summary.json."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from types import SimpleNamespace

import pytest

from changing_slam_ros import __version__
from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.config import CONFIG_SECTIONS
from changing_slam_ros.provenance import git_commit, run_provenance

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"


def test_version_flag_prints_the_package_version_and_exits_zero(capsys):
    with pytest.raises(SystemExit) as stop:
        cli_main(["--version"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"changing-slam {__version__}")
    git = git_commit()
    if git is not None:
        assert f"(git {git['commit'][:10]}" in out


def _git(root: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_git_commit_of_a_checkout_and_none_outside_one(tmp_path):
    assert git_commit(tmp_path) is None  # not a git work tree
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    assert git_commit(repo) is None  # no commit yet
    (repo / "a.txt").write_text("one\n")
    _git(repo, "add", "a.txt")
    _git(repo, "commit", "-q", "-m", "one")
    head = _git(repo, "rev-parse", "HEAD")
    assert git_commit(repo) == {"commit": head, "dirty": False}
    (repo / "a.txt").write_text("two\n")
    assert git_commit(repo) == {"commit": head, "dirty": True}
    # a package folder inside some other repository (a venv in a checkout) is not that repository's commit
    inner = repo / "venv" / "site-packages"
    inner.mkdir(parents=True)
    assert git_commit(inner) is None


def test_resolved_config_has_every_section_with_the_file_values_and_the_defaults(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text("tracking:\n  min_local_inliers: 17\ncamera:\n  width: 320\n  height: 240\n  fx: 260.0\n"
                    "  fy: 261.0\n  cx: 160.0\n  cy: 120.0\n")  # fmt: skip
    from changing_slam_ros.config import load_config
    from changing_slam_ros.core.slam.tracking_config import TrackingConfig

    data, where = load_config(path)
    record = run_provenance(data, where, options={"out": tmp_path, "rate": 1.0})
    json.dumps(record)  # plain JSON values only
    assert record["package_version"] == __version__
    assert record["config_path"] == str(path)
    config = record["config"]
    assert set(config) == set(CONFIG_SECTIONS)
    assert config["tracking"]["min_local_inliers"] == 17
    assert config["camera"]["fx"] == 260.0 and config["camera"]["dist"] == [0.0] * 5
    other = next(k for k, v in vars(TrackingConfig()).items() if k != "min_local_inliers" and isinstance(v, (int, float)))
    assert config["tracking"][other] == getattr(TrackingConfig(), other)  # a default filled in
    assert record["options"] == {"out": str(tmp_path), "rate": 1.0}
    assert run_provenance({}, "defaults")["config"]["camera"] is None  # intrinsics from the data then


def test_run_metrics_record_version_commit_and_resolved_config(tmp_path):
    out = tmp_path / "run"
    code = cli_main(["run", str(BAG), "--out", str(out), "--config", "tum_fr1", "--quiet", "--no-plot",
                     "--detections", "none", "--max-frames", "4"])  # fmt: skip
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    record = metrics["provenance"]
    assert record["package_version"] == __version__
    git = git_commit()
    assert record["git_commit"] == (git["commit"] if git else None)
    assert record["config_path"].endswith("tum_fr1.yaml")
    assert record["config"]["camera"]["fx"] == 517.3  # the value in config/tum_fr1.yaml, not only its path
    assert record["config"]["dataset"]["depth_scale"] == 5000.0
    assert record["options"]["max_frames"] == 4


def test_graph_summary_provenance_is_the_nodes_config_resolved(tmp_path):
    pytest.importorskip("rclpy")
    from changing_slam_ros.commands.graph_outputs import graph_provenance

    config = str(REPO / "config" / "tum_fr1.yaml")
    record = graph_provenance(config, SimpleNamespace(bag="b.mcap", rate=1.0))
    assert record["config_path"] == config and record["config"]["camera"]["fy"] == 516.5
    assert record["options"] == {"bag": "b.mcap", "rate": 1.0}
    defaults = graph_provenance("", SimpleNamespace())
    assert defaults["config_path"] == "defaults" and defaults["config"]["camera"] is None
