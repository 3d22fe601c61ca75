"""`changing-slam graph` supervision with stand-in node processes (no ROS): a node that keeps dying stops the
whole graph within 10 s, naming the node, its last log lines and its log, instead of waiting for --timeout."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import pytest

from changing_slam_ros.commands.graph import Graph, NodeFailed, add_arguments
from changing_slam_ros.commands.graph_process import stop_all

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"

# A node that says it is up, works a little, then fails: with the same error each time, or with the start
# number in it (a different error each time).
DYING = """
import pathlib, sys, time
count = pathlib.Path({count!r}); n = int(count.read_text()) + 1 if count.exists() else 1; count.write_text(str(n))
print('[INFO] [tracking]: tracking: started', flush=True)
time.sleep(0.3)
print('[INFO] [tracking]: tracking: working on frame 1', flush=True)
raise RuntimeError('undistortPoints: 2 distortion coefficients' + ({vary} and f' (start {{n}})' or ''))
"""
# A node that is up and ignores SIGINT and SIGTERM (only SIGKILL ends it).
STUBBORN = """
import signal, time
signal.signal(signal.SIGINT, signal.SIG_IGN); signal.signal(signal.SIGTERM, signal.SIG_IGN)
print('{marker}', flush=True)
time.sleep(600)
"""


def graph_with_stand_ins(tmp_path: Path, vary: bool, max_restarts: int = 2) -> Graph:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args([str(BAG), "--out", str(tmp_path / "out"), "--config", "tum_fr1", "--no-detection",
                              "--no-object-map", "--max-restarts", str(max_restarts), "--lossless"])  # fmt: skip
    graph = Graph(args)
    dying = [sys.executable, "-c", DYING.format(count=str(tmp_path / "starts"), vary=vary)]
    graph.nodes["tracking"].argv = dying
    graph.nodes["tracking"].restart_argv = None
    graph.nodes["local_mapping"].argv = graph.nodes["local_mapping"].restart_argv = \
        [sys.executable, "-c", STUBBORN.format(marker="local_mapping: started")]  # fmt: skip
    graph.nodes["loop_closing"].argv = graph.nodes["loop_closing"].restart_argv = \
        [sys.executable, "-c", STUBBORN.format(marker="loop_closing: started")]  # fmt: skip
    graph.player.argv = [sys.executable, "-c", STUBBORN.format(marker="bag_player: played 1/")]
    return graph


@pytest.mark.parametrize("vary", [False, True], ids=["same_error", "new_error_each_time"])
def test_a_node_dying_repeatedly_stops_every_process_within_10_s_naming_node_lines_and_log(tmp_path, capsys, vary):
    graph = graph_with_stand_ins(tmp_path, vary)
    t0 = time.monotonic()
    with pytest.raises(NodeFailed) as info:
        graph.run()
    took_s = time.monotonic() - t0
    message = str(info.value)
    starts = int((tmp_path / "starts").read_text())
    if vary:  # three deaths with different errors: --max-restarts 2 trips on the third
        assert starts == 3 and "restarted 2 times (--max-restarts)" in message
    else:  # the same error twice: a restart will not help
        assert starts == 2 and "died twice with the same error" in message
    assert message.startswith("graph: tracking ") and "RuntimeError: undistortPoints" in message
    assert f"log {graph.nodes['tracking'].log_path}" in message and "\n" not in message
    err = capsys.readouterr().err
    assert f"graph: tracking's last log lines ({graph.nodes['tracking'].log_path}):" in err
    assert "tracking: working on frame 1" in err and "RuntimeError" in err
    # every process is gone, the stubborn ones (SIGINT and SIGTERM ignored) too, within 10 s of the last death
    assert all(not n.running() for n in (*graph.nodes.values(), graph.player))
    assert took_s < 10.0 + 2.0 * starts, took_s  # each start ~0.5 s; stopping at most ~8 s


def test_cli_prints_the_failure_on_one_line_and_exits_1(tmp_path, capsys, monkeypatch):
    from changing_slam_ros import cli
    from changing_slam_ros.commands import graph as graph_command

    made: list[Graph] = []

    def fake_graph(args: argparse.Namespace) -> Graph:
        made.append(graph_with_stand_ins(tmp_path, vary=False))
        return made[-1]

    monkeypatch.setattr(graph_command, "Graph", fake_graph)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "graph_summary.json").write_text("{}\n")  # an earlier run's results
    rc = cli.main(["graph", str(BAG), "--out", str(tmp_path / "out")])
    assert rc == 1
    lines = capsys.readouterr().err.splitlines()
    final = [ln for ln in lines if ln.startswith("changing-slam graph: error:")]
    assert len(final) == 1 and "graph: tracking died twice with the same error" in final[0]
    assert "Traceback" not in "\n".join(ln for ln in lines if not ln.startswith("  "))
    # --out holds the earlier results, untouched; this run's logs are kept aside, where the message says
    assert (tmp_path / "out" / "graph_summary.json").read_text() == "{}\n"
    log = Path(final[0].rsplit("log ", 1)[1])
    assert log.is_file() and "RuntimeError" in log.read_text() and log.parent.parent.name.startswith("out.incomplete-")
    assert any(ln.startswith(f"graph: stopped; partial results kept in {log.parent.parent}") for ln in lines)


def test_stop_all_ends_processes_that_ignore_sigint_and_sigterm_within_its_budget(tmp_path):
    graph = graph_with_stand_ins(tmp_path, vary=False)
    nodes = [graph.nodes["local_mapping"], graph.nodes["loop_closing"]]
    for node in nodes:
        node.start(graph.env)
    graph._wait_ready(nodes[0], 30.0)
    graph._wait_ready(nodes[1], 30.0)
    t0 = time.monotonic()
    codes = stop_all(nodes, budget_s=4.0)
    assert time.monotonic() - t0 < 5.0
    assert codes == {"local_mapping": -9, "loop_closing": -9}


def test_lossless_gaps_name_what_a_lossless_run_did_not_finish():
    from changing_slam_ros.commands.graph_outputs import lossless_gaps

    complete = {"map_update_waits_timed_out": 0, "keyframes_without_map_update": 0}
    player = "[INFO] bag_player: finished: 87 messages in 9.1 s (CPU 0.4 s), 0 ack timeouts"
    assert lossless_gaps(player, complete, {"keyframes_received": 21, "keyframes_mapped": 21}) == []
    # keyframe 0 sent again after a restarted local_mapping's resync answer: a duplicate, mapped once, no gap
    resent = {"keyframes_received": 22, "keyframes_duplicate": 1, "keyframes_mapped": 21}
    assert lossless_gaps(player, complete, resent) == []
    timed_out = {"map_update_waits_timed_out": 1, "keyframes_without_map_update": 2}
    lost = {"keyframes_received": 23, "keyframes_mapped": 21}
    gaps = lossless_gaps(player.replace("0 ack", "2 ack"), timed_out, lost)
    assert gaps == ["2 frames went out without tracking's ack (ack timeout)",
                    "tracking went on without 1 map updates / loop verdicts",
                    "2 keyframes sent never came back as a map update",
                    "local_mapping received 23 distinct keyframes and mapped 21"]  # fmt: skip
    assert lossless_gaps(player, {}, None) == ["tracking wrote no tracking_stats.json"]
