"""CPU seconds of the graph's processes while the bag plays (`changing-slam graph`'s graph_summary.json).

Wall-clock figures of a 1x run depend on whatever else shares the cores; CPU time per process does not (much):
it says where the graph's work goes and what it would need on an idle machine. A process's user + system time
(all its threads) comes from /proc/<pid>/stat; `PlayCpu` samples it when playback starts and again while the
player runs, so a node's figure is what it spent during playback, not its start-up (imports, ONNX session,
map loading) or its shutdown (writing files). A node restarted during playback counts the CPU of each of its
processes. Where /proc is missing (not Linux) every figure is None.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

_TICKS_PER_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process `pid` so far (all threads), or None when it is gone or unreadable."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            stat = f.read()
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2 :].split()  # after "pid (comm) ": state is field 3 of the man page
    try:
        return (int(fields[11]) + int(fields[12])) / _TICKS_PER_S  # utime, stime (fields 14 and 15)
    except (IndexError, ValueError):
        return None


@dataclass
class PlayCpu:
    """Per node name: CPU seconds spent since `start` (for processes seen then) or since the process began."""

    at_start: dict[int, float] = field(default_factory=dict)  # pid -> CPU s when playback started
    last: dict[int, float] = field(default_factory=dict)  # pid -> newest sample
    names: dict[int, str] = field(default_factory=dict)  # pid -> node name

    def start(self, pids: dict[str, int]) -> None:
        for name, pid in pids.items():
            cpu = process_cpu_s(pid)
            if cpu is not None:
                self.at_start[pid], self.last[pid], self.names[pid] = cpu, cpu, name

    def sample(self, pids: dict[str, int]) -> None:
        """Take a sample of every running node (call it while they run: an exited process cannot be read)."""
        for name, pid in pids.items():
            cpu = process_cpu_s(pid)
            if cpu is not None:
                self.last[pid], self.names[pid] = cpu, name

    def seconds(self) -> dict[str, float]:
        """Node name -> CPU seconds during playback (summed over restarts), rounded to 10 ms."""
        out: dict[str, float] = {}
        for pid, cpu in self.last.items():
            name = self.names[pid]
            out[name] = out.get(name, 0.0) + cpu - self.at_start.get(pid, 0.0)
        return {name: round(v, 2) for name, v in out.items()}


def per_frame_ms(seconds: dict[str, float], frames: int) -> dict[str, float]:
    """Process name (and `total`) -> CPU milliseconds per bag frame, from CPU seconds per process."""
    if frames <= 0 or not seconds:
        return {}
    out = {name: round(v * 1e3 / frames, 2) for name, v in seconds.items()}
    out["total"] = round(sum(seconds.values()) * 1e3 / frames, 2)
    return out


def play_cpu_summary(cpu: "PlayCpu", player_log: str, frames: int) -> dict[str, Any]:
    """graph_summary.json's CPU seconds per process during playback and per bag frame; the player's own figure for
    its play() (its log line) replaces the sampled one, which includes its start-up."""
    import re

    found = re.findall(r"messages in [0-9.]+ s \(CPU ([0-9.]+) s\)", player_log)
    sec = cpu.seconds()
    if found:
        sec["bag_player"] = float(found[-1])
    return {"cpu_s_during_play": sec, "cpu_ms_per_bag_frame": per_frame_ms(sec, frames)}
