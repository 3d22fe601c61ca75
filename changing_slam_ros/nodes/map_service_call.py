"""Call the map owner's SaveMap or LoadMap service once, from the command line (no `ros2 service call` needed).

    python -m changing_slam_ros.nodes.map_service_call load /path/to/map.npz [--service /local_mapping/load_map]
        [--timeout 60]
    python -m changing_slam_ros.nodes.map_service_call save /path/to/map.npz [--service /local_mapping/save_map]

Prints the reply (`success`, `message`) as one line and exits 0 when the service said success, 1 when it
refused (the message names the file and field), 2 when no service answered within --timeout. `changing-slam
graph --load-map PATH@S` runs it S seconds into playback.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

DEFAULT_SERVICES = {"load": "/local_mapping/load_map", "save": "/local_mapping/save_map"}


def call(kind: str, path: str, service: str, timeout_s: float) -> tuple[int, str]:
    """(exit code, reply line) of one call; rclpy is initialised and shut down here."""
    import rclpy

    from changing_slam_msgs.srv import LoadMap, SaveMap

    srv_type = LoadMap if kind == "load" else SaveMap
    rclpy.init()
    node = rclpy.create_node("map_service_call")
    try:
        client = node.create_client(srv_type, service)
        if not client.wait_for_service(timeout_sec=timeout_s):
            return 2, f"map_service_call: no {service} within {timeout_s:.0f} s"
        future = client.call_async(srv_type.Request(path=path))
        deadline = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not future.done():
            return 2, f"map_service_call: {service} did not answer within {timeout_s:.0f} s"
        reply = future.result()
        return (0 if reply.success else 1), f"map_service_call: {service} success={reply.success} {reply.message}"
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="map_service_call", description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=sorted(DEFAULT_SERVICES), help="load or save")
    parser.add_argument("path", help="map file (map.npz)")
    parser.add_argument("--service", default="", help="service name (default /local_mapping/load_map or save_map)")
    parser.add_argument("--timeout", type=float, default=60.0, metavar="S", help="wait for the service and the reply")
    a = parser.parse_args(argv)
    code, line = call(a.kind, a.path, a.service or DEFAULT_SERVICES[a.kind], a.timeout)
    print(line, flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
