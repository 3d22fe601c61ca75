"""What every node's `main()` shares: init, spin, clean shutdown (ros2/demos jazzy pattern), type lookup.

    def main(args=None) -> int:
        return run_node(lambda argv: DetectionNode(), args)

`run_node` spins inside `try`, treats Ctrl-C (KeyboardInterrupt) and SIGTERM (ExternalShutdownException)
as a normal stop, also when they arrive while the node is still starting, prints a `SlamError` as one line and returns 1, and always destroys the node and calls
`try_shutdown()`.
"""

from __future__ import annotations

import importlib
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from changing_slam_ros.errors import ConfigError, SlamError
from changing_slam_ros.nodes.heap_trim import HeapTrim, interval_from_env
from changing_slam_ros.nodes.node_help import NodeHelp, ParamSpec, format_help, wants_help


_TYPE_WORDS = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
               "string_array": "a list of strings", "double_array": "a list of numbers"}


def undeclared_parameters(node: Node) -> list[str]:
    """Names given to the node (`-p name:=value`, parameter overrides) that it never declared: misspellings."""
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    return sorted(n for n in overrides if not node.has_parameter(n) and not n.startswith("qos_overrides."))


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare every parameter with its description and default; returns name -> value (arrays as lists)."""
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.parameter import Parameter

    from rclpy.exceptions import InvalidParameterTypeException

    values: dict[str, Any] = {}
    for name, default, description in specs:
        try:
            param = node.declare_parameter(name, default, ParameterDescriptor(description=description))
        except InvalidParameterTypeException as err:
            expected = default.name.lower() if isinstance(default, Parameter.Type) else type(default).__name__
            given = getattr(err, "args", ("",))[0].split("' to '", 1)[-1].split("' of type", 1)[0]
            raise ConfigError(f"{node.get_name()}: parameter {name}: expected {_TYPE_WORDS.get(expected, expected)}, "
                              f"got {given!r} ({description})") from err  # fmt: skip
        value = param.value
        if isinstance(default, Parameter.Type):
            value = [] if value is None else list(value)
        values[name] = value
    return values


# The interface packages whose Python classes a type name may select: the ones package.xml depends on, their
# dependencies and our own. A type name read from a bag only picks a class out of these; it never names a module
# to import (a bag naming `this/msg/Zen` would otherwise import Python's `this`).
INTERFACE_PACKAGES = frozenset({
    "builtin_interfaces", "std_msgs", "std_srvs", "sensor_msgs", "geometry_msgs", "nav_msgs", "visualization_msgs",
    "diagnostic_msgs", "rosgraph_msgs", "tf2_msgs", "changing_slam_msgs", "rcl_interfaces", "lifecycle_msgs",
    "action_msgs", "unique_identifier_msgs", "type_description_interfaces", "service_msgs",
})  # fmt: skip
_TYPE_NAME = re.compile(r"^([a-z][a-z0-9_]*)/(?:(msg|srv)/)?([A-Z][A-Za-z0-9]*)$")


def message_class(msgtype: str) -> Any:
    """The Python class of ROS 2 type `pkg/msg/Name` (also `pkg/srv/Name`, ROS 1 style `pkg/Name`).

    Only packages in `INTERFACE_PACKAGES` are looked up; any other name raises ImportError naming the type, and
    nothing is imported for it. (The graph starts nodes with `python -P`, so the current folder cannot shadow
    an interface package either.)
    """
    match = _TYPE_NAME.match(msgtype)
    if match is None:
        raise ImportError(f"{msgtype}: not a ROS 2 type name (expected package/msg/Name)")
    package, kind, name = match.group(1), match.group(2) or "msg", match.group(3)
    if package not in INTERFACE_PACKAGES:
        raise ImportError(f"{msgtype}: package {package} is not an allowed interface package "
                          f"({', '.join(sorted(INTERFACE_PACKAGES))})")  # fmt: skip
    module = importlib.import_module(f"{package}.{kind}")
    cls = getattr(module, name, None)
    if not isinstance(cls, type) or not hasattr(cls, "get_fields_and_field_types"):
        raise ImportError(f"{msgtype}: {package}.{kind} has no message type {name}")
    return cls


class StopRequest:
    """SIGINT / SIGTERM as a request to stop between callbacks, not an exception inside one.

    rclpy's own handlers shut the context down from another thread and Python raises KeyboardInterrupt at
    whatever line the main thread is on: a keyframe half mapped is lost (received, never in the map). Here the
    first signal only sets `requested` and calls `on_request` (wake the executor, or shut the context down for a
    `body` such as the player's loop); a second signal raises KeyboardInterrupt (stop now).
    """

    def __init__(self) -> None:
        self.requested = False
        self.on_request: Callable[[], None] | None = None
        self._previous = {sig: signal.signal(sig, self._handle) for sig in (signal.SIGINT, signal.SIGTERM)}

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        if self.on_request is not None:
            self.on_request()

    def restore(self) -> None:
        for sig, previous in self._previous.items():
            signal.signal(sig, previous)


def drain_work(node: Node, executor: SingleThreadedExecutor, stop: StopRequest, timeout_s: float) -> None:
    """After a stop request, spin while the node says it still waits for work it started (`work_pending()`:
    a description, or "" when done), so that what was sent to it is finished before its outputs are written."""
    pending = getattr(node, "work_pending", None)
    if pending is None or not pending():
        return
    node.get_logger().info(f"{node.get_name()}: stopping after {pending()}")
    deadline = time.monotonic() + timeout_s
    while (what := pending()) and rclpy.ok():
        if time.monotonic() > deadline:
            node.get_logger().warning(f"{node.get_name()}: stopping without {what} (not done after {timeout_s:.0f} s)")
            return
        executor.spin_once(timeout_sec=0.1)


def run_node(
    make_node: Callable[[list[str]], Node],
    args: Sequence[str] | None = None,
    body: Callable[[Node, SingleThreadedExecutor], int] | None = None,
    drain_timeout_s: float = 90.0,
    node_help: NodeHelp | None = None,
) -> int:
    """Init rclpy, build the node from the non-ROS command-line arguments, spin (or run `body`), shut down.

    A first SIGINT / SIGTERM ends spinning between callbacks; the node then finishes the work it announced
    (`drain_work`, at most `drain_timeout_s`) and `destroy_node` writes its outputs with the context still up.
    Returns the process exit code: 0 on a normal end or Ctrl-C/SIGTERM, 1 on a `SlamError`. With `node_help`
    and `-h` / `--help` before `--ros-args`, prints the node's parameters and returns 0 without initialising rclpy.
    """
    from rclpy.signals import SignalHandlerOptions

    argv = list(sys.argv if args is None else args)
    if node_help is not None and wants_help(argv[1:]):
        sys.stdout.write(format_help(node_help))
        return 0
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    stop = StopRequest()
    node: Node | None = None
    code = 0
    try:
        non_ros = rclpy.utilities.remove_ros_args(argv)[1:]
        executor = SingleThreadedExecutor()
        node = make_node(non_ros)
        if unknown := undeclared_parameters(node):
            node.get_logger().warning(f"{node.get_name()}: unknown parameter(s) {', '.join(unknown)} ignored "
                                      "(`ros2 param list` or the node's docs name the known ones)")  # fmt: skip
        executor.add_node(node)
        if body is None:
            stop.on_request = executor.wake
            heap = HeapTrim(interval_from_env())  # freed memory back to the system between callbacks (`heap_trim`)
            while not stop.requested and rclpy.ok():
                executor.spin_once(timeout_sec=0.25)
                heap.maybe_trim()
            if stop.requested:
                drain_work(node, executor, stop, drain_timeout_s)
        else:
            stop.on_request = rclpy.try_shutdown  # the body's loop checks the context
            if not stop.requested:
                code = body(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0
    except SlamError as err:
        print(f"error: {err}", file=sys.stderr)
        code = 1
    except Exception:
        if rclpy.ok():
            raise
        code = 0  # stopped while the node was starting: rcl calls fail on the shut-down context
    finally:
        try:
            if node is not None:
                node.destroy_node()
        finally:
            stop.restore()
            rclpy.try_shutdown()
    return code
