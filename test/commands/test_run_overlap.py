"""`changing-slam run` with the detector (the shipped model) running ahead on its own thread: the trajectory is
byte for byte the one of `--serial` and the same from run to run; a detector failure on that thread ends the run
with the usual one-line error; an interrupt, raised in the loop or sent as SIGINT, stops the run and its threads."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.core.dynamic.detector import Detector
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.errors import DatasetError

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "bags" / "sim_walking_changing.mcap"  # a person walks through frames 33-126
OUTPUTS = ("trajectory.txt", "trajectory_online.txt", "keyframes.txt")
WORKERS = ("frame-reader", "frame-detector")


def _run(out: Path, *extra: str) -> dict[str, bytes]:
    rc = cli_main(["run", str(SAMPLE), "--out", str(out), "--config", "sim", "--quiet", "--no-plot", *extra])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["dynamic"]["detections"] == "model"
    assert metrics["detection_overlapped"] is ("--serial" not in extra)
    return {name: (out / name).read_bytes() for name in OUTPUTS}


def _workers_alive() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name in WORKERS]


def _same_in_both_modes_and_every_run(tmp_path: Path, *extra: str) -> None:
    serial = _run(tmp_path / "serial", "--serial", *extra)
    first = _run(tmp_path / "overlap1", *extra)
    second = _run(tmp_path / "overlap2", *extra)
    assert first == serial
    assert second == first
    assert _workers_alive() == []


def test_overlapped_and_serial_runs_write_the_same_trajectories_on_the_first_60_frames(tmp_path: Path) -> None:
    _same_in_both_modes_and_every_run(tmp_path, "--max-frames", "60")


@pytest.mark.slow
def test_overlapped_and_serial_runs_write_the_same_trajectories_on_the_whole_sample(tmp_path: Path) -> None:
    _same_in_both_modes_and_every_run(tmp_path)


def test_a_detector_failure_on_its_thread_is_one_line_and_stops_the_run(tmp_path: Path, monkeypatch, capsys) -> None:
    detect = Detector.detect
    calls = []

    def failing(self: Detector, rgb, stamp_ns: int = 0):
        calls.append(threading.current_thread().name)
        if len(calls) == 5:
            raise DatasetError(f"frame at stamp {stamp_ns}: corrupt colour image")
        return detect(self, rgb, stamp_ns)

    monkeypatch.setattr(Detector, "detect", failing)
    rc = cli_main(["run", str(SAMPLE), "--out", str(tmp_path / "out"), "--config", "sim", "--quiet", "--no-plot"])
    err = capsys.readouterr().err
    assert rc == 1 and "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ": error: " in ln]
    assert re.fullmatch(r"changing-slam run: error: frame at stamp \d+: corrupt colour image", line)
    assert set(calls) == {"frame-detector"}
    assert not (tmp_path / "out").exists()
    assert _workers_alive() == []


def test_an_interrupt_while_tracking_stops_the_run_and_its_threads(tmp_path: Path, monkeypatch, capsys) -> None:
    process = SlamSystem.process
    frames = []

    def interrupted(self: SlamSystem, rgbd, detections=None):
        frames.append(rgbd.stamp_ns)
        if len(frames) == 4:
            raise KeyboardInterrupt
        return process(self, rgbd, detections)

    monkeypatch.setattr(SlamSystem, "process", interrupted)
    t0 = time.monotonic()
    rc = cli_main(["run", str(SAMPLE), "--out", str(tmp_path / "out"), "--config", "sim", "--quiet", "--no-plot"])
    assert rc == 130 and "changing-slam run: interrupted" in capsys.readouterr().err
    assert len(frames) == 4 and time.monotonic() - t0 < 60
    assert _workers_alive() == []


def test_ctrl_c_during_an_overlapped_run_exits_promptly(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "changing_slam_ros.cli", "run", str(SAMPLE), "--out", str(tmp_path / "out"),
           "--config", "sim", "--no-plot"]  # fmt: skip
    # SIGINT as a terminal's Ctrl-C delivers it, also when the suite itself runs in the background of a shell
    # (which starts its children with SIGINT ignored)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    err = bytearray()

    def read_stderr() -> None:  # tqdm's progress goes to stderr, updated in place with \r
        for chunk in iter(lambda: os.read(proc.stderr.fileno(), 4096), b""):  # type: ignore[union-attr]
            err.extend(chunk)

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    deadline = time.monotonic() + 120
    while not re.search(rb"slam: .*\b([5-9]|\d\d+)/225", bytes(err)) and time.monotonic() < deadline:
        assert proc.poll() is None, bytes(err).decode()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    try:
        rc = proc.wait(timeout=20)
    finally:
        proc.kill()
    reader.join(5)
    text = bytes(err).decode()
    assert rc == 130, text
    assert time.monotonic() - t0 < 20
    assert "changing-slam run: interrupted" in text and "Traceback" not in text
