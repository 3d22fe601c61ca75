"""Playback timing without ROS (io/playback.py): schedule, rate, offset, pauses, looping, remapping."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from types import SimpleNamespace

import pytest

from changing_slam_ros.errors import BagError, ConfigError
from changing_slam_ros.io.bag_messages import RawMessage
from changing_slam_ros.io.playback import (
    PlaybackClock,
    PlaybackOptions,
    PlaybackProgress,
    first_bag_ns,
    parse_remaps,
    pass_period_ns,
    plan,
    resume_bag_ns,
)

S = 1_000_000_000
T0 = 1305031102 * S  # a TUM-like start time


class FakeBag:
    """Messages at given log times (ns) on given topics, with the reader's filtering semantics."""

    def __init__(self, items: Sequence[tuple[str, int]]) -> None:
        self.items = [RawMessage(topic, "std_msgs/msg/Header", t, t, b"") for topic, t in items]
        self.calls = 0

    @property
    def start_ns(self) -> int:
        return min(m.log_stamp_ns for m in self.items)

    @property
    def end_ns(self) -> int:
        return max(m.log_stamp_ns for m in self.items)

    @property
    def topics(self) -> dict[str, SimpleNamespace]:
        names = [m.topic for m in self.items]
        return {t: SimpleNamespace(msgcount=names.count(t)) for t in names}

    def messages(self, topics=None, start_ns=None, stop_ns=None) -> Iterator[RawMessage]:  # noqa: ANN001
        self.calls += 1
        for m in sorted(self.items, key=lambda m: m.log_stamp_ns):
            if topics is not None and m.topic not in topics:
                continue
            if start_ns is not None and m.log_stamp_ns < start_ns:
                continue
            yield m


