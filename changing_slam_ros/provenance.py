"""What produced a run's results: package version, git commit of the checkout, the configuration as resolved.

`run_provenance` is what `changing-slam run` (metrics.json) and `changing-slam graph` (graph_summary.json) record
under `provenance`; `version_line` is what `changing-slam --version` prints. The commit is read only when the
package lies in a git checkout of its own (an installed package, or a venv inside some other repository, has
none: None, never an error). The configuration is every section of `config.CONFIG_SECTIONS` parsed into its
dataclass, defaults filled in, as JSON values.
"""

from __future__ import annotations

import dataclasses
import enum
import subprocess
from pathlib import Path
from typing import Any

from changing_slam_ros import __version__
from changing_slam_ros.config import section, section_classes

CHECKOUT = Path(__file__).resolve().parent.parent  # the repository root when run from a checkout


def _git(root: Path, *args: str) -> str | None:
    try:
        result = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return result.stdout.strip() if result.returncode == 0 else None


def git_commit(root: Path = CHECKOUT) -> dict[str, Any] | None:
    """{"commit": full hash, "dirty": tracked files changed} of the checkout at `root`; None when `root` is not
    the top of a git work tree (or git is missing)."""
    if not (root / ".git").exists():
        return None
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() != root.resolve():
        return None
    commit = _git(root, "rev-parse", "HEAD")
    if commit is None:
        return None
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status) if status is not None else None}


def version_line() -> str:
    """`changing-slam 0.1.0`, with ` (git abc1234567, modified)` from a checkout."""
    git = git_commit()
    if git is None:
        return f"changing-slam {__version__}"
    return f"changing-slam {__version__} (git {git['commit'][:10]}{', modified' if git['dirty'] else ''})"


def jsonable(value: Any) -> Any:
    """Dataclasses, tuples, enums, paths and numpy values as plain JSON values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in value]
    if isinstance(value, enum.Enum):
        return jsonable(value.value)
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return value.tolist()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def resolved_config(data: dict[str, Any], where: str) -> dict[str, Any]:
    """Every config section as its dataclass reads it from `data` (a parsed config file; {} = defaults)."""
    out: dict[str, Any] = {}
    for name, cls in section_classes().items():
        if name == "camera" and data.get(name) is None:
            out[name] = None  # no intrinsics in the config: they come from the dataset or camera_info
        else:
            out[name] = jsonable(section(cls, data.get(name), f"{where}: {name}"))
    return out


def run_provenance(data: dict[str, Any], where: str, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """The `provenance` entry of metrics.json / graph_summary.json."""
    git = git_commit()
    out: dict[str, Any] = {
        "package_version": __version__,
        "git_commit": git["commit"] if git else None,
        "git_dirty": git["dirty"] if git else None,
        "config_path": where,
        "config": resolved_config(data, where),
    }
    if options is not None:
        out["options"] = jsonable(options)
    return out
