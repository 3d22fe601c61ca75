"""Untrusted input to the nodes: type names in a bag select only allowed installed interfaces (nothing is
imported by a bag's say-so, nothing from the current folder), and SaveMap / LoadMap stay inside `map_dir`."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros
rclpy = pytest.importorskip("rclpy")

from changing_slam_ros.commands.graph_process import child_env, node_argv  # noqa: E402
from changing_slam_ros.nodes.node_runner import message_class  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
PLANTED = "import pathlib; pathlib.Path({marker!r}).write_text('executed')\n"


def write_bag(path: Path, types: dict[str, str]) -> Path:
    """An mcap file with one message per topic: {topic: type name}; each type is `string data` on the wire."""
    from mcap.writer import Writer

    cdr = b"\x00\x01\x00\x00" + (3).to_bytes(4, "little") + b"hi\x00"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        for i, (topic, msgtype) in enumerate(sorted(types.items())):
            schema = writer.register_schema(name=msgtype, encoding="ros2msg", data=b"string data")
            channel = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema)
            writer.add_message(channel, log_time=1_000_000_000 + i, data=cdr, publish_time=1_000_000_000 + i)
        writer.finish()
    return path


def test_type_names_outside_the_allowed_interface_packages_are_refused_importing_nothing(tmp_path, monkeypatch):
    (tmp_path / "evil.py").write_text(PLANTED.format(marker=str(tmp_path / "ran")))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))  # as `python -m` from this folder would have it
    sys.modules.pop("this", None)
    for name in ("this/msg/Zen", "evil/msg/Zen", "evil/Zen", "os/msg/System", "std_msgs/msg/../Zen", "std_msgs.msg"):
        with pytest.raises(ImportError, match="not an allowed interface package|not a ROS 2 type name"):
            message_class(name)
    assert "this" not in sys.modules and "evil" not in sys.modules and not (tmp_path / "ran").exists()
    with pytest.raises(ImportError, match="has no message type"):
        message_class("std_msgs/msg/QoSProfile")  # an attribute, not a message
    from sensor_msgs.msg import Image

    assert message_class("sensor_msgs/msg/Image") is Image and message_class("sensor_msgs/Image") is Image


def test_bag_player_skips_topics_whose_type_names_a_module_and_imports_none(ros_context, tmp_path, monkeypatch):
    from rclpy.parameter import Parameter

    from changing_slam_ros.nodes.bag_player_node import BagPlayerNode

    (tmp_path / "evil.py").write_text(PLANTED.format(marker=str(tmp_path / "ran")))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("this", None)
    bag = write_bag(tmp_path / "zen.mcap", {"/zen": "this/msg/Zen", "/evil": "evil/msg/Zen",
                                             "/text": "std_msgs/msg/String"})  # fmt: skip
    player = BagPlayerNode(context=ros_context, parameter_overrides=[Parameter("bag", value=str(bag))])
    try:
        assert sorted(player.bag_publishers) == ["/text"]
    finally:
        player.destroy_node()
    assert "this" not in sys.modules and "evil" not in sys.modules and not (tmp_path / "ran").exists()


def test_graph_node_processes_do_not_import_modules_planted_in_the_current_folder(tmp_path):
    """`changing-slam graph evil.mcap` in a folder holding evil.py: the player process (started as the graph
    starts it: `python -P`, PYTHONSAFEPATH) neither executes evil.py nor a planted `std_msgs.py`."""
    marker = tmp_path / "ran"
    for module in ("evil", "std_msgs", "this"):
        (tmp_path / f"{module}.py").write_text(PLANTED.format(marker=str(marker)))
    bag = write_bag(tmp_path / "evil.mcap", {"/evil": "evil/msg/Zen", "/text": "std_msgs/msg/String"})
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(150, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(tmp_path / "ros"))  # fmt: skip
    env.pop("PYTHONPATH", None)
    env = child_env(env)  # PYTHONPATH: the package root only, never the current folder
    argv = node_argv("bag_player_node", {"bag": "evil.mcap", "publish_clock": False}, positional=None)
    out = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert not marker.exists()
    assert "skipping /evil" in out.stderr + out.stdout and "not an allowed interface package" in out.stderr + out.stdout
    assert bag.is_file()


# -- SaveMap / LoadMap ------------------------------------------------------------------------------
def _spin_until(executor, done, timeout_s: float = 20.0) -> bool:  # noqa: ANN001
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if done():
            return True
        executor.spin_once(timeout_sec=0.05)
    return done()


def _service_caller(ros_context, node, prefix: str):  # noqa: ANN001, ANN202
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from changing_slam_msgs.srv import LoadMap, SaveMap

    probe = Node("probe", context=ros_context)
    clients = {"save": probe.create_client(SaveMap, f"/{prefix}/save_map"),
               "load": probe.create_client(LoadMap, f"/{prefix}/load_map")}  # fmt: skip
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)

    def call(kind: str, path: str):  # noqa: ANN202
        assert _spin_until(executor, clients[kind].service_is_ready)
        request = (SaveMap if kind == "save" else LoadMap).Request(path=path)
        future = clients[kind].call_async(request)
        assert _spin_until(executor, future.done, 60.0)
        return future.result()

    return call, executor, probe


def _escapes(tmp_path: Path, maps: Path, suffix: str) -> list[tuple[str, str]]:
    """(request path, expected reason) pairs that must be refused."""
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (maps / "link").symlink_to(outside)
    (maps / f"notes{suffix}").write_text("my notes, not a map\n")
    return [
        (str(outside / f"m{suffix}"), "outside map_dir"),
        (f"../elsewhere/m{suffix}", "'..' is not allowed"),
        (f"sub/../../elsewhere/m{suffix}", "'..' is not allowed"),
        (f"link/m{suffix}", "outside map_dir"),
        ("/etc/passwd", "outside map_dir"),
        ("bashrc", "a map file name ends in"),
        (f"notes{suffix}", "is not a map file of ours"),
    ]


def test_local_mapping_save_and_load_map_stay_inside_map_dir_and_say_why_they_refuse(ros_context, tmp_path):
    from rclpy.parameter import Parameter

    from changing_slam_ros.io.map_file import load_map
    from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode

    maps = tmp_path / "maps"
    maps.mkdir()
    cases = _escapes(tmp_path, maps, ".npz")
    unset = LocalMappingNode(context=ros_context, parameter_overrides=[Parameter("config", value="sim")])
    call, executor, probe = _service_caller(ros_context, unset, "local_mapping")
    refused = call("save", str(maps / "a.npz"))
    assert not refused.success and "no map_dir parameter is set" in refused.message
    executor.shutdown()
    unset.destroy_node()
    probe.destroy_node()

    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="sim"), Parameter("map_dir", value=str(maps))])  # fmt: skip
    call, executor, probe = _service_caller(ros_context, node, "local_mapping")
    for path, reason in cases:
        reply = call("save", path)
        assert not reply.success and reason in reply.message, (path, reply.message)
    assert (maps / "notes.npz").read_text() == "my notes, not a map\n"
    assert sorted(p.name for p in (tmp_path / "elsewhere").iterdir()) == []
    saved = call("save", "first.npz")
    assert saved.success, saved.message
    load_map(maps / "first.npz")
    again = call("save", str(maps / "first.npz"))  # an absolute path inside map_dir, over a map of ours
    assert again.success, again.message
    (tmp_path / "elsewhere" / "m.npz").write_bytes((maps / "first.npz").read_bytes())
    for path, reason in [*cases[:5], ("missing.npz", "no such map file"), ("notes.npz", "not a map file")]:
        reply = call("load", path)
        assert not reply.success and ("not loaded" in reply.message), (path, reply.message)
        if reason != "not a map file":
            assert reason in reply.message, (path, reply.message)
    loaded = call("load", "first.npz")
    assert loaded.success, loaded.message
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()


def test_object_map_save_and_load_map_stay_inside_map_dir_and_say_why_they_refuse(ros_context, tmp_path):
    from rclpy.parameter import Parameter

    from changing_slam_ros.nodes.object_map_node import ObjectMapNode

    maps = tmp_path / "maps"
    maps.mkdir()
    cases = _escapes(tmp_path, maps, ".json")
    node = ObjectMapNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="sim"), Parameter("map_dir", value=str(maps))])  # fmt: skip
    call, executor, probe = _service_caller(ros_context, node, "object_map")
    for path, reason in cases:
        reply = call("save", path)
        assert not reply.success and reason in reply.message, (path, reply.message)
        assert reply.message.startswith("object_map: SaveMap: refused")
    assert (maps / "notes.json").read_text() == "my notes, not a map\n"
    assert list((tmp_path / "elsewhere").iterdir()) == []
    assert call("save", "semantic.json").success and call("save", "semantic.json").success  # ours: replaced
    assert json.loads((maps / "semantic.json").read_text())["format"] == "changing_slam_ros semantic map"
    assert call("load", "semantic.json").success
    for path, reason in cases[:5]:
        reply = call("load", path)
        assert not reply.success and reason in reply.message, (path, reply.message)
    executor.shutdown()
    node.destroy_node()
    probe.destroy_node()
