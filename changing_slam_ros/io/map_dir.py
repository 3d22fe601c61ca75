"""Where the SaveMap / LoadMap services of a node may read and write: names inside one configured map folder.

Any peer on the DDS domain can call a node's services, so a request's path is treated as untrusted: it must name
a file inside `map_dir` (a relative name, or an absolute path that lies inside it), with no `..` component, no
symbolic link leading out of the folder, and one of the node's map suffixes. Saving never replaces a file that is
not a map of ours (`is_metric_map` / `is_semantic_map` look at the file's format marker, not its name).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePath

from changing_slam_ros.errors import MapFileError


class MapPathRefused(MapFileError):
    """A SaveMap / LoadMap request names a path the node does not read or write; the message says why."""


def is_metric_map(path: Path) -> bool:
    """A map file of `io.map_file` (an npz archive holding `format_version`), of any format version."""
    try:
        with zipfile.ZipFile(path) as archive:
            return "format_version.npy" in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def is_semantic_map(path: Path) -> bool:
    """A semantic-map file of `io.semantic_map_file` (JSON or YAML whose `format` is ours)."""
    from changing_slam_ros.io.semantic_map_file import FORMAT

    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return False
    try:
        if path.suffix in (".yaml", ".yml"):
            import yaml

            doc = yaml.safe_load(text)
        else:
            doc = json.loads(text)
    except Exception:  # noqa: BLE001 - any parse failure means "not ours"
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT


@dataclass(frozen=True)
class MapDir:
    """The folder a node's map services are confined to.

    `root`: the configured `map_dir` ("" = none: every request path is refused); `suffixes`: the endings of the
    node's map files; `is_ours`: whether an existing file is a map this node may overwrite.
    """

    root: str
    suffixes: tuple[str, ...]
    is_ours: Callable[[Path], bool]
    service: str = "map service"  # named in refusals, e.g. "local_mapping SaveMap"

    def resolve(self, name: str, for_write: bool) -> Path:
        """The absolute path of request name `name`; MapPathRefused saying why when it is not allowed."""
        if not self.root:
            raise MapPathRefused(f"{self.service}: refused {name!r}: no map_dir parameter is set (map files are read "
                                 "and written only inside it)")  # fmt: skip
        if not name:
            raise MapPathRefused(f"{self.service}: refused: empty path (give a file name inside {self.root})")
        if "\x00" in name:
            raise MapPathRefused(f"{self.service}: refused {name!r}: NUL character in the path")
        if ".." in PurePath(name).parts:
            raise MapPathRefused(f"{self.service}: refused {name!r}: '..' is not allowed in a map path")
        root = Path(self.root).resolve()
        candidate = Path(name) if Path(name).is_absolute() else root / name
        try:
            path = candidate.resolve()
        except (OSError, RuntimeError) as err:
            raise MapPathRefused(f"{self.service}: refused {name!r}: cannot resolve it ({err})") from err
        if not path.is_relative_to(root) or path == root:
            raise MapPathRefused(f"{self.service}: refused {name!r}: outside map_dir {root}")
        if not any(path.name.endswith(s) for s in self.suffixes):
            raise MapPathRefused(f"{self.service}: refused {name!r}: a map file name ends in "
                                 f"{' or '.join(self.suffixes)}")  # fmt: skip
        if for_write and path.exists():
            if not path.is_file() or not self.is_ours(path):
                raise MapPathRefused(f"{self.service}: refused {name!r}: {path} exists and is not a map file of ours "
                                     "(never overwritten)")  # fmt: skip
        if not for_write and not path.is_file():
            raise MapPathRefused(f"{self.service}: refused {name!r}: no such map file in map_dir {root}")
        return path
