"""`changing-slam graph` interrupted over an earlier complete run (Ctrl-C, or SIGKILL of the graph process): --out
keeps the earlier results untouched, the interrupted run's logs and outputs are kept aside under
`<out>.incomplete-<time>`, and no node process outlives the graph."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import default_sigint

pytestmark = [pytest.mark.ros, pytest.mark.slow]
REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def processes_naming(text: str) -> list[str]:
    out = subprocess.run(["ps", "-ww", "-eo", "args"], capture_output=True, text=True).stdout
    return [ln for ln in out.splitlines() if text in ln and "ps -eo" not in ln]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["ctrl_c", "sigkill"])
def test_an_interrupted_graph_keeps_the_earlier_results_and_its_own_aside(tmp_path, sig):
    out = tmp_path / "graph"
    out.mkdir()
    (out / "graph_summary.json").write_text('{"poses_published": 9}\n')  # an earlier complete run
    (out / "trajectory.txt").write_text("1.0 0 0 0 0 0 0 1\n")
    before = snapshot(out)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "changing_slam_ros", "graph", str(BAG), "--out", str(out),
                             "--config", "tum_fr1", "--lossless", "--no-detection", "--no-object-map", "--rate", "0.1"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path,
                            env=env, preexec_fn=default_sigint)  # fmt: skip
    # (a suite started in the background passes SIGINT on as ignored: the graph gets the terminal's default back)
    assert proc.stdout is not None
    seen = []
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        seen.append(line)
        if " up after " in line or not line:
            break
    time.sleep(3.0)  # playing: the 0.6 s bag takes 6 s at rate 0.1, so the signal lands mid-run on a busy machine too
    proc.send_signal(sig)
    rest, _ = proc.communicate(timeout=300)
    text = "".join(seen) + rest
    assert snapshot(out) == before, text  # the earlier results, untouched
    [kept] = sorted(tmp_path.glob("graph.incomplete-*"))
    assert (kept / "logs" / "tracking.log").is_file()
    deadline = time.monotonic() + 120
    while processes_naming(str(kept)) and time.monotonic() < deadline:  # SIGKILL: the nodes stop by themselves
        time.sleep(0.5)
    assert processes_naming(str(kept)) == []
    if sig == signal.SIGINT:
        assert proc.returncode == 130 and f"partial results kept in {kept}" in text, text
    # the nodes stopped as on Ctrl-C and wrote what they had into the kept folder
    assert (kept / "tracking_stats.json").is_file(), sorted(p.name for p in kept.iterdir())
