"""Publishers and subscriptions without rclpy's default QoS-event handlers (a node mixin), to spin cheaply.

rclpy gives every publisher and subscription two QoS-event handlers by default (incompatible QoS, incompatible
type: each only logs a warning), and its executor walks every handler in Python on every wake-up. On the
tracking node's 12 publishers and 8 subscriptions that is 40 handlers: a spin cost about 1.0 ms of CPU instead
of about 0.45 ms (2 loaded cores; `bench/bench_rclpy_spin.py`), and tracking wakes several times per frame. A
QoS mismatch is reported at both ends, so a node that keeps the handlers on its subscriptions of external data
(camera images, camera_info) still warns when a driver offers incompatible QoS.

    class TrackingNode(QuietQosEvents, Node): ...
    node.create_subscription(Image, topic, cb, qos, event_callbacks=SubscriptionEventCallbacks())  # keep them
"""

from __future__ import annotations

from typing import Any

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks


class QuietQosEvents:
    """Mixin placed before `rclpy.node.Node` (or LifecycleNode) in the bases.

    Every publisher and subscription the node creates (including rclpy's own /parameter_events and /rosout ones
    and those of helpers given the node, e.g. nodes/diagnostics.py) gets no handlers unless `event_callbacks` is
    passed."""

    def create_publisher(self, *args: Any, **kwargs: Any) -> Any:
        kwargs.setdefault("event_callbacks", PublisherEventCallbacks(use_default_callbacks=False))
        return super().create_publisher(*args, **kwargs)  # type: ignore[misc]

    def create_subscription(self, *args: Any, **kwargs: Any) -> Any:
        kwargs.setdefault("event_callbacks", SubscriptionEventCallbacks(use_default_callbacks=False))
        return super().create_subscription(*args, **kwargs)  # type: ignore[misc]
