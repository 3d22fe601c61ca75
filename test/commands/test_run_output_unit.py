"""`changing-slam run` writes its outputs as one unit: --out is checked before the first frame, an interrupted run
(Ctrl-C or an error while processing or writing, SIGKILL while writing or committing) leaves the earlier
complete results in --out, and what it wrote is kept aside under `<out>.incomplete-<time>`."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import default_sigint

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.io.output_dir import SUPERSEDED, OutputDir

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"
ARGS = ["--config", "tum_fr1", "--quiet", "--no-plot", "--detections", "none"]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file's bytes (the superseded marker a killed commit may leave is removed by the next run)."""
    files = [p for p in sorted(folder.rglob("*")) if p.is_file() and p.name != SUPERSEDED]
    return {str(p.relative_to(folder)): p.read_bytes() for p in files}


def consistent(folder: Path) -> int:
    """The number of frames of the one run the folder holds (metrics.json and the trajectories agree)."""
    metrics = json.loads((folder / "metrics.json").read_text())
    rows = [ln for ln in (folder / "trajectory.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    online = [ln for ln in (folder / "trajectory_online.txt").read_text().splitlines() if ln and ln[0] != "#"]
    assert metrics["frames_tracked"] == len(rows) == len(online)
    return int(metrics["frames"])


@pytest.fixture(scope="module")
def earlier(tmp_path_factory) -> Path:
    """An earlier complete run over the first 5 frames (the runs under test process all 9)."""
    if not BAG.is_file():
        pytest.skip(f"{BAG} missing")
    out = tmp_path_factory.mktemp("earlier") / "out"
    assert cli_main(["run", str(BAG), "--out", str(out), "--max-frames", "5", *ARGS]) == 0
    assert consistent(out) == 5
    return out


@pytest.fixture
def out(earlier, tmp_path) -> Path:
    target = tmp_path / "out"
    shutil.copytree(earlier, target)
    return target


def leftovers(target: Path) -> list[Path]:
    return sorted(target.parent.glob(f"{target.name}.incomplete-*"))


def test_a_complete_run_replaces_the_earlier_results_whole(out):
    assert cli_main(["run", str(BAG), "--out", str(out), *ARGS]) == 0
    assert consistent(out) == 9 and not (out / SUPERSEDED).exists()
    assert leftovers(out) == []


def test_ctrl_c_while_processing_frames_leaves_the_earlier_results_and_nothing_else(out, monkeypatch, capsys):
    from changing_slam_ros.core.system import SlamSystem

    before = snapshot(out)
    real = SlamSystem.process
    calls = []

    def interrupted(self, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(SlamSystem, "process", interrupted)
    assert cli_main(["run", str(BAG), "--out", str(out), *ARGS]) == 130
    assert snapshot(out) == before and leftovers(out) == []  # nothing was written: nothing kept


@pytest.mark.parametrize("error", [KeyboardInterrupt, OSError], ids=["ctrl_c", "disk_error"])
def test_an_interruption_while_writing_keeps_the_earlier_results_and_the_partial_ones_aside(out, monkeypatch, capsys,
                                                                                           error):
    from changing_slam_ros.commands import run as run_command

    before = snapshot(out)

    def broken_save(*a, **k):  # noqa: ANN002, ANN003, ANN202
        raise error(28, "No space left on device") if error is OSError else error()

    monkeypatch.setattr(run_command, "save_map", broken_save)  # after the trajectories, before metrics.json
    rc = cli_main(["run", str(BAG), "--out", str(out), *ARGS])
    assert rc == (130 if error is KeyboardInterrupt else 1)
    assert snapshot(out) == before and consistent(out) == 5
    [kept] = leftovers(out)
    assert (kept / "trajectory.txt").is_file() and not (kept / "metrics.json").exists()
    err = capsys.readouterr().err
    assert f"partial results kept in {kept}" in err and "Traceback" not in err
    if error is OSError:
        assert "No space left on device" in err.strip().splitlines()[-1]


def test_out_is_checked_before_the_first_frame(tmp_path, monkeypatch, capsys):
    from changing_slam_ros.core.system import SlamSystem

    def never(*a, **k):  # noqa: ANN002, ANN003, ANN202
        raise AssertionError("a frame was processed")

    monkeypatch.setattr(SlamSystem, "process", never)
    a_file = tmp_path / "results.txt"
    a_file.write_text("not a folder\n")
    data = tmp_path / "data"
    data.mkdir()
    (data / "rgb.txt").write_text("# a dataset, not results\n")
    for target, reason in ((a_file, "exists and is not a folder"), (data, "holds files that are not the results")):
        assert cli_main(["run", str(BAG), "--out", str(target), *ARGS]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(target) in err[0] and reason in err[0], err
    assert (data / "rgb.txt").read_text() == "# a dataset, not results\n" and a_file.read_text() == "not a folder\n"
    if os.geteuid() != 0:  # root writes into read-only folders anyway
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        for target in (ro, ro / "new"):
            assert cli_main(["run", str(BAG), "--out", str(target), *ARGS]) == 1
            assert "not writable" in capsys.readouterr().err


def test_a_commit_killed_between_swap_and_cleanup_leaves_the_new_results_and_a_later_run_removes_the_old(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "metrics.json").write_text("old\n")
    first = OutputDir.prepare(target)
    (first.work / "metrics.json").write_text("new\n")
    import changing_slam_ros.io.output_dir as od

    real_rmtree = od.shutil.rmtree
    od.shutil.rmtree = lambda *a, **k: None  # the process "dies" before deleting the superseded results
    try:
        first.commit()
    finally:
        od.shutil.rmtree = real_rmtree
    assert (target / "metrics.json").read_text() == "new\n"
    [old] = leftovers(target)
    assert (old / SUPERSEDED).exists() and (old / "metrics.json").read_text() == "old\n"
    second = OutputDir.prepare(target)
    assert leftovers(target) == [second.work]  # the superseded folder is gone, only the new work folder is there
    second.abandon()
    assert leftovers(target) == []


KILLER = """
import os, sys, time
from changing_slam_ros.commands import run as run_command
from changing_slam_ros.io import output_dir
from changing_slam_ros.cli import main

def pause(label, real):
    def wrapped(*a, **k):
        print(label, flush=True)
        time.sleep(60)
        return real(*a, **k)
    return wrapped

point = sys.argv[1]
if point == "write":
    run_command.save_map = pause("PAUSED", run_command.save_map)
elif point == "commit":
    output_dir._exchange = pause("PAUSED", output_dir._exchange)
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
@pytest.mark.parametrize("point,sig", [("write", signal.SIGKILL), ("write", signal.SIGINT), ("commit", signal.SIGKILL)])
def test_a_signal_at_the_write_phase_or_the_commit_leaves_one_consistent_run(out, point, sig):
    before = snapshot(out)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", KILLER, point, "run", str(BAG), "--out", str(out), *ARGS],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=default_sigint)  # fmt: skip
    deadline = time.monotonic() + 300
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "PAUSED" in line or not line:
            break
    proc.send_signal(sig)
    proc.wait(60)
    assert snapshot(out) == before and consistent(out) == 5  # the earlier run, untouched
    [kept] = leftovers(out)
    assert (kept / "trajectory.txt").is_file() and not (kept / "metrics.json").exists() or point == "commit"
    if point == "commit":  # all written, not swapped in: the new run is complete under the incomplete name
        assert consistent(kept) == 9


def test_a_keypoint_log_inside_out_survives_the_swap_into_place(tmp_path):
    """`--keypoint-log OUT/keypoints.npz` is written into the staging folder, so it is there once the run is."""
    import subprocess
    import sys

    from helpers import REPO

    bag = REPO / "bags" / "tum_fr1_xyz_first10.mcap"
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "changing_slam_ros.cli", "run", str(bag), "--out", str(out), "--config",
                           "tum_fr1", "--quiet", "--no-plot", "--max-frames", "4", "--keypoint-log",
                           str(out / "keypoints.npz")], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (out / "keypoints.npz").is_file() and (out / "metrics.json").is_file()
