"""Error hierarchy: one base, one subclass per area.

Messages name the object (file, topic, field) and say what was expected. The CLI prints a
`SlamError` on one line and exits 1; anything else is a bug and shows a traceback.
"""

from __future__ import annotations

import os


class SlamError(Exception):
    """Base of every error the project raises on bad input or configuration."""


class ConfigError(SlamError):
    """A configuration file or parameter is missing, malformed or out of range."""


class DatasetError(SlamError):
    """A dataset folder (TUM layout, 7-Scenes) is missing files or holds malformed ones."""


class BagError(SlamError):
    """A ROS 1 bag, ROS 2 bag or mcap file cannot be read or lacks the configured topics."""


class EvalError(SlamError):
    """A trajectory cannot be evaluated (empty, unreadable, no associated stamps)."""


class MapFileError(SlamError):
    """A saved map file is missing, corrupt or of an unsupported version."""


class OutputError(SlamError):
    """A run's results cannot be written (disk full, permissions changed during the run)."""


class SimError(SlamError):
    """A simulator scenario or its rendering cannot be produced."""


def utf8_error(path: str | os.PathLike[str], err: UnicodeDecodeError, what: str) -> str:
    """`path:line: not UTF-8 <what> (byte 0xNN)`: where a file stops being UTF-8, for a one-line error."""
    try:
        with open(path, "rb") as f:
            raw = f.read()
    except OSError:
        raw = err.object if isinstance(err.object, bytes) else b""
    line = raw[: err.start].count(b"\n") + 1
    byte = f" (byte 0x{raw[err.start]:02x})" if err.start < len(raw) else ""
    return f"{path}:{line}: not UTF-8 {what}{byte}"


def read_utf8(path: str | os.PathLike[str], error: type[SlamError], what: str = "text", noun: str = "") -> str:
    """The text of `path`; `error` with a one-line message naming the file where it cannot be read
    (`path: cannot read [noun] (reason)`) or stops being UTF-8 (`utf8_error`)."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except OSError as err:
        raise error(f"{path}: cannot read{' ' + noun if noun else ''} ({err.strerror or err})") from err
    except UnicodeDecodeError as err:
        raise error(utf8_error(path, err, what)) from err


def yaml_error(path: str | os.PathLike[str], err: Exception) -> str:
    """`path:line: not valid YAML (problem)` from a PyYAML error, on one line (PyYAML's own text spans several)."""
    mark = getattr(err, "problem_mark", None)
    where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
    problem = getattr(err, "problem", None) or str(err).strip().splitlines()[0]
    return f"{where}: not valid YAML ({problem})"
