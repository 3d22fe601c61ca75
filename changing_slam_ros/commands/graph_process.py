"""One node process of `changing-slam graph`: its command line, start, log, restarts and stop."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class NodeProcess:
    """One node of the graph: its command, the running process and its restarts."""

    name: str
    argv: list[str]
    log_dir: Path
    starts: int = 0
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None
    exit_codes: list[int] = field(default_factory=list)
    restart_argv: list[str] | None = None  # the command of a restart, when it differs from the first start's
    nice: int = 0  # niceness added to the process (and all its threads) before it starts

    def start(self, env: dict[str, str]) -> None:
        suffix = "" if self.starts == 0 else f".{self.starts}"
        self.log_path = self.log_dir / f"{self.name}{suffix}.log"
        argv = self.restart_argv if self.starts > 0 and self.restart_argv is not None else self.argv
        log = open(self.log_path, "wb")  # noqa: SIM115 - the child keeps writing it
        try:
            increment = self.nice
            self.proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                                         preexec_fn=(lambda: os.nice(increment)) if increment else None)  # fmt: skip
        finally:
            log.close()
        self.starts += 1

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def log_text(self) -> str:
        try:
            return self.log_path.read_text(errors="replace") if self.log_path else ""
        except OSError:
            return ""

    def stop(self, sig: int, wait_s: float) -> int | None:
        """Send `sig`, wait up to `wait_s`; returns the exit code or None while it still runs."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(wait_s)
            except subprocess.TimeoutExpired:
                return None
        return self.proc.returncode


def python_argv() -> list[str]:
    """The interpreter command of a node process: `-P` keeps the current folder off `sys.path`, so a module
    planted where `changing-slam graph` is run (an `evil.py` beside a bag) is never imported by a node."""
    return [sys.executable, "-P"]


def child_env(env: dict[str, str]) -> dict[str, str]:
    """`env` for node processes: PYTHONSAFEPATH=1 (the current folder off `sys.path` of any Python they start
    too) and this package's own root first on PYTHONPATH, so the nodes run the code the graph runs."""
    import changing_slam_ros

    root = str(Path(changing_slam_ros.__file__).resolve().parent.parent)
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    return dict(env, PYTHONSAFEPATH="1", PYTHONPATH=os.pathsep.join([root, *(p for p in paths if p != root)]))


def node_argv(module: str, params: dict[str, Any], remaps: dict[str, str] | None = None,
               positional: list[str] | None = None) -> list[str]:  # fmt: skip
    argv = [*python_argv(), "-m", f"changing_slam_ros.nodes.{module}", *(positional or []), "--ros-args"]
    for key, value in params.items():
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, list):
            text = "[" + ", ".join(f"'{v}'" for v in value) + "]"
        elif isinstance(value, str):
            text = f"'{value}'"  # YAML string, also for values that look like numbers or are empty
        else:
            text = str(value)
        argv += ["-p", f"{key}:={text}"]
    for src, dst in (remaps or {}).items():
        argv += ["-r", f"{src}:={dst}"]
    return argv
