"""The tracking node's detection inputs: which detections a frame waits for, and boxes carried forward.

A frame's detections are settled when they are in, when the detector announced on /detection/skipped that it
will not detect the image, or when it has published detections of a later image. Frames tracked without their
own detections take the newest earlier boxes carried forward (`core.dynamic.late_detections`).
Mixed into `TrackingNode`, whose `__init__` sets the state these methods use.
"""

from __future__ import annotations

import time
from typing import Any

from changing_slam_msgs.msg import DetectionArray
from std_msgs.msg import Header

from changing_slam_ros.nodes.conversions import detections_from_msg, stamp_to_ns
from changing_slam_ros.nodes.keep_newest import keep_newest as _keep_newest


class DetectionInputs:
    """Methods of `TrackingNode` (see the module docstring)."""

    def on_detections(self, msg: DetectionArray) -> None:
        ds = detections_from_msg(msg)
        self._detections_seen = True
        self.detections_in += 1
        received = (self._received_s.get(ds.stamp_ns) or self._processed_received_s.get(ds.stamp_ns)
                    or self.queue.received_s(ds.stamp_ns))  # fmt: skip
        if received is not None:  # also for frames tracked already: how late detections come
            delay_ms = (time.monotonic() - received) * 1e3
            self.detection_delay_ms.append(delay_ms)
            self._recent_delays_ms.append(delay_ms)
        self.detections[ds.stamp_ns] = ds
        self._last_detected_ns = ds.stamp_ns
        if self._newest_detections is None or ds.stamp_ns > self._newest_detections.stamp_ns:
            self._previous_detections, self._newest_detections = self._newest_detections, ds
        _keep_newest(self.detections, 30)
        if self.backend is not None and self.backend.system.refinement is not None:
            # tracking.deferred_refinement: the frames tracked before these detections came get their final pose
            # refined (core.deferred_refinement); the published poses stay
            self.backend.system.refine_with_detections(ds)
        self._drain()

    def _detections_settled(self, stamp_ns: int) -> bool:
        """A frame's detections are in, or none will come: the detector announced it skips the image, or it has
        published detections of a later image (it works through images in order and never goes back)."""
        last = self._last_detected_ns
        return stamp_ns in self.detections or stamp_ns in self._skipped or (last is not None and stamp_ns < last)

    def on_detections_skipped(self, msg: Header) -> None:
        """The detector will not detect this image (its rate cap, or it rejected it): its frame stops waiting."""
        self.detections_skipped_in += 1
        self._skipped[stamp_to_ns(msg.stamp)] = None
        _keep_newest(self._skipped, 30)
        self._drain()

    def _carried_detections(self, stamp_ns: int) -> Any:
        """The newest earlier detections for a frame that has none of its own (`core.late_detections`), or None."""
        from changing_slam_ros.core.dynamic.late_detections import carried_forward

        if self._newest_detections is None or self._carry.max_age_s <= 0:
            return None
        c0 = time.process_time()
        images = None
        if self._carry.flow:
            before = self._recent_images.get(self._newest_detections.stamp_ns)
            after = self._recent_images.get(stamp_ns)
            images = (before, after) if before is not None and after is not None else None
        carried = carried_forward(self._newest_detections, stamp_ns, self._carry, self._previous_detections, images)
        if carried is not None:
            self.frames_with_carried_detections += 1
            self.carry_cpu_ms.append((time.process_time() - c0) * 1e3)
        return carried

    def _detections_hopelessly_late(self, wait_s: float) -> bool:
        """detections_skip_late: the last `detections_late_window` detections all came after `wait_s`."""
        d = self._recent_delays_ms
        return bool(self.params["detections_skip_late"] and len(d) == d.maxlen and min(d) > wait_s * 1e3)

    def _wait_for_detections(self) -> bool:
        return (self.backend is not None and self.backend.wants_detections
                and (self._detections_seen or self.params["detections_required"]))  # fmt: skip
