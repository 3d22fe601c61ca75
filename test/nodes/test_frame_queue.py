"""nodes/frame_queue.py: which waiting frames the tracking node tracks, drops or waits for (no ROS needed)."""

import pytest

from changing_slam_ros.errors import SlamError
from changing_slam_ros.nodes.frame_queue import FrameQueue, PendingFrame


def frames(deadlines_s: list[float]) -> list[PendingFrame]:
    return [PendingFrame(stamp_ns=k, rgb_msg=f"rgb{k}", depth_msg=f"d{k}", received_s=0.0, deadline_s=t)
            for k, t in enumerate(deadlines_s)]  # fmt: skip


@pytest.mark.parametrize("policy", ["all", "latest"])
def test_the_head_waits_for_its_detections_or_deadline_and_blocks_the_frames_behind_it(policy: str) -> None:
    detections: set[int] = {1}
    q = FrameQueue(policy, detections.__contains__)
    for f in frames([10.0, 10.0, 10.0]):
        q.push(f)
    assert q.next_deadline_s() == 10.0 and q.received_s(2) == 0.0 and q.received_s(7) is None
    if policy == "all":
        assert q.take_stale(5.0) == [] and q.pop_ready(5.0) is None  # frame 1 is ready, frame 0 is not
        detections.add(0)
        assert [q.pop_ready(5.0).stamp_ns, q.pop_ready(5.0).stamp_ns] == [0, 1]  # type: ignore[union-attr]
        assert q.pop_ready(9.9) is None and q.pop_ready(10.0).stamp_ns == 2  # type: ignore[union-attr]
        assert len(q) == 0 and q.next_deadline_s() is None
    else:
        assert q.take_stale(5.0) == [] and q.pop_ready(5.0) is None  # frame 0 is within its wait: kept, it blocks
        assert [f.stamp_ns for f in q.take_stale(10.0)] == [0, 1]  # deadlines passed, older than the newest ready (2)
        assert q.pop_ready(10.0).stamp_ns == 2 and len(q) == 0  # type: ignore[union-attr]


def test_latest_drops_everything_before_a_frame_whose_deadline_passed() -> None:
    q = FrameQueue("latest", lambda stamp_ns: False)
    for f in frames([1.0, 2.0, 3.0, 9.0]):
        q.push(f)
    assert q.take_stale(0.5) == []  # nothing ready: nothing dropped
    assert [f.stamp_ns for f in q.take_stale(3.0)] == [0, 1]  # frame 2 is ready (3.0 s), so 0 and 1 go
    assert q.pop_ready(3.0).stamp_ns == 2 and q.pop_ready(3.0) is None  # type: ignore[union-attr]
    assert q.next_deadline_s() == 9.0 and q.pop().stamp_ns == 3 and q.next_deadline_s() is None


def test_an_unknown_policy_is_an_error_naming_the_parameter() -> None:
    with pytest.raises(SlamError, match="frame_policy: 'newest' unknown"):
        FrameQueue("newest", lambda stamp_ns: False)


def test_latest_keeps_a_frame_still_within_its_detection_wait_when_a_later_skipped_frame_is_ready() -> None:
    """Detector capped at half the camera rate: frame 0 (received at 0 s) waits for its own detections, frame 1
    (0.033 s) was skipped by the detector, so it is ready at once. Before its deadline (the 50 ms detection wait)
    frame 0 is kept and frame 1 waits behind it; once frame 0 has waited that long it is dropped as before."""
    detections: set[int] = {1}  # frame 1: skipped (announced), ready
    q = FrameQueue("latest", detections.__contains__)
    for k, (received, deadline) in enumerate([(0.0, 0.05), (0.033, 0.083)]):
        q.push(PendingFrame(stamp_ns=k, rgb_msg=k, depth_msg=k, received_s=received, deadline_s=deadline))
    assert q.take_stale(0.04) == [] and q.pop_ready(0.04) is None  # frame 0 is 40 ms old: kept, and it blocks
    detections.add(0)  # its detections arrive at 45 ms
    assert q.take_stale(0.045) == []  # both ready, but frame 0's deadline (50 ms) has not passed
    assert [q.pop_ready(0.045).stamp_ns, q.pop_ready(0.045).stamp_ns] == [0, 1]  # type: ignore[union-attr]
    q2 = FrameQueue("latest", {1}.__contains__)  # frame 0's detections never come
    for k, (received, deadline) in enumerate([(0.0, 0.05), (0.033, 0.083)]):
        q2.push(PendingFrame(stamp_ns=k, rgb_msg=k, depth_msg=k, received_s=received, deadline_s=deadline))
    assert [f.stamp_ns for f in q2.take_stale(0.05)] == [0]  # waited its full 50 ms: the newer ready frame wins
    assert q2.pop_ready(0.05).stamp_ns == 1  # type: ignore[union-attr]
