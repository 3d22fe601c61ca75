"""CPU time of one rclpy executor wake-up, with and without the default QoS-event handlers.

    .venv/bin/python bench/bench_rclpy_spin.py [--publishers 12] [--subscriptions 8] [--seconds 1.5]

A node with N publishers and M subscriptions (std_msgs/Header, nothing sent) and a 1 ms timer is spun by a
SingleThreadedExecutor; each spin_once is one wake-up (wait set built, waited, the timer's callback run).
Prints the process CPU time per spin for: a bare node, the node with rclpy's default event handlers (two per
publisher and subscription), and without them (`nodes/qos_events.py`). CPU time, not wall time: the machine
may be shared.
"""

from __future__ import annotations

import argparse
import time


def spin_cpu_ms(n_pub: int, n_sub: int, default_events: bool, seconds: float) -> tuple[int, float]:
    """(waitables of the node, CPU ms per spin_once)."""
    import rclpy
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Header

    node = rclpy.create_node("bench_spin", start_parameter_services=False)
    pub_kw = {} if default_events else {"event_callbacks": PublisherEventCallbacks(use_default_callbacks=False)}
    sub_kw = {} if default_events else {"event_callbacks": SubscriptionEventCallbacks(use_default_callbacks=False)}
    for i in range(n_pub):
        node.create_publisher(Header, f"bench_pub_{i}", 10, **pub_kw)
    for i in range(n_sub):
        node.create_subscription(Header, f"bench_sub_{i}", lambda msg: None, 10, **sub_kw)
    node.create_timer(0.001, lambda: None)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        for _ in range(50):  # warm-up
            executor.spin_once(timeout_sec=0.1)
        c0, w0, spins = time.process_time(), time.perf_counter(), 0
        while time.perf_counter() - w0 < seconds:
            executor.spin_once(timeout_sec=0.1)
            spins += 1
        return len(list(node.waitables)), 1e3 * (time.process_time() - c0) / spins
    finally:
        executor.shutdown()
        node.destroy_node()


def main() -> None:
    import rclpy

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--publishers", type=int, default=12)
    parser.add_argument("--subscriptions", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=1.5)
    a = parser.parse_args()
    rclpy.init()
    try:
        for label, n_pub, n_sub, default in (
            ("bare node", 0, 0, True),
            ("default event handlers", a.publishers, a.subscriptions, True),
            ("no event handlers", a.publishers, a.subscriptions, False),
        ):
            waitables, ms = spin_cpu_ms(n_pub, n_sub, default, a.seconds)
            print(f"{label:24s} {n_pub:3d} pub {n_sub:3d} sub  {waitables:3d} waitables  {ms:.3f} CPU ms per spin")
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
