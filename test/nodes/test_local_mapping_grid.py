"""local_mapping's `~/grid`: a node started from a saved map publishes the map's occupancy grid at once, transient
local (a subscriber that joins later still gets it), with the floor-frame origin in the map frame; saving the map
writes the Nav2 pair beside it, and it parses as map_server reads it.

The map: 30 frames of the simulator's `static` room (320x240, 15 fps) through the offline system, saved with its
keyframes' depth scans.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import spin_until

pytestmark = pytest.mark.ros

pytest.importorskip("rclpy")
pytest.importorskip("changing_slam_msgs.msg", reason="interfaces not built (tools/build_interfaces.sh)")


@pytest.fixture(scope="module")
def saved_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.core.system import SlamSystem
    from changing_slam_ros.errors import SimError
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.map_file import save_map
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    root = tmp_path_factory.mktemp("grid_node")
    try:
        simulate(build_scenario("static", 0), root / "static", RenderOptions(width=320, height=240, frames=30, fps=15.0), 0)
    except SimError as err:
        pytest.skip(f"no offscreen rendering here: {err}")
    system = SlamSystem(system_config_from_mapping(load_yaml(find_config("sim")), "sim"))
    for rgbd in open_dataset(root / "static", "sim"):
        system.process(rgbd)
    assert all(kf.grid_scan is not None for kf in system.atlas.current.keyframes.values())
    save_map(root / "map.npz", system.atlas, None, system.tracker.next_kf_id)
    return root / "map.npz"


def test_grid_is_latched_and_saved_as_a_nav2_pair(ros_context, saved_map: Path, tmp_path: Path) -> None:  # noqa: ANN001
    from nav_msgs.msg import OccupancyGrid
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from changing_slam_ros.io.nav2_map import read_nav2_map
    from changing_slam_ros.nodes.local_mapping_node import LocalMappingNode

    node = LocalMappingNode(context=ros_context, parameter_overrides=[
        Parameter("config", value="sim"), Parameter("map_file", value=str(saved_map)),
        Parameter("grid.resolution_m", value=0.1)])  # fmt: skip
    listener = Node("grid_listener", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(listener)
    try:
        got: list[OccupancyGrid] = []
        # joins after the grid was published (at start, from the loaded map): only a latched grid reaches it
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        listener.create_subscription(OccupancyGrid, "/local_mapping/grid", got.append, qos)
        assert spin_until(executor, lambda: got, 10.0)
        infos = listener.get_publishers_info_by_topic("/local_mapping/grid")
        assert len(infos) == 1 and infos[0].qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        msg = got[0]
        data = np.array(msg.data, np.int8)
        assert msg.header.frame_id == "map" and msg.info.resolution == pytest.approx(0.1)
        assert len(data) == msg.info.width * msg.info.height and msg.info.width * msg.info.height > 100
        assert (data == 100).sum() >= 20 and (data == 0).sum() >= 200 and set(np.unique(data)) <= {-1, 0, 100}
        q = msg.info.origin.orientation
        assert abs(np.linalg.norm([q.x, q.y, q.z, q.w]) - 1.0) < 1e-9 and abs(q.w) < 0.999  # the floor is tilted in map
        node.save_map(tmp_path / "saved.npz")
        pair = read_nav2_map(tmp_path / "saved_grid.yaml")
        assert (tmp_path / "saved_grid.pgm").is_file() and pair.resolution_m == pytest.approx(0.1)
        np.testing.assert_array_equal(pair.occupancy.reshape(-1), data)
    finally:
        executor.shutdown()
        listener.destroy_node()
        node.destroy_node()
