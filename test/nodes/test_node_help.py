"""Every node executable's `--help`: the parameters with type, default and description, exit 0, rclpy never
initialised; the rows agree with the generated reference docs/nodes.md (read from the built nodes)."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros
pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from changing_slam_ros.nodes.node_help import wants_help  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
NODES = ["bag_player", "detection", "tracking", "local_mapping", "loop_closing", "object_map"]
ENTRY = re.compile(r"^  (\S+) \(([^,]+), default (.*)\)$")


def reference_rows(node: str) -> list[tuple[str, str, str, str]]:
    """(name, type, default, description) of the node's parameter table in docs/nodes.md."""
    page = (REPO / "docs" / "nodes.md").read_text()
    section = page.split(f"\n## {node}\n", 1)[1].split("\n## ", 1)[0]
    table = section.split("### Parameters\n", 1)[1]
    rows = []
    for line in table.splitlines()[3:]:
        if not line.startswith("| `"):
            break
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows.append((cells[0].strip("`"), cells[1], cells[2][1:-1], cells[3]))
    return rows


def help_rows(text: str) -> list[tuple[str, str, str, str]]:
    """(name, type, default, description) of each parameter entry `--help` printed."""
    rows: list[tuple[str, str, str, str]] = []
    for line in text.splitlines():
        if match := ENTRY.match(line):
            rows.append((match.group(1), match.group(2), match.group(3), ""))
        elif rows and line.startswith(" " * 6):
            name, kind, default, description = rows[-1]
            rows[-1] = (name, kind, default, (description + " " + line.strip()).strip())
    return rows


@pytest.mark.parametrize("node", NODES)
def test_help_prints_every_parameter_as_the_reference_does_without_ros(node, capsys, monkeypatch):
    import rclpy

    def no_init(*args, **kwargs):
        raise AssertionError("--help initialised rclpy")

    monkeypatch.setattr(rclpy, "init", no_init)
    module = importlib.import_module(f"changing_slam_ros.nodes.{node}_node")
    assert module.main([node, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: ros2 run changing_slam_ros {node} ")
    rows = help_rows(out)
    expected = reference_rows(node)
    assert len(expected) >= 6
    assert [r[:3] for r in rows] == [r[:3] for r in expected]
    # descriptions are wrapped on spaces: compare them with whitespace normalised
    assert [" ".join(r[3].split()) for r in rows] == [" ".join(r[3].split()) for r in expected]


@pytest.mark.parametrize("node", NODES)
def test_node_executable_help_exits_zero(node):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    result = subprocess.run([sys.executable, "-m", f"changing_slam_ros.nodes.{node}_node", "--help"], cwd=REPO,
                            env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert [r[0] for r in help_rows(result.stdout)] == [r[0] for r in reference_rows(node)]


def test_help_flag_counts_only_before_ros_args():
    assert wants_help(["--help"])
    assert wants_help(["bag.mcap", "-h", "--ros-args", "-p", "rate:=2.0"])
    assert not wants_help(["bag.mcap", "--ros-args", "-p", "rate:=2.0"])
    assert not wants_help(["--ros-args", "--help"])
