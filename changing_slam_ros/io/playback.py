"""Bag playback timing, ROS-free: which message goes out when, under which topic name.

`bag_player` (nodes/bag_player_node.py) publishes; this module decides. A message recorded at log time
`t_bag` is due at wall time

    t_wall = anchor_wall + (t_bag - anchor_bag) / rate

where the anchor is (bag start + start offset, the wall time playback started). A pause (lossless mode
waiting for subscribers) shifts `anchor_wall` by the time waited, so playback resumes at the recorded
spacing instead of bursting to catch up. Looping, pass k plays every message `k x pass_period_ns` later, its
header stamp rewritten alike (`pass_period_ns`), so that time keeps running forward across passes. The simulated time published on `/clock` at wall time `w` is
`anchor_bag + (w - anchor_wall) * rate`, never behind the last message published.

All times are integer nanoseconds; wall times come from a monotonic clock the caller passes in.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from changing_slam_ros.errors import BagError, ConfigError
from changing_slam_ros.io.bag_messages import RawMessage, with_stamps_shifted

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class PlaybackOptions:
    """What to play and how fast.

    - `rate`: playback speed factor (2.0 = twice as fast as recorded), > 0.
    - `start_offset_s`: seconds of the bag skipped at the start (from the bag's first message), >= 0.
    - `loop`: play again from the offset after the end, each pass shifted in time, until stopped.
    - `loop_passes`: with `loop`, how many passes in all (0 = until stopped).
    - `topics`: bag topics to play; empty = all.
    - `remap`: (bag topic, published topic) pairs; other topics keep their names.
    - `first_pass`, `resume_at_s`: where a restarted player resumes: that pass (0-based, its messages shifted
      as that pass's), that many seconds after the offset; later passes start at the offset again.
    """

    rate: float = 1.0
    start_offset_s: float = 0.0
    loop: bool = False
    topics: tuple[str, ...] = ()
    remap: tuple[tuple[str, str], ...] = ()
    loop_passes: int = 0
    first_pass: int = 0
    resume_at_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.rate > 0.0:
            raise ConfigError(f"bag_player: rate must be > 0, got {self.rate}")
        for name in ("start_offset_s", "resume_at_s", "loop_passes", "first_pass"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"bag_player: {name} must be >= 0, got {getattr(self, name)}")
        if self.first_pass and not self.loop:
            raise ConfigError(f"bag_player: first_pass {self.first_pass} needs loop:=true")
        if self.loop and self.loop_passes and self.first_pass >= self.loop_passes:
            raise ConfigError(f"bag_player: first_pass {self.first_pass} is not before loop_passes {self.loop_passes}")

    def output_topic(self, bag_topic: str) -> str:
        """The name `bag_topic` is published under."""
        return dict(self.remap).get(bag_topic, bag_topic)


def parse_remaps(rules: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """Parse `from:=to` rules (the ROS remap syntax) into pairs; ConfigError names a malformed rule."""
    pairs = []
    for rule in rules:
        src, sep, dst = rule.partition(":=")
        if not sep or not src.strip() or not dst.strip():
            raise ConfigError(f"bag_player: remap rule {rule!r} is not of the form '/from:=/to'")
        pairs.append((src.strip(), dst.strip()))
    return tuple(pairs)


class PlaybackClock:
    """Bag time <-> wall time at a rate, with pauses; see the module docstring."""

    def __init__(self, rate: float, anchor_bag_ns: int, anchor_wall_ns: int) -> None:
        if not rate > 0.0:
            raise ConfigError(f"bag_player: rate must be > 0, got {rate}")
        self.rate = rate
        self.anchor_bag_ns = anchor_bag_ns
        self.anchor_wall_ns = anchor_wall_ns
        self._last_published_bag_ns = anchor_bag_ns

    def due_wall_ns(self, bag_ns: int) -> int:
        """Wall time at which the message logged at `bag_ns` is due."""
        return self.anchor_wall_ns + round((bag_ns - self.anchor_bag_ns) / self.rate)

    def wait_ns(self, bag_ns: int, wall_now_ns: int) -> int:
        """Nanoseconds to wait before publishing `bag_ns` (0 when late)."""
        return max(0, self.due_wall_ns(bag_ns) - wall_now_ns)

    def bag_now_ns(self, wall_now_ns: int) -> int:
        """Simulated time for `/clock`: follows the wall clock, never behind the last message sent."""
        t = self.anchor_bag_ns + round((wall_now_ns - self.anchor_wall_ns) * self.rate)
        return max(t, self._last_published_bag_ns)

    def mark_published(self, bag_ns: int) -> None:
        self._last_published_bag_ns = max(self._last_published_bag_ns, bag_ns)

    def pause(self, waited_wall_ns: int) -> None:
        """Account for `waited_wall_ns` of waiting: later messages keep their recorded spacing."""
        self.anchor_wall_ns += max(0, waited_wall_ns)


class MessageSource(Protocol):
    """What playback needs of a bag (`io.bag_messages.BagMessages` provides it)."""

    @property
    def start_ns(self) -> int: ...

    @property
    def end_ns(self) -> int: ...

    @property
    def topics(self) -> Mapping[str, Any]: ...  # name -> connection with `msgcount`

    def messages(
        self,
        topics: Sequence[str] | None = None,
        start_ns: int | None = None,
        stop_ns: int | None = None,
    ) -> Iterator[RawMessage]: ...


@dataclass(frozen=True)
class PlannedMessage:
    """One message to publish: its pass (0-based, > 0 when looping), output topic, and the message with its log
    time and header stamp shifted by `shift_ns` (the pass's, 0 in the first)."""

    pass_index: int
    topic: str
    msg: RawMessage
    shift_ns: int = 0


def first_bag_ns(bag: MessageSource, options: PlaybackOptions) -> int:
    """Log time a pass starts at: the bag's first message plus the start offset."""
    return bag.start_ns + round(options.start_offset_s * NS_PER_S)


def pass_period_ns(bag: MessageSource, options: PlaybackOptions) -> int:
    """How much later each pass of a loop plays: the span from the offset to the bag's end plus one period of the
    bag's most frequent topic, so that a pass's first frame follows the previous pass's last at the recorded
    spacing and no stamp repeats (at least 1 ms)."""
    counts = [int(c.msgcount) for c in bag.topics.values()]
    busiest = max(counts, default=0)
    gap = (bag.end_ns - bag.start_ns) // (busiest - 1) if busiest > 1 else 0
    return bag.end_ns - first_bag_ns(bag, options) + max(gap, 1_000_000)


def resume_bag_ns(bag: MessageSource, options: PlaybackOptions) -> int:
    """Log time (shifted) of the first message this playback plays: its first pass at its resume point."""
    return (first_bag_ns(bag, options) + options.first_pass * pass_period_ns(bag, options)
            + round(options.resume_at_s * NS_PER_S))  # fmt: skip


def plan(bag: MessageSource, options: PlaybackOptions, max_passes: int | None = None) -> Iterator[PlannedMessage]:
    """Messages in log-time order from the offset on, pass after pass when looping, each pass shifted by
    `pass_period_ns` more; from `first_pass` at `resume_at_s` for a resumed player.

    Raises BagError when the offset lies past the bag's end or a pass yields nothing (so a loop never spins
    empty). `max_passes` bounds the passes in all, counted from pass 0 (None = `loop_passes`, forever when 0
    and `options.loop`, else 1).
    """
    start = first_bag_ns(bag, options)
    if start > bag.end_ns:
        span_s = (bag.end_ns - bag.start_ns) / NS_PER_S
        raise BagError(f"bag_player: start offset {options.start_offset_s} s is past the bag's end ({span_s:.3f} s)")
    topics = list(options.topics) or None
    if max_passes is not None:
        passes: int | None = max_passes
    else:
        passes = (options.loop_passes or None) if options.loop else 1
    period = pass_period_ns(bag, options) if options.loop else 0
    index = options.first_pass
    while passes is None or index < passes:
        count = 0
        resume = start + round(options.resume_at_s * NS_PER_S) if index == options.first_pass else start
        for msg in bag.messages(topics=topics, start_ns=resume):
            count += 1
            yield PlannedMessage(index, options.output_topic(msg.topic), with_stamps_shifted(msg, index * period),
                                 index * period)  # fmt: skip
        if count == 0 and resume == start:
            raise BagError(
                f"bag_player: nothing to play from {options.start_offset_s} s on"
                + (f" on topics {', '.join(options.topics)}" if options.topics else "")
            )
        index += 1


@dataclass
class PlaybackProgress:
    """Counts what was published and says when to log a progress line."""

    total_messages: int
    span_ns: int
    period_ns: int
    published: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    _last_log_wall_ns: int | None = None

    def record(self, topic: str) -> None:
        self.published += 1
        self.per_topic[topic] = self.per_topic.get(topic, 0) + 1

    def due(self, wall_now_ns: int) -> bool:
        """True once per `period_ns` of wall time (and at the first call)."""
        if self._last_log_wall_ns is None or wall_now_ns - self._last_log_wall_ns >= self.period_ns:
            self._last_log_wall_ns = wall_now_ns
            return True
        return False

    def line(self, pass_index: int, elapsed_bag_ns: int) -> str:
        """`played 120/300 messages, 4.00/10.00 s of the bag (40 %)` (+ the pass when looping)."""
        pct = 100.0 * elapsed_bag_ns / self.span_ns if self.span_ns > 0 else 100.0
        head = f"pass {pass_index + 1}: " if pass_index else ""
        return (
            f"{head}played {self.published}/{self.total_messages} messages, "
            f"{elapsed_bag_ns / NS_PER_S:.2f}/{self.span_ns / NS_PER_S:.2f} s of the bag ({pct:.0f} %)"
        )
