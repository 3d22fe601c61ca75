"""The lead-owned shared pieces: config loading, atomic writes, SE(3) helpers, TUM trajectory files, CLI."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.config import load_yaml, section
from changing_slam_ros.core.geometry.se3 import invert, make_pose, quat_to_rot, rot_to_quat, rotation_angle_rad
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import ConfigError, EvalError
from changing_slam_ros.io.atomic import atomic_open, atomic_write_text
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory, write_tum_trajectory
from helpers import REPO, TUM_REFERENCE, require


@dataclasses.dataclass(frozen=True)
class _Inner:
    sigma: float = 0.5


@dataclasses.dataclass(frozen=True)
class _Cfg:
    n_features: int = 1000
    ratio: float = 0.9
    enabled: bool = True
    name: str = "x"
    sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    inner: _Inner = _Inner()
    limits: tuple[float, ...] = (0.1, 10.0)


def test_section_fills_typed_fields_and_keeps_defaults() -> None:
    cfg = section(_Cfg, {"n_features": 1500, "ratio": 1, "sigmas": {"person": 0.5}, "inner": {"sigma": 2}}, "f: s")
    assert cfg.n_features == 1500 and isinstance(cfg.ratio, float) and cfg.ratio == 1.0
    assert cfg.sigmas == {"person": 0.5} and cfg.inner.sigma == 2.0 and cfg.enabled is True
    assert section(_Cfg, {"limits": [0.2, 5]}, "f").limits == (0.2, 5.0)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"n_feature": 3}, r"cfg.yaml: tracking: unknown key\(s\) n_feature"),
        ({"n_features": 1.5}, r"tracking.n_features: expected an integer"),
        ({"enabled": "yes"}, r"tracking.enabled: expected true or false"),
        ({"ratio": "high"}, r"tracking.ratio: expected a number"),
        ({"inner": {"sigma": "a"}}, r"tracking.inner.sigma: expected a number"),
    ],
)
def test_section_rejects_bad_values_naming_file_and_key(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        section(_Cfg, data, "cfg.yaml: tracking")


def test_load_yaml_names_the_file_on_bad_yaml(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("camera: [1, 2\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:2: not valid YAML \(expected .,. or .\]., but got .<stream "
                                          r"end>.\)$"):  # fmt: skip
        load_yaml(bad)
    with pytest.raises(ConfigError, match="missing.yaml: cannot read config"):
        load_yaml(tmp_path / "missing.yaml")


def test_atomic_write_keeps_old_content_when_the_writer_fails(tmp_path: Path) -> None:
    target = tmp_path / "map.json"
    atomic_write_text(target, "good")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as fh:
            fh.write("half")
            raise RuntimeError("crash mid-write")
    assert target.read_text() == "good"
    assert [p.name for p in tmp_path.iterdir()] == ["map.json"]


def test_quaternion_round_trip_and_inverse() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = q if q[3] >= 0 else -q
        r = quat_to_rot(q)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.allclose(rot_to_quat(r), q, atol=1e-9)
        t = make_pose(r, rng.normal(size=3))
        assert np.allclose(t @ invert(t), np.eye(4), atol=1e-12)
    assert rotation_angle_rad(quat_to_rot(np.array([0, 0, np.sin(0.3), np.cos(0.3)]))) == pytest.approx(0.6)


def test_tum_trajectory_write_then_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1
    traj = Trajectory(1305031102.175304 + np.arange(20) / 30.0, rng.normal(size=(20, 3)), q)
    write_tum_trajectory(tmp_path / "t.txt", traj)
    back = read_tum_trajectory(tmp_path / "t.txt")
    assert np.allclose(back.stamps_s, traj.stamps_s, atol=1e-6)
    assert np.allclose(back.positions, traj.positions, atol=1e-9)
    assert np.allclose(back.poses(), traj.poses(), atol=1e-8)


def test_tum_trajectory_reader_reads_the_official_ground_truth() -> None:
    gt = read_tum_trajectory(require(TUM_REFERENCE) / "freiburg1_xyz-groundtruth.txt")
    assert len(gt) == 3000
    assert gt.stamps_s[0] == pytest.approx(1305031098.6659)
    assert np.allclose(gt.positions[0], [1.3563, 0.6305, 1.6380])


@pytest.mark.parametrize(
    ("content", "match"),
    [("", "trajectory is empty"), ("# only a comment\n", "trajectory is empty"),
     ("1 2 3 4 5 6 7\n", r":1: expected 8 columns"), ("1 2 3 4 0 0 0 x\n", r":1: not a number"),
     ("1 0 0 0 0 0 0 0\n", "zero quaternion")],
)
def test_tum_trajectory_reader_rejects_bad_files_naming_them(tmp_path: Path, content: str, match: str) -> None:
    f = tmp_path / "est.txt"
    f.write_text(content)
    with pytest.raises(EvalError, match=match):
        read_tum_trajectory(f)


def test_cli_lists_every_subcommand_and_rejects_unknown_ones() -> None:
    out = subprocess.run([sys.executable, "-m", "changing_slam_ros.cli", "--help"], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0
    for name in ("run", "eval", "convert", "simulate", "bench", "graph"):
        assert name in out.stdout
    bad = subprocess.run([sys.executable, "-m", "changing_slam_ros.cli", "fly"], capture_output=True, text=True, cwd=REPO)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


def test_atomic_write_gives_the_file_ordinary_permissions(tmp_path: Path) -> None:
    import os

    target = tmp_path / "trajectory.txt"
    atomic_write_text(target, "x")
    umask = os.umask(0)
    os.umask(umask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~umask)
