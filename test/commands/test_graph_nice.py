"""`changing-slam graph --nice NODE=N`: parsing, and the niceness reaching the child process."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from changing_slam_ros.commands.graph import NodeProcess, parse_nice
from changing_slam_ros.errors import ConfigError

NODES = ("tracking", "local_mapping", "bag_player")


def test_parse_nice_maps_nodes_to_increments() -> None:
    assert parse_nice(["local_mapping=5", "bag_player=0"], NODES) == {"local_mapping": 5, "bag_player": 0}
    assert parse_nice([], NODES) == {}


@pytest.mark.parametrize("spec, word", [("mapping=5", "unknown node"), ("tracking=x", "integer"),
                                        ("tracking=-3", "0..19"), ("tracking=20", "0..19")])  # fmt: skip
def test_parse_nice_rejects_bad_specs_naming_the_option(spec: str, word: str) -> None:
    with pytest.raises(ConfigError, match=word) as err:
        parse_nice([spec], NODES)
    assert "--nice" in str(err.value)


def test_node_process_starts_with_the_raised_niceness(tmp_path: Path) -> None:
    probe = [sys.executable, "-c", "import os; print(os.nice(0))"]
    base = os.nice(0)
    niced = NodeProcess("local_mapping", probe, tmp_path, nice=7)
    plain = NodeProcess("tracking", probe, tmp_path)
    for node in (niced, plain):
        node.start(dict(os.environ))
        assert node.proc is not None and node.proc.wait(30) == 0
    assert int(niced.log_text().strip()) == min(base + 7, 19)
    assert int(plain.log_text().strip()) == base
