"""The progress of a `changing-slam graph` run while it plays: frames played, received and posed, and the live
pose rate, from the bag player's and tracking's log lines.

On a terminal one line is rewritten in place about once a second; elsewhere (a log file, CI) a line is printed
every `LOG_PERIOD_S` seconds, so the log gets no more than that.
"""

from __future__ import annotations

import re
import sys
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from changing_slam_ros.commands.graph_process import NodeProcess

TTY_PERIOD_S = 1.0
LOG_PERIOD_S = 10.0
RATE_WINDOW_S = 3.0  # the live rate is over the last few seconds
# nodes/tracking_stats.py's counts line and io/playback.py's progress line
TRACKING_COUNTS = re.compile(r"tracking: (\d+) colour received, \d+ frames, .*?, (\d+) poses")
PLAYER_PROGRESS = re.compile(r"played \d+/\d+ messages, ([0-9.]+)/([0-9.]+) s of the bag")


@dataclass(frozen=True)
class Counts:
    """What the run has done so far: colour frames played (bag runs: from the player's position in the bag),
    received by tracking and posed."""

    played: int | None
    received: int
    posed: int


class LogTail:
    """The lines appended to a growing log file since the last call (a restarted node's new log followed)."""

    def __init__(self) -> None:
        self.path: Path | None = None
        self.offset = 0
        self._partial = ""

    def new_lines(self, path: Path | None) -> list[str]:
        if path is None:
            return []
        if path != self.path:
            self.path, self.offset, self._partial = path, 0, ""
        try:
            with open(path, "rb") as f:
                f.seek(self.offset)
                data = f.read()
        except OSError:
            return []
        self.offset += len(data)
        text = self._partial + data.decode(errors="replace")
        lines = text.split("\n")
        self._partial = lines.pop()
        return lines


def progress_line(counts: Counts, total: int, rate_hz: float | None) -> str:
    """`graph: played 120/450 frames, received 118, posed 117 (99 %), 29.6 poses/s`; live topics have no
    `played`, a bag without a known frame count no `/total`."""
    parts = []
    if counts.played is not None:
        parts.append(f"played {counts.played}/{total} frames" if total else f"played {counts.played} frames")
    parts.append(f"received {counts.received}")
    share = f" ({100.0 * counts.posed / counts.received:.0f} %)" if counts.received else ""
    parts.append(f"posed {counts.posed}{share}")
    parts.append(f"{rate_hz:.1f} poses/s" if rate_hz is not None else "-- poses/s")
    return "graph: " + ", ".join(parts)


class GraphProgress:
    """Reads the counts from the logs and shows them: `update(now)` from the supervising loop, `finish()` once."""

    def __init__(self, tracking: NodeProcess, player: NodeProcess | None, total_frames: int,
                 stream: TextIO | None = None) -> None:  # fmt: skip
        self.tracking, self.player, self.total = tracking, player, total_frames
        self.stream = stream if stream is not None else sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.period_s = TTY_PERIOD_S if self.tty else LOG_PERIOD_S
        self._tracking_tail, self._player_tail = LogTail(), LogTail()
        self.received = self.posed = 0
        self.played: int | None = 0 if player is not None else None
        self._history: deque[tuple[float, int]] = deque()  # (time, posed)
        self._last_shown_s: float | None = None
        self._line_open = False  # a tty line written without its newline

    def counts(self) -> Counts:
        for line in self._tracking_tail.new_lines(self.tracking.log_path):
            m = TRACKING_COUNTS.search(line)
            if m:
                self.received, self.posed = int(m.group(1)), int(m.group(2))
        if self.player is not None:
            for line in self._player_tail.new_lines(self.player.log_path):
                m = PLAYER_PROGRESS.search(line)
                if m and float(m.group(2)) > 0:
                    self.played = round(self.total * float(m.group(1)) / float(m.group(2)))
        return Counts(self.played, self.received, self.posed)

    def rate_hz(self, now: float, posed: int) -> float | None:
        """Poses per second over the last RATE_WINDOW_S (None until two samples span a second)."""
        self._history.append((now, posed))
        while len(self._history) > 2 and now - self._history[1][0] >= RATE_WINDOW_S:
            self._history.popleft()
        t0, p0 = self._history[0]
        return (posed - p0) / (now - t0) if now - t0 >= 1.0 else None

    def update(self, now: float) -> None:
        counts = self.counts()
        rate = self.rate_hz(now, counts.posed)
        if self._last_shown_s is not None and now - self._last_shown_s < self.period_s:
            return
        self._last_shown_s = now
        line = progress_line(counts, self.total, rate)
        if self.tty:
            self.stream.write("\r\033[K" + line)
            self._line_open = True
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def finish(self) -> None:
        """Ends the tty line, so that what is printed next starts on a line of its own."""
        if self._line_open:
            self.stream.write("\n")
            self.stream.flush()
            self._line_open = False
