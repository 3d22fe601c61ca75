"""tools/build_interfaces.sh: idempotent, and what it installs imports from a bare shell with nothing sourced."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import REPO

SCRIPT = REPO / "tools" / "build_interfaces.sh"
PREFIX = Path(sys.prefix)


def _run(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=60,
                          env=env or dict(os.environ, VIRTUAL_ENV=str(PREFIX)))  # fmt: skip


@pytest.fixture
def built() -> None:
    if _run("--check").returncode != 0:
        pytest.skip("interfaces not built or out of date: run tools/build_interfaces.sh")


def test_a_second_call_does_nothing_and_returns_at_once(built):
    t0 = time.monotonic()
    done = _run()
    elapsed = time.monotonic() - t0
    assert done.returncode == 0 and done.stdout == "" and done.stderr == ""
    assert elapsed < 2.0, f"no-op call took {elapsed:.2f} s"


def test_the_stamp_follows_the_message_definitions(built, tmp_path):
    """--check hashes msg_defs/ contents: an identical copy is up to date, an edited definition is not.

    Read-only on the venv: a copy of the script and msg_defs/ in tmp_path checks against the installed stamps.
    """
    import shutil

    root = tmp_path / "repo"
    (root / "tools").mkdir(parents=True)
    shutil.copy2(SCRIPT, root / "tools" / SCRIPT.name)
    shutil.copytree(REPO / "msg_defs", root / "msg_defs", ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, VIRTUAL_ENV=str(PREFIX))
    check = ["bash", str(root / "tools" / SCRIPT.name), "--check"]
    assert subprocess.run(check, capture_output=True, text=True, env=env, timeout=60).returncode == 0
    with (root / "msg_defs" / "changing_slam_msgs" / "msg" / "Detection.msg").open("a") as fh:
        fh.write("float32 extra\n")
    done = subprocess.run(check, capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 1 and "out of date" in done.stdout


def test_installed_interfaces_import_from_a_bare_environment(built):
    env = {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/root")}
    code = "from changing_slam_msgs.msg import Keyframe; from tf2_msgs.msg import TFMessage; print(Keyframe().id)"
    done = subprocess.run([str(PREFIX / "bin" / "python"), "-c", code], capture_output=True, text=True,
                          env=env, cwd="/", timeout=60)  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip() == "0", done.stderr


def test_bad_arguments_print_the_usage():
    done = _run("--bogus")
    assert done.returncode == 2 and "usage: tools/build_interfaces.sh [--force|--check]" in done.stderr