def test_messages_are_due_at_their_recorded_spacing_divided_by_the_rate():
    clock = PlaybackClock(rate=2.0, anchor_bag_ns=T0, anchor_wall_ns=500)
    assert clock.due_wall_ns(T0) == 500
    assert clock.due_wall_ns(T0 + S) == 500 + S // 2  # 1 s of bag at 2x = 0.5 s of wall time
    assert clock.wait_ns(T0 + S, wall_now_ns=500 + S // 4) == S // 4
    assert clock.wait_ns(T0 + S, wall_now_ns=500 + S) == 0  # late: publish at once


def test_a_pause_shifts_the_schedule_so_playback_resumes_at_the_recorded_spacing():
    clock = PlaybackClock(rate=1.0, anchor_bag_ns=T0, anchor_wall_ns=0)
    clock.pause(3 * S)  # lossless mode waited 3 s for a slow subscriber
    assert clock.due_wall_ns(T0 + S) == 4 * S
    assert clock.bag_now_ns(wall_now_ns=3 * S + S // 2) == T0 + S // 2


def test_clock_time_follows_the_wall_clock_times_the_rate_and_never_goes_behind_a_sent_message():
    clock = PlaybackClock(rate=0.5, anchor_bag_ns=T0, anchor_wall_ns=0)
    assert clock.bag_now_ns(2 * S) == T0 + S
    clock.mark_published(T0 + 5 * S)  # published late (e.g. a burst)
    assert clock.bag_now_ns(2 * S) == T0 + 5 * S


def test_start_offset_skips_the_first_seconds_and_anchors_the_schedule_there():
    bag = FakeBag([("/a", T0 + i * S // 10) for i in range(30)])  # 10 Hz for 3 s
    opts = PlaybackOptions(start_offset_s=1.0)
    assert first_bag_ns(bag, opts) == T0 + S
    played = [p.msg.log_stamp_ns for p in plan(bag, opts)]
    assert played[0] == T0 + S and len(played) == 20


def test_loop_replays_the_messages_pass_after_pass_each_pass_later_by_the_bags_duration_and_one_frame():
    bag = FakeBag([("/a", T0), ("/b", T0 + S), ("/a", T0 + 2 * S)])
    assert pass_period_ns(bag, PlaybackOptions(loop=True)) == 2 * S + 2 * S  # span 2 s, /a every 2 s
    items = list(plan(bag, PlaybackOptions(loop=True), max_passes=3))
    assert [p.pass_index for p in items] == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert [p.msg.topic for p in items[3:6]] == ["/a", "/b", "/a"]
    assert bag.calls == 3
    stamps = [p.msg.log_stamp_ns for p in items]
    assert stamps == [T0 + k * 4 * S + t for k in range(3) for t in (0, S, 2 * S)]  # time keeps running forward
    assert [p.msg.header_stamp_ns for p in items] == stamps and [p.shift_ns for p in items[3:4]] == [4 * S]
    assert len(list(plan(bag, PlaybackOptions(loop=True, loop_passes=2)))) == 6  # then playback ends


def test_a_resumed_playback_starts_in_its_pass_at_its_point_and_plays_the_later_passes_whole():
    bag = FakeBag([("/a", T0 + i * S // 10) for i in range(10)])  # 10 Hz for 0.9 s: a pass every second
    opts = PlaybackOptions(loop=True, loop_passes=3, first_pass=1, resume_at_s=0.55)
    items = list(plan(bag, opts))
    assert [p.pass_index for p in items] == [1] * 4 + [2] * 10
    assert items[0].msg.log_stamp_ns == T0 + S + 6 * S // 10 == resume_bag_ns(bag, opts) + S // 20
    assert resume_bag_ns(bag, PlaybackOptions()) == T0
    with pytest.raises(ConfigError, match="first_pass 1 needs loop:=true"):
        PlaybackOptions(first_pass=1)
    with pytest.raises(ConfigError, match="first_pass 3 is not before loop_passes 3"):
        PlaybackOptions(loop=True, loop_passes=3, first_pass=3)


def test_a_shifted_message_has_its_header_stamp_rewritten_in_the_cdr_bytes():
    from rosbags.typesys import Stores, get_typestore

    from changing_slam_ros.io.bag_messages import _cdr_header_stamp_ns, with_stamps_shifted

    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](1305031102, 900_000_000), "camera")
    cdr = bytes(store.serialize_cdr(header, "std_msgs/msg/Header"))
    msg = RawMessage("/h", "std_msgs/msg/Header", T0, 1305031102_900_000_000, cdr)
    moved = with_stamps_shifted(msg, 1_250_000_000)
    assert moved.header_stamp_ns == _cdr_header_stamp_ns(moved.cdr) == 1305031104_150_000_000
    back = store.deserialize_cdr(moved.cdr, "std_msgs/msg/Header")
    assert (back.stamp.sec, back.stamp.nanosec, back.frame_id) == (1305031104, 150_000_000, "camera")
    assert moved.log_stamp_ns == T0 + 1_250_000_000 and with_stamps_shifted(msg, 0) is msg


def test_topic_filter_and_remaps_choose_what_is_played_and_under_which_name():
    bag = FakeBag([("/camera/rgb/image_color", T0), ("/tf", T0 + 1), ("/camera/depth/image", T0 + 2)])
    opts = PlaybackOptions(
        topics=("/camera/rgb/image_color", "/camera/depth/image"),
        remap=parse_remaps(["/camera/rgb/image_color:=/image", " /camera/depth/image := /depth "]),
    )
    assert [(p.msg.topic, p.topic) for p in plan(bag, opts)] == [
        ("/camera/rgb/image_color", "/image"),
        ("/camera/depth/image", "/depth"),
    ]


def test_bad_options_are_rejected_with_the_offending_value():
    with pytest.raises(ConfigError, match="rate must be > 0, got 0.0"):
        PlaybackOptions(rate=0.0)
    with pytest.raises(ConfigError, match="start_offset_s must be >= 0"):
        PlaybackOptions(start_offset_s=-1.0)
    with pytest.raises(ConfigError, match="'/a=/b' is not of the form"):
        parse_remaps(["/a=/b"])
    bag = FakeBag([("/a", T0), ("/a", T0 + S)])
    with pytest.raises(BagError, match="start offset 5.0 s is past the bag's end \\(1.000 s\\)"):
        list(plan(bag, PlaybackOptions(start_offset_s=5.0)))
    with pytest.raises(BagError, match="nothing to play .* on topics /nope"):
        list(plan(bag, PlaybackOptions(topics=("/nope",))))


def test_progress_reports_counts_and_fraction_once_per_period():
    progress = PlaybackProgress(total_messages=300, span_ns=10 * S, period_ns=2 * S)
    assert progress.due(0) and not progress.due(S) and progress.due(2 * S)
    for _ in range(120):
        progress.record("/a")
    assert progress.line(0, 4 * S) == "played 120/300 messages, 4.00/10.00 s of the bag (40 %)"
    assert progress.line(2, 4 * S).startswith("pass 3: ")
