"""`--help` of the node executables: the node's parameters with type, default and description, without ROS.

Each node module keeps its parameters as a table of `ParamSpec` (name, default, description) that the node
declares (`node_runner.declare_parameters`) and `run_node` prints when `-h` / `--help` comes before `--ros-args`;
rclpy is never initialised for it. Types and defaults are written as docs/nodes.md writes them
(`nodes/node_reference.py` reads the same declarations back from the built nodes).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

# A parameter spec: (name, default, description). Use Parameter.Type.STRING_ARRAY (etc.) as the default of
# an array parameter that starts empty: rclpy cannot infer a type from [].
ParamSpec = tuple[str, Any, str]

HELP_FLAGS = ("-h", "--help")


@dataclass(frozen=True)
class NodeHelp:
    """What `--help` prints for one node executable."""

    executable: str  # the `ros2 run changing_slam_ros` name, also the module `nodes/<executable>_node.py`
    summary: str  # one line: what the node does
    parameters: Sequence[ParamSpec]
    positional: str = ""  # non-ROS command-line arguments, e.g. "[BAG]"


def first_line(doc: str | None) -> str:
    """The first line of a module's docstring: the node's summary."""
    return (doc or "").strip().splitlines()[0] if (doc or "").strip() else ""


def format_value(value: Any) -> str:
    """A parameter value as docs/nodes.md shows it (without the backticks): true, "text", [1, 2], []."""
    if value is None:
        return "[]"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        items = list(value.tolist() if hasattr(value, "tolist") else value)
        return "[" + ", ".join(f'"{v}"' if isinstance(v, str) else str(v) for v in items) + "]"
    return str(value)


def parameter_type(default: Any) -> str:
    """The ROS parameter type rclpy declares for this default: bool, integer, double, string, string[], ..."""
    from rclpy.parameter import Parameter

    kind = default if isinstance(default, Parameter.Type) else Parameter.Type.from_parameter_value(default)
    return kind.name.lower().replace("_array", "[]")


def parameter_default(default: Any) -> Any:
    """The value a node starts with for this default (an array declared by its type starts empty)."""
    from rclpy.parameter import Parameter

    return None if isinstance(default, Parameter.Type) else default


def wants_help(args: Sequence[str]) -> bool:
    """`-h` / `--help` among the node's own arguments (those before `--ros-args`), program name excluded."""
    own = list(args)
    if "--ros-args" in own:
        own = own[: own.index("--ros-args")]
    return any(a in HELP_FLAGS for a in own)


def format_help(node: NodeHelp, width: int = 100) -> str:
    """The text `--help` prints: usage, summary, then one entry per parameter."""
    module = f"changing_slam_ros.nodes.{node.executable}_node"
    positional = f" {node.positional}" if node.positional else ""
    lines = [
        f"usage: ros2 run changing_slam_ros {node.executable} [-h]{positional} [--ros-args -p NAME:=VALUE ...]",
        f"   or: python -m {module} [-h]{positional} [--ros-args -p NAME:=VALUE ...]",
        "",
        node.summary,
        "",
        "parameters (set with --ros-args -p NAME:=VALUE; rclpy's use_sim_time too):",
    ]
    for name, default, description in node.parameters:
        lines.append(f"  {name} ({parameter_type(default)}, default {format_value(parameter_default(default))})")
        lines += textwrap.wrap(description, width=width, initial_indent=" " * 6, subsequent_indent=" " * 6)
    return "\n".join(lines) + "\n"
