"""The ROS 2 layout: `colcon build` puts every node where `ros2 run changing_slam_ros <node>` looks, and it runs."""

from __future__ import annotations

import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import REPO

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODES = ("detection", "tracking", "local_mapping", "loop_closing", "object_map", "bag_player")
PACKAGE_FILES = ("setup.py", "setup.cfg", "package.xml", "resource", "changing_slam_ros", "config", "launch")


def _copy_package(dst: Path) -> None:
    """The ament_python package alone (msg_defs/ is built separately by tools/build_interfaces.sh)."""
    dst.mkdir(parents=True)
    for name in PACKAGE_FILES:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dst / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        elif src.exists():
            shutil.copy2(src, dst / name)


def _read_until(proc: subprocess.Popen, needle: str, timeout_s: float) -> str:
    """Output of `proc` (stdout+stderr) up to the first line containing `needle`; fails after timeout_s."""
    seen = ""
    deadline = time.monotonic() + timeout_s
    assert proc.stdout is not None
    while needle not in seen:
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None and not select.select([proc.stdout], [], [], 0)[0]:
            raise AssertionError(f"no '{needle}' within {timeout_s} s (exit {proc.poll()}); output:\n{seen}")
        ready, _, _ = select.select([proc.stdout], [], [], min(left, 0.5))
        if ready:
            line = proc.stdout.readline()
            seen += line
    return seen


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory) -> Path:
    pytest.importorskip("colcon_ros", reason="colcon-ros not installed")
    ws = tmp_path_factory.mktemp("colcon_ws")
    _copy_package(ws / "src" / "changing_slam_ros")
    colcon = Path(sys.executable).parent / "colcon"
    cmd = [str(colcon), "--log-base", "log", "build", "--base-paths", "src", "--build-base", "build",
           "--install-base", "install", "--event-handlers", "console_direct-"]  # fmt: skip
    done = subprocess.run(cmd, cwd=ws, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"colcon build failed:\n{done.stdout}\n{done.stderr}"
    return ws / "install"


def test_colcon_build_puts_every_node_at_the_ros2_run_location(colcon_install):
    lib = colcon_install / "changing_slam_ros" / "lib" / "changing_slam_ros"
    for node in NODES:
        exe = lib / node
        assert exe.is_file() and os.access(exe, os.X_OK), f"{exe} missing or not executable"
        assert exe.read_text().startswith("#!") and "python" in exe.read_text().splitlines()[0]
    share = colcon_install / "changing_slam_ros" / "share"
    assert (share / "ament_index" / "resource_index" / "packages" / "changing_slam_ros").is_file()
    assert (share / "changing_slam_ros" / "package.xml").is_file()


def test_the_installed_bag_player_starts_plays_and_exits_cleanly_on_sigint(colcon_install, tmp_path, fr1_bag_writer):
    bag = fr1_bag_writer(tmp_path / "bag", n=3, scale=8)
    exe = colcon_install / "changing_slam_ros" / "lib" / "changing_slam_ros" / "bag_player"
    env = dict(os.environ, ROS_DOMAIN_ID="163", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    script = f'. "{colcon_install}/local_setup.sh" && exec "{exe}" "{bag.path}" --ros-args -p loop:=true'
    proc = subprocess.Popen(
        ["sh", "-c", script], cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        out = _read_until(proc, "played", timeout_s=60)
        assert "[bag_player]: bag_player: " in out and "3 topics, 9 messages" in out
        # It is the colcon-installed copy that runs, not the source checkout.
        assert str(colcon_install) in _installed_module_path(colcon_install, env)
        out += _read_until(proc, "looping", timeout_s=30)  # still playing: pass 2 began
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert rc == 0, out + (proc.stdout.read() if proc.stdout else "")


def _installed_module_path(install: Path, env: dict[str, str]) -> str:
    script = f'. "{install}/local_setup.sh" && exec "{sys.executable}" -c "import changing_slam_ros.nodes.bag_player_node as m; print(m.__file__)"'
    done = subprocess.run(["sh", "-c", script], cwd="/", env=env, capture_output=True, text=True, timeout=60)
    return done.stdout.strip()


def test_the_launch_file_starts_every_node_executable_of_the_package():
    """Checked statically: launch/launch_ros are not on PyPI (a ROS 2 machine runs it for real)."""
    import ast

    tree = ast.parse((REPO / "launch" / "changing_slam.launch.py").read_text())
    executables = {
        kw.value.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "Node"
        for kw in node.keywords
        if kw.arg == "executable" and isinstance(kw.value, ast.Constant)
    }
    assert executables == set(NODES)
    try:
        import launch_ros  # noqa: F401
    except ImportError:
        return
    import importlib.util

    spec = importlib.util.spec_from_file_location("launch_file", REPO / "launch" / "changing_slam.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert len(module.generate_launch_description().entities) >= 11


@pytest.mark.parametrize("node", ["tracking", "object_map"])
def test_installed_graph_nodes_start_and_exit_cleanly_on_sigterm(colcon_install, tmp_path, node):
    pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")
    exe = colcon_install / "changing_slam_ros" / "lib" / "changing_slam_ros" / node
    env = dict(os.environ, ROS_DOMAIN_ID="164", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(["sh", "-c", f'. "{colcon_install}/local_setup.sh" && exec "{exe}"'], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        out = _read_until(proc, f"{node}: started", timeout_s=60)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert rc == 0, out + (proc.stdout.read() if proc.stdout else "")


def _declared_parameters(node: str) -> set[str]:
    """The names a node module spells as parameter specs, `(name, default, description)` tuples (what
    `node_runner.declare_parameters` takes; bag_player builds its list in a variable first, tracking keeps its
    table in `tracking_params.py`)."""
    import ast

    nodes = REPO / "changing_slam_ros" / "nodes"
    sources = [nodes / f"{node}_node.py", nodes / f"{node}_params.py"]
    return {
        item.elts[0].value
        for path in sources if path.is_file()
        for item in ast.walk(ast.parse(path.read_text()))
        if isinstance(item, ast.Tuple) and len(item.elts) == 3
        and isinstance(item.elts[0], ast.Constant) and isinstance(item.elts[0].value, str)
    }  # fmt: skip


def test_every_parameter_the_launch_file_sets_is_declared_by_its_node():
    """A misspelt or removed parameter in the launch file would be silently ignored by rclpy on a ROS 2 machine."""
    import ast

    tree = ast.parse((REPO / "launch" / "changing_slam.launch.py").read_text())
    checked = 0
    for call in ast.walk(tree):
        if not (isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Node"):
            continue
        kw = {k.arg: k.value for k in call.keywords}
        node = kw["executable"].value
        declared = _declared_parameters(node) | {"use_sim_time"}
        assert len(declared) > 3, node
        for d in (e for e in kw["parameters"].elts if isinstance(e, ast.Dict)):
            for key in d.keys:
                assert key.value in declared, f"launch file sets {node}.{key.value}, which {node} does not declare"
                checked += 1
    assert checked >= 12
