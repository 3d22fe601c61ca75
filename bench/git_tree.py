"""A git revision of this repository as a source tree, for the benchmarks that measure against a baseline.

    from git_tree import archive_tree
    archive_tree("8b22cd1", Path(tmp))                      # the whole tree
    archive_tree("8b22cd1", Path(tmp), "changing_slam_ros")  # the package only
"""

from __future__ import annotations

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def archive_tree(ref: str, dest: Path, *paths: str) -> Path:
    """Extract `git archive REF [PATHS]` of this repository into `dest` (created if missing); returns `dest`."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", ref, *paths], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest
