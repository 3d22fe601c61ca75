"""Per-node diagnostics: latency and drop counts as `diagnostic_msgs/DiagnosticArray` on /diagnostics, and logged.

    diag = NodeDiagnostics(node, period_s=5.0)          # publishes on a steady timer
    diag.set_source(lambda: {"latency_ms_median": 42.0, "dropped": 3})

The log gets the same figures when they changed since the last line. Each report is one DiagnosticStatus named `<node name>` (hardware_id `changing_slam`), level OK, or WARN when a
`warn_if` predicate on the values holds (e.g. latency over target, drops). Values are written as strings
(DiagnosticStatus carries KeyValue strings only).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node


def summarise_ms(values: list[float] | np.ndarray, prefix: str) -> dict[str, float | None]:
    """`<prefix>_ms_median`, `<prefix>_ms_p90`, `<prefix>_ms_max` of a list of milliseconds (None when empty)."""
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {f"{prefix}_ms_median": None, f"{prefix}_ms_p90": None, f"{prefix}_ms_max": None}
    return {f"{prefix}_ms_median": float(np.median(a)), f"{prefix}_ms_p90": float(np.percentile(a, 90)),
            f"{prefix}_ms_max": float(a.max())}  # fmt: skip


def _text(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.2f}"
    return str(v)


class NodeDiagnostics:
    """Publishes the node's figures every `period_s` (steady clock) on /diagnostics and logs them."""

    def __init__(self, node: Node, period_s: float, log: bool = True,
                 warn_if: Callable[[Mapping[str, Any]], str | None] | None = None) -> None:  # fmt: skip
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.source: Callable[[], Mapping[str, Any]] = dict
        self.log = log
        self.warn_if = warn_if
        self.n_published = 0
        self._last_logged = ""
        if period_s > 0:
            node.create_timer(period_s, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def set_source(self, source: Callable[[], Mapping[str, Any]]) -> None:
        self.source = source

    def status(self) -> DiagnosticStatus:
        values = dict(self.source())
        warning = self.warn_if(values) if self.warn_if is not None else None
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN if warning else DiagnosticStatus.OK, name=self.node.get_name(),
            message=warning or "ok", hardware_id="changing_slam",
            values=[KeyValue(key=str(k), value=_text(v)) for k, v in values.items()],
        )  # fmt: skip

    def publish(self) -> DiagnosticStatus:
        st = self.status()
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(msg)
        self.n_published += 1
        text = ", ".join(f"{kv.key} {kv.value}" for kv in st.values)
        if self.log and text != self._last_logged:  # the log gets a line when something changed
            self._last_logged = text
            self.node.get_logger().info(f"{self.node.get_name()}: diagnostics: {text}")
        return st
