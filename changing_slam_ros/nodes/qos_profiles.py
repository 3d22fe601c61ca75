"""QoS profiles the nodes share.

`LATCHED`: reliable, transient local, depth 1 (ROS 1's latched topic): a subscriber that matches after the last
message still gets it (maps, the semantic map, the occupancy grid, a node's "ready" announcement).
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
