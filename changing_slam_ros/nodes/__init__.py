"""Thin rclpy nodes: parameters, QoS, message <-> core conversion, then one call into core."""
