"""The launch file's `auto` arguments give the nodes what `changing-slam graph` gives them, in real time and lossless.

`launch` and `launch_ros` are not on PyPI, so the launch file runs here against stand-ins that record what it
builds; a `PythonExpression` is evaluated as launch does (its parts joined, `LaunchConfiguration`s replaced by the
argument values, then `eval`). The graph's side is the argv it builds for its node processes (no process starts).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import sys
import types
from pathlib import Path
from typing import Any

import pytest

from changing_slam_ros.commands.graph import Graph, add_arguments

REPO = Path(__file__).resolve().parents[2]
# node -> the parameters the five `auto` launch arguments set
AUTO_PARAMETERS = {"detection": ("intra_op_threads", "model", "max_rate_hz"), "tracking": ("detections_wait_s",),
                   "local_mapping": ("ba_solver",)}  # fmt: skip


class _Record:
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


def _stand_ins() -> dict[str, types.ModuleType]:
    mods = {name: types.ModuleType(name) for name in
            ("launch", "launch.actions", "launch.conditions", "launch.substitutions", "launch_ros", "launch_ros.actions")}  # fmt: skip
    mods["launch"].LaunchDescription = lambda entities: entities
    mods["launch.actions"].DeclareLaunchArgument = type("DeclareLaunchArgument", (_Record,), {})
    mods["launch.conditions"].IfCondition = type("IfCondition", (_Record,), {})
    mods["launch.substitutions"].LaunchConfiguration = type("LaunchConfiguration", (_Record,), {})
    mods["launch.substitutions"].PythonExpression = type("PythonExpression", (_Record,), {})
    mods["launch_ros.actions"].Node = type("Node", (_Record,), {})
    return mods


def _launch_parameters(monkeypatch: pytest.MonkeyPatch, lossless: bool) -> dict[str, dict[str, Any]]:
    """node name -> its parameters as the launch file gives them with its defaults and `lossless`."""
    for name, module in _stand_ins().items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("changing_slam_launch", REPO / "launch" / "changing_slam.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    entities = module.generate_launch_description()
    args = {e.args[0]: e.kwargs["default_value"] for e in entities if type(e).__name__ == "DeclareLaunchArgument"}
    args["lossless"] = "true" if lossless else "false"

    def value(v: Any) -> Any:
        kind = type(v).__name__
        if kind == "LaunchConfiguration":
            return args[v.args[0]]
        if kind == "PythonExpression":
            return eval("".join(str(value(p)) for p in v.args[0]))  # noqa: S307 - what launch does with it
        return v

    out: dict[str, dict[str, Any]] = {}
    for e in entities:
        if type(e).__name__ == "Node":
            params = {k: value(v) for d in e.kwargs["parameters"] for k, v in d.items()}
            out[e.kwargs["executable"]] = params
    return out


def _graph_parameters(tmp_path: Path, lossless: bool) -> dict[str, dict[str, Any]]:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    bag = REPO / "bags" / "sim_walking_changing.mcap"
    if not bag.is_file():
        pytest.skip(f"{bag} missing")
    graph = Graph(parser.parse_args([str(bag), "--out", str(tmp_path), "--config", "sim", *(["--lossless"] if lossless else [])]))
    out: dict[str, dict[str, Any]] = {}
    for node, params in AUTO_PARAMETERS.items():
        argv = dict(a.split(":=", 1) for a in graph.nodes[node].argv if ":=" in a)
        out[node] = {name: ast.literal_eval(argv[name]) for name in params}
    return out


@pytest.mark.parametrize("lossless", [False, True], ids=["real_time", "lossless"])
def test_auto_launch_arguments_give_the_nodes_the_graph_commands_settings(monkeypatch, tmp_path, lossless):
    launch = _launch_parameters(monkeypatch, lossless)
    graph = _graph_parameters(tmp_path, lossless)
    for node, params in AUTO_PARAMETERS.items():
        for name in params:
            assert launch[node][name] == graph[node][name], (node, name)
    if not lossless:  # the real-time settings measured for six processes on two cores (commands/graph.py)
        assert launch["detection"]["model"] == "ssd_mobilenet_v2_coco_int8" and launch["detection"]["max_rate_hz"] == 15.0
        assert launch["tracking"]["detections_wait_s"] == 0.05 and launch["local_mapping"]["ba_solver"] == "schur"


@pytest.mark.parametrize(("given", "expected"), [
    ({}, ("/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info")),
    ({"topics": "realsense_jazzy"}, ("/camera/camera/color/image_raw", "/camera/camera/aligned_depth_to_color/image_raw",
                                     "/camera/camera/color/camera_info")),
    ({"topics": "realsense", "depth_topic": "/d"}, ("/camera/color/image_raw", "/d", "/camera/color/camera_info")),
], ids=["tum", "realsense_jazzy", "realsense_one_replaced"])  # fmt: skip
def test_camera_topic_arguments_remap_tracking_and_detection(monkeypatch, given, expected):
    """A live camera (a RealSense driver's topics) reaches tracking and detection through the `topics` preset and
    the three topic arguments that replace single names of it."""
    for name, module in _stand_ins().items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("changing_slam_launch", REPO / "launch" / "changing_slam.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    entities = module.generate_launch_description()
    nodes = {e.kwargs["executable"]: e for e in entities if type(e).__name__ == "Node"}
    args = {e.args[0]: e.kwargs["default_value"] for e in entities if type(e).__name__ == "DeclareLaunchArgument"}
    args.update(given)

    def value(v: Any) -> Any:
        if isinstance(v, str):
            return v
        if type(v).__name__ == "LaunchConfiguration":
            return args[v.args[0]]
        return eval("".join(str(value(p)) for p in v.args[0]))  # noqa: S307 - what launch does with it

    def remaps(node: str) -> dict[str, str]:
        return {src: value(dst) for src, dst in nodes[node].kwargs["remappings"]}

    colour, depth, info = expected
    assert remaps("tracking") == {"/camera/rgb/image_color": colour, "/camera/depth/image": depth,
                                  "/camera/rgb/camera_info": info}  # fmt: skip
    assert remaps("detection") == {"image": colour}
