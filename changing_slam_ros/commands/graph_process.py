"""One node process of `changing-slam graph`: its command line, start, log, restarts and stop."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import SlamError


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

    def start(self, env: dict[str, str], fresh: bool = False) -> None:
        """Start the process (`restart_argv` for a restart unless `fresh`: as at the first start)."""
        suffix = "" if self.starts == 0 else f".{self.starts}"
        self.log_path = self.log_dir / f"{self.name}{suffix}.log"
        argv = self.restart_argv if self.starts > 0 and self.restart_argv is not None and not fresh else self.argv
        log = open(self.log_path, "wb")  # noqa: SIM115 - the child keeps writing it
        try:
            increment = self.nice

            def before_exec() -> None:
                _stop_with_parent()
                # SIGINT asks a node to write its outputs and stop: a graph started in the background of a shell
                # (where SIGINT is ignored and the ignore is inherited) must still be able to send it
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                if increment:
                    os.nice(increment)

            self.proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                                         preexec_fn=before_exec)  # fmt: skip
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

    def last_lines(self, n: int = 12) -> list[str]:
        """The last `n` non-empty lines of the current log (what a node printed before it died)."""
        return [ln for ln in self.log_text().splitlines() if ln.strip()][-n:]

    def failure(self) -> str:
        """The error a dead node ended with: the last line of a Python traceback or an `error:` line; "" if none."""
        lines = self.last_lines(40)
        for ln in reversed(lines):
            text = ln.strip()
            if text.startswith("error:") or (": " in text and text.split(":", 1)[0].endswith(("Error", "error",
                                                                                               "Exception"))):
                return text[:300]
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


def _stop_with_parent() -> None:
    """In a node process before exec: SIGTERM when the graph process dies (Linux PR_SET_PDEATHSIG), so a graph
    killed with SIGKILL leaves no node running; the node then stops as on Ctrl-C and writes what it has."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: the nodes outlive a killed graph


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


def stop_all(nodes: list[NodeProcess], budget_s: float = 8.0) -> dict[str, int | None]:
    """Stop every running process at once: SIGINT, then SIGTERM, then SIGKILL, all within about `budget_s`
    (a crash loop: nothing is waited for one node after another). Returns name -> exit code."""
    import signal
    import time

    steps = ((signal.SIGINT, 0.5 * budget_s), (signal.SIGTERM, 0.3 * budget_s), (signal.SIGKILL, 0.2 * budget_s))
    for sig, wait_s in steps:
        alive = [n for n in nodes if n.running()]
        for node in alive:
            try:
                node.proc.send_signal(sig)  # type: ignore[union-attr]
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait_s
        while any(n.running() for n in alive) and time.monotonic() < deadline:
            time.sleep(0.05)
    return {n.name: (n.proc.returncode if n.proc is not None else None) for n in nodes}


class NodeFailed(SlamError):
    """A node died in a way a restart does not mend (crash loop, death while starting); the graph stops at once."""

    def __init__(self, node: NodeProcess, why: str) -> None:
        failure = node.failure()
        super().__init__(f"graph: {node.name} {why}" + (f" ({failure})" if failure else "")
                         + f"; every process stopped; log {node.log_path}")  # fmt: skip
        self.node = node
