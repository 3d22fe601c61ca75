"""docs/nodes.md is what the generator reads from the nodes (tools/gen_node_reference.py)."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")

from changing_slam_ros.nodes import node_reference  # noqa: E402


def test_committed_node_reference_matches_the_nodes(ros_context):
    page = node_reference.render(ros_context)
    assert node_reference.DOC.read_text() == page, (
        "docs/nodes.md is out of date (a parameter, topic or service changed, or docs/nodes_intro/ was edited): "
        "run python tools/gen_node_reference.py"
    )


def test_every_node_parameter_has_a_description(ros_context):
    assert node_reference.undescribed_parameters(ros_context) == []


def test_when_column_names_the_parameters_a_topic_needs_or_excludes():
    default = [("/a", "t", "q"), ("/b", "t", "q")]
    variants = [("`x:=1`", [("/a", "t", "q"), ("/c", "t", "q")]), ("`y:=1`", [("/b", "t", "q"), ("/c", "t", "q")])]
    assert node_reference._with_conditions(default, variants) == [
        ("/a", "t", "q", "not with `y:=1`"),
        ("/b", "t", "q", "not with `x:=1`"),
        ("/c", "t", "q", "with `x:=1`; with `y:=1`"),
    ]
