"""Our interface definitions (msg_defs/) registered with a rosbags typestore at run time.

Bags that carry `changing_slam_msgs/msg/*` (keyframes, detections, map updates, object states) can then be
written, read and decoded by rosbags without building the interface package::

    store = typestore_with_project_types()
    Keyframe = store.types["changing_slam_msgs/msg/Keyframe"]
    cdr = store.serialize_cdr(Keyframe(...), "changing_slam_msgs/msg/Keyframe")

The `.msg` files are found in the source checkout (`<repo>/msg_defs/<package>/msg/`) or, for an installed
package, in `<prefix>/share/<package>/msg/` of the ament prefixes. `tf2_msgs/msg/TFMessage` comes from rosbags'
own Jazzy store; the fallback package in msg_defs/ is only registered for stores that lack it.
Services (`.srv`) are not registered: bags never carry them.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import ConfigError

MSG_DEFS_DIR = Path(__file__).resolve().parents[2] / "msg_defs"

# ROS package name -> its folder under msg_defs/.
PACKAGES = {"changing_slam_msgs": "changing_slam_msgs", "tf2_msgs": "tf2_msgs_fallback"}


def msg_dir(package: str) -> Path:
    """Folder holding `package`'s `.msg` files: the source checkout first, then installed share dirs."""
    source = MSG_DEFS_DIR / PACKAGES.get(package, package) / "msg"
    if source.is_dir():
        return source
    for prefix in _ament_prefixes():
        installed = prefix / "share" / package / "msg"
        if installed.is_dir():
            return installed
    raise ConfigError(
        f"{package}: no message definitions in {source} nor in share/{package}/msg of "
        f"{', '.join(str(p) for p in _ament_prefixes()) or 'any ament prefix'}"
    )


def project_types(packages: tuple[str, ...] = ("changing_slam_msgs",)) -> dict[str, Any]:
    """Field definitions of every message of `packages`, keyed `package/msg/Name` (rosbags Typesdict)."""
    from rosbags.typesys import TypesysError, get_types_from_msg

    types: dict[str, Any] = {}
    for package in packages:
        folder = msg_dir(package)
        for path in sorted(folder.glob("*.msg")):
            name = f"{package}/msg/{path.stem}"
            try:
                types.update(get_types_from_msg(path.read_text(), name))
            except (OSError, TypesysError) as err:
                raise ConfigError(f"{path}: cannot parse message definition: {err}") from err
    return types


def register_project_types(store: Any) -> Any:
    """Add our messages (and TFMessage where the store lacks it) to rosbags typestore `store`; returns it."""
    packages: tuple[str, ...] = ("changing_slam_msgs",)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        packages += ("tf2_msgs",)
    store.register(project_types(packages))
    return store


def typestore_with_project_types() -> Any:
    """A fresh rosbags ROS 2 Jazzy typestore that also knows `changing_slam_msgs`."""
    from rosbags.typesys import Stores, get_typestore

    return register_project_types(get_typestore(Stores.ROS2_JAZZY))


def _ament_prefixes() -> list[Path]:
    prefixes = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    if Path(sys.prefix) not in prefixes:
        prefixes.append(Path(sys.prefix))
    return prefixes
