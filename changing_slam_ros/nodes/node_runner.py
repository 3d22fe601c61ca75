"""What every node's `main()` shares: init, spin, clean shutdown (ros2/demos jazzy pattern), type lookup.

    def main(args=None) -> int:
        return run_node(lambda argv: DetectionNode(), args)

`run_node` spins inside `try`, treats Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException)
as a normal stop, also when they arrive while the node is still starting, prints a `SlamError` as one line and returns 1, and always destroys the node and calls
`try_shutdown()`.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from changing_slam_ros.errors import SlamError


# A parameter spec: (name, default, description). Use Parameter.Type.STRING_ARRAY (etc.) as the default of
# an array parameter that starts empty: rclpy cannot infer a type from [].
ParamSpec = tuple[str, Any, str]


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare every parameter with its description and default; returns name -> value (arrays as lists)."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.parameter import Parameter

    values: dict[str, Any] = {}
    for name, default, description in specs:
        param = node.declare_parameter(name, default, ParameterDescriptor(description=description))
        value = param.value
        if isinstance(default, Parameter.Type):
            value = [] if value is None else list(value)
        values[name] = value
    return values


def message_class(msgtype: str) -> Any:
    """The Python class of ROS 2 type `pkg/msg/Name` (also `pkg/srv/Name`); ImportError when not installed."""
    try:
        from rosidl_runtime_py.utilities import get_message  # type: ignore[import-not-found]

        return get_message(msgtype)
    except ImportError:
        pass
    parts = msgtype.split("/")
    if len(parts) == 2:  # ROS 1 style pkg/Name
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        raise ImportError(f"{msgtype}: not a ROS 2 type name (expected package/msg/Name)")
    package, kind, name = parts
    module = importlib.import_module(f"{package}.{kind}")
    try:
        return getattr(module, name)
    except AttributeError as err:
        raise ImportError(f"{msgtype}: {package}.{kind} has no {name}") from err


def run_node(
    make_node: Callable[[list[str]], Node],
    args: Sequence[str] | None = None,
    body: Callable[[Node, SingleThreadedExecutor], int] | None = None,
) -> int:
    """Init rclpy, build the node from the non-ROS command-line arguments, spin (or run `body`), shut down.

    Returns the process exit code: 0 on a normal end or Ctrl-C/SIGTERM, 1 on a `SlamError`.
    """
    argv = list(sys.argv if args is None else args)
    rclpy.init(args=argv)
    node: Node | None = None
    code = 0
    try:
        non_ros = rclpy.utilities.remove_ros_args(argv)[1:]
        executor = SingleThreadedExecutor()
        node = make_node(non_ros)
        executor.add_node(node)
        if body is None:
            executor.spin()
        else:
            code = body(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    except SlamError as err:
        print(f"error: {err}", file=sys.stderr)
        code = 1
    except Exception:
        if rclpy.ok():
            raise
        code = 0  # SIGINT/SIGTERM arrived while the node was starting: rcl calls fail on the shut-down context
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code
