"""A git revision of this repository as a source tree, for the benchmarks that measure against a baseline.

    from git_tree import archive_tree
    archive_tree("8b22cd1", Path(tmp))                      # the whole tree
    archive_tree("8b22cd1", Path(tmp), "changing_slam_ros")  # the package only
    current, baseline = alternating_runs("8b22cd1", Path("."), 2, lambda tree: run_tree(tree, ...))
"""

from __future__ import annotations

import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def archive_tree(ref: str, dest: Path, *paths: str) -> Path:
    """Extract `git archive REF [PATHS]` of this repository into `dest` (created if missing); returns `dest`."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref, *paths], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def alternating_runs(baseline: str | None, current: Path, runs: int,
                     run_tree: Callable[[Path], dict[str, Any]]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """`runs` runs of `run_tree` on the `current` tree and, when `baseline` is a git ref, as many on that revision
    (archived into a temporary folder), alternating baseline, current, baseline, ... so that other load on a shared
    machine hits both alike; returns (current runs, baseline runs)."""
    current_runs: list[dict[str, Any]] = []
    baseline_runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench_baseline_") as tmp:
        if baseline:
            archive_tree(baseline, Path(tmp))
        for _ in range(runs):
            if baseline:
                baseline_runs.append(run_tree(Path(tmp)))
            current_runs.append(run_tree(current))
    return current_runs, baseline_runs
