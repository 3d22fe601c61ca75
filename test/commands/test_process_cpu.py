"""commands/process_cpu.py: CPU seconds of a child process during a window, from /proc."""

import subprocess
import sys
import time

import pytest

from changing_slam_ros.commands.process_cpu import PlayCpu, per_frame_ms, process_cpu_s

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")

BUSY = "import time\nt = time.process_time()\nwhile time.process_time() - t < {s}: pass\ntime.sleep(30)\n"


def test_a_busy_child_counts_its_cpu_after_start_only() -> None:
    # The child burns 0.6 s of CPU, then sleeps; the window starts after 0.3 s of it.
    child = subprocess.Popen([sys.executable, "-c", BUSY.format(s=0.6)])
    try:
        while (process_cpu_s(child.pid) or 0.0) < 0.3:
            time.sleep(0.01)
        cpu = PlayCpu()
        cpu.start({"busy": child.pid})
        while (process_cpu_s(child.pid) or 0.0) < 0.6:
            time.sleep(0.05)
        time.sleep(0.2)
        cpu.sample({"busy": child.pid})
        sec = cpu.seconds()["busy"]
        assert 0.15 <= sec <= 0.45  # about 0.6 - 0.3 s (10 ms ticks, start sampled a little late)
    finally:
        child.kill()
        child.wait()
    assert process_cpu_s(child.pid) is None  # gone: no figure, not a crash


def test_per_frame_ms_divides_by_frames_and_adds_a_total() -> None:
    assert per_frame_ms({"tracking": 3.0, "detection": 1.5}, 300) == {"tracking": 10.0, "detection": 5.0, "total": 15.0}
    assert per_frame_ms({"tracking": 3.0}, 0) == {}
