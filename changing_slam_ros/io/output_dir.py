"""A run's output folder written as one unit: results go into a fresh folder beside the target, which replaces
the target only when the run is complete.

    out = OutputDir.prepare("out/fr1", "--out")   # checks before any work: writable, not a file
    write results into out.work ...
    out.commit()                                  # out/fr1 now holds this run's results, all of them

The work folder is `<name>.incomplete-<UTC time>` beside the target, so a run that is interrupted (Ctrl-C, an
error, SIGKILL) leaves the target as it was (the earlier complete results, or nothing) and its partial results
under that name. `commit` swaps the two folders in one `renameat2(RENAME_EXCHANGE)` call where the kernel has
it (Linux >= 3.15), so at every instant the target holds one complete run; elsewhere it renames the old target
aside first. The superseded results are then deleted; a marker file lets a later `prepare` recognise them (and
delete them) should the process die between the swap and the deletion.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from changing_slam_ros.errors import ConfigError

SUPERSEDED = ".superseded"  # written into the old results just before they are swapped out
# A non-empty target is replaced only when it holds one of these: the results of an earlier run or graph. Any
# other folder (a dataset, a home folder) is refused rather than swapped out and deleted.
RESULT_FILES = ("metrics.json", "graph_summary.json", "trajectory.txt", "tracking_stats.json", "timing.json")
_RENAME_EXCHANGE = 2  # linux/fs.h
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (renameat2 RENAME_EXCHANGE); False where the call is not available."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (38, 22, 95):  # ENOSYS, EINVAL, EOPNOTSUPP: not supported here
        return False
    raise OSError(err, os.strerror(err), str(b))


@dataclass
class OutputDir:
    """`target`: the folder the user named; `work`: where this run writes (see the module doc)."""

    target: Path
    work: Path
    committed: bool = False

    @classmethod
    def prepare(cls, path: str | Path, option: str = "--out") -> OutputDir:
        """Check that `path` can receive results and create the work folder beside it; ConfigError naming
        `option` and the path otherwise (before any frame is read)."""
        target = Path(path).absolute()
        if target.exists() and not target.is_dir():
            raise ConfigError(f"{option} {path}: exists and is not a folder")
        if target.is_dir() and not os.access(target, os.W_OK | os.X_OK):
            raise ConfigError(f"{option} {path}: folder is not writable")
        if target.is_dir() and any(target.iterdir()) and not any((target / f).is_file() for f in RESULT_FILES):
            raise ConfigError(f"{option} {path}: holds files that are not the results of an earlier run (no "
                              f"{' / '.join(RESULT_FILES[:2])}); results replace the whole folder, so give a new "
                              "or empty one")  # fmt: skip
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(f"{option} {path}: cannot create its parent folder ({err.strerror})") from err
        if not os.access(target.parent, os.W_OK | os.X_OK):
            raise ConfigError(f"{option} {path}: {target.parent} is not writable")
        _clean_superseded(target)
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
        work = target.with_name(f"{target.name}.incomplete-{stamp}")
        n = 1
        while work.exists():
            n += 1
            work = target.with_name(f"{target.name}.incomplete-{stamp}-{n}")
        try:
            work.mkdir()
        except OSError as err:
            raise ConfigError(f"{option} {path}: cannot write beside it ({err.strerror})") from err
        return cls(target, work)

    def path_after_commit(self, p: Path) -> Path:
        """Where `p` (inside the work folder) will be once committed."""
        return self.target / Path(p).relative_to(self.work)

    def commit(self) -> Path:
        """Put the work folder in the target's place (atomically where possible); returns the target."""
        if self.target.is_dir():
            (self.target / SUPERSEDED).touch()
            if not _exchange(self.work, self.target):
                old = self.target.with_name(f"{self.work.name}.old")
                os.rename(self.target, old)
                os.rename(self.work, self.target)
                self.work = old
            shutil.rmtree(self.work, ignore_errors=True)
        else:
            os.rename(self.work, self.target)
        self.committed = True
        return self.target

    def abandon(self) -> Path | None:
        """An interrupted or failed run: keep what it wrote under the work folder's name (returned), or remove
        the work folder when it is empty (None)."""
        if self.committed or not self.work.is_dir():
            return None
        if any(self.work.iterdir()):
            return self.work
        self.work.rmdir()
        return None


def check_output_file(path: str | Path, option: str) -> Path:
    """A file about to be written (convert's OUT.mcap): its folder created and writable, and the path not a
    folder; ConfigError naming `option` and the path otherwise, before any work starts."""
    p = Path(path).absolute()
    if p.is_dir():
        raise ConfigError(f"{option} {path}: is a folder")
    _writable_folder(p.parent, option, path)
    return p


def check_output_folder(path: str | Path, option: str) -> Path:
    """A folder about to be filled (simulate's --out): created when missing, writable, not a file."""
    p = Path(path).absolute()
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{option} {path}: exists and is not a folder")
    _writable_folder(p, option, path)
    return p


def _writable_folder(folder: Path, option: str, given: str | Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"{option} {given}: cannot create {folder} ({err.strerror})") from err
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {given}: {folder} is not writable")


def _clean_superseded(target: Path) -> None:
    """Remove results a committed run replaced but had no time to delete; drop a stale marker in the target."""
    for p in target.parent.glob(f"{target.name}.incomplete-*"):
        if (p / SUPERSEDED).exists():
            shutil.rmtree(p, ignore_errors=True)
    marker = target / SUPERSEDED
    if marker.exists():
        marker.unlink()
