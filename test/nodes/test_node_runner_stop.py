"""`node_runner.run_node` on SIGINT / SIGTERM: the callback running finishes (no KeyboardInterrupt inside it), the
node finishes the work it announces (`work_pending`), and `destroy_node` runs with the context still up; a second
signal stops at once."""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")
REPO = Path(__file__).resolve().parents[2]

NODE = """
import os, signal, sys, threading, time
import rclpy
from rclpy.node import Node
from changing_slam_ros.nodes.node_runner import run_node

class Busy(Node):
    def __init__(self):
        super().__init__("busy")
        self.started = self.finished = 0
        self.create_timer(0.05, self.work)
        for at in {signals}:
            threading.Timer(at, lambda: os.kill(os.getpid(), signal.{sig})).start()

    def work(self):
        self.started += 1
        t = time.monotonic()
        while time.monotonic() - t < 0.4:  # Python code all the way: an exception could land anywhere here
            sum(range(1000))
        self.finished += 1

    def work_pending(self):
        return f"{{3 - self.finished}} steps" if self.finished < 3 else ""

    def destroy_node(self):
        print(f"started {{self.started}} finished {{self.finished}} context_ok {{self.context.ok()}}", flush=True)
        super().destroy_node()

sys.exit(run_node(lambda argv: Busy(), ["busy"]))
"""


def run_busy(signals: list[float], sig: str = "SIGINT") -> tuple[int, str]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))  # fmt: skip
    out = subprocess.run([sys.executable, "-c", NODE.format(signals=signals, sig=sig)], env=env, capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    return out.returncode, out.stdout + out.stderr


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_lets_the_running_callback_and_the_announced_work_finish(sig):
    rc, out = run_busy([0.6], sig)  # arrives inside the first (or second) callback
    assert rc == 0, out
    assert "started 3 finished 3 context_ok True" in out, out
    assert "KeyboardInterrupt" not in out and "Traceback" not in out
    assert "busy: stopping after" in out  # the node said what it waited for


def test_a_second_signal_stops_at_once():
    rc, out = run_busy([0.6, 0.8])
    assert rc == 0, out
    line = next(ln for ln in out.splitlines() if ln.startswith("started"))
    started, finished = int(line.split()[1]), int(line.split()[3])
    assert finished < 3 and started - finished <= 1, out
    assert "Traceback" not in out
