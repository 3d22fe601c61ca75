"""The progress of `changing-slam graph`: counts read from the nodes' log lines as they grow, the pose rate, one
rewritten line on a terminal and a line per LOG_PERIOD_S elsewhere."""

from __future__ import annotations

import io
from pathlib import Path

from changing_slam_ros.commands.graph_process import NodeProcess
from changing_slam_ros.commands.graph_progress import LOG_PERIOD_S, Counts, GraphProgress, progress_line


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _node(tmp_path: Path, name: str) -> NodeProcess:
    node = NodeProcess(name, [], tmp_path)
    node.log_path = tmp_path / f"{name}.log"
    node.log_path.write_text("")
    return node


def _tracking_line(received: int, posed: int) -> str:  # as nodes/tracking_stats.py logs it
    return (f"[INFO] [1.0] [tracking]: tracking: {received} colour received, {received} frames, {received} colour/depth "
            f"pairs, unpaired dropped: 0 colour, 0 depth, {posed} poses, latency median 32 ms\n")  # fmt: skip


def _append(node: NodeProcess, text: str) -> None:
    with open(node.log_path, "a") as f:  # type: ignore[arg-type]
        f.write(text)


def test_counts_rate_and_a_line_per_period_in_a_log(tmp_path) -> None:
    tracking, player = _node(tmp_path, "tracking"), _node(tmp_path, "bag_player")
    out = io.StringIO()
    progress = GraphProgress(tracking, player, 300, stream=out)
    progress.update(0.0)
    assert out.getvalue() == "graph: played 0/300 frames, received 0, posed 0, -- poses/s\n"
    # 10 s later: half the bag played (the player's position in bag time), 148 received, 147 posed
    _append(player, "[INFO] [bag_player]: bag_player: played 450/900 messages, 5.00/10.00 s of the bag (50 %)\n")
    for t in range(1, 11):
        _append(tracking, _tracking_line(15 * t, 15 * t - 3))
        progress.update(float(t))
    _append(tracking, _tracking_line(148, 147)[:40])  # a line still being written is not read yet
    progress.update(LOG_PERIOD_S)
    lines = out.getvalue().splitlines()
    assert len(lines) == 2  # one at the start, one after LOG_PERIOD_S: no line per update
    assert lines[1] == "graph: played 150/300 frames, received 150, posed 147 (98 %), 15.0 poses/s"
    assert progress.counts() == Counts(150, 150, 147)


def test_live_topics_on_a_terminal_one_line_rewritten(tmp_path) -> None:
    tracking = _node(tmp_path, "tracking")
    out = _Tty()
    progress = GraphProgress(tracking, None, 0, stream=out)
    for t in range(5):
        _append(tracking, _tracking_line(30 * t, 30 * t))
        progress.update(float(t))
    progress.finish()
    text = out.getvalue()
    assert text.count("\r") == 5 and text.count("\n") == 1 and text.endswith("\n")
    assert text.rstrip().split("\r\033[K")[-1] == "graph: received 120, posed 120 (100 %), 30.0 poses/s"
    assert progress_line(Counts(None, 0, 0), 0, None) == "graph: received 0, posed 0, -- poses/s"
