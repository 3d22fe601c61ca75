"""Configuration: YAML parsed once, at the edge, into typed dataclasses.

A config file is a mapping of sections (`camera`, `dataset`, `features`, `tracking`, ...). Each area of
the code owns a frozen dataclass for its section with the papers' values as defaults; this module
only reads YAML and fills dataclasses, rejecting unknown keys and wrong types with a `ConfigError`
that names the file and the key.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from changing_slam_ros.errors import ConfigError, read_utf8, yaml_error

T = TypeVar("T")

PACKAGE_CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
# The top-level sections a config file may hold, each read by one area of the code into its dataclass. Any other
# name (a misspelt `trackng:`) is an error, as unknown keys inside a section are.
CONFIG_SECTIONS = ("camera", "dataset", "features", "tracking", "mapping", "loop", "dynamic", "objects", "detector",
                   "grid")


def section_classes() -> dict[str, type]:
    """YAML top-level section -> the dataclass that area of the code parses it into (imported here, lazily)."""
    from changing_slam_ros.core.dynamic.detector import DetectorConfig
    from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig
    from changing_slam_ros.core.features.orb_features import FeatureConfig
    from changing_slam_ros.core.map.occupancy_grid import GridConfig
    from changing_slam_ros.core.objects.map_object import ObjectMapConfig
    from changing_slam_ros.core.slam.local_mapping import MappingConfig
    from changing_slam_ros.core.slam.loop_closing import LoopConfig
    from changing_slam_ros.core.slam.tracking_config import TrackingConfig
    from changing_slam_ros.io.dataset_config import CameraConfig, DatasetConfig

    classes = {"camera": CameraConfig, "dataset": DatasetConfig, "features": FeatureConfig,
               "tracking": TrackingConfig, "mapping": MappingConfig, "loop": LoopConfig, "dynamic": DynamicConfig,
               "detector": DetectorConfig, "objects": ObjectMapConfig, "grid": GridConfig}  # fmt: skip
    assert set(classes) == set(CONFIG_SECTIONS)
    return classes


def find_config(name_or_path: str | Path) -> Path:
    """Resolve a config given as a path or as the name of a shipped one (`tum_fr1`, `7scenes`)."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    for candidate in (PACKAGE_CONFIG_DIR / f"{name_or_path}.yaml", _share_config_dir() / f"{name_or_path}.yaml"):
        if candidate.is_file():
            return candidate
    raise ConfigError(f"{name_or_path}: no such config file and no shipped config of that name")


def _share_config_dir() -> Path:
    try:
        from ament_index_python.packages import get_package_share_directory  # type: ignore

        return Path(get_package_share_directory("changing_slam_ros")) / "config"
    except Exception:  # noqa: BLE001 - ament index absent outside a ROS install
        return PACKAGE_CONFIG_DIR


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; errors name the file."""
    p = Path(path)
    text = read_utf8(p, ConfigError, noun="config")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(yaml_error(p, err)) from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping of sections at top level, got {type(data).__name__}")
    return data


def check_sections(data: dict[str, Any], where: str) -> dict[str, Any]:
    """`data` (a parsed config file) when every top-level key is a known section; ConfigError naming the file,
    the unknown section and the closest known name otherwise."""
    import difflib

    unknown = sorted(str(k) for k in data if k not in CONFIG_SECTIONS)
    if unknown:
        hints = [f"{u} (did you mean {m[0]}?)" if (m := difflib.get_close_matches(u, CONFIG_SECTIONS, 1)) else u
                 for u in unknown]  # fmt: skip
        raise ConfigError(f"{where}: unknown section(s) {', '.join(hints)}; known: {', '.join(CONFIG_SECTIONS)}")
    return data


def load_config(name_or_path: str | Path) -> tuple[dict[str, Any], str]:
    """A config file or shipped config name, parsed and its sections checked: (data, path as text)."""
    path = find_config(name_or_path)
    return check_sections(load_yaml(path), str(path)), str(path)


def section(cls: type[T], data: dict[str, Any] | None, where: str) -> T:
    """Build dataclass `cls` from mapping `data`; unknown keys and wrong types raise ConfigError.

    `where` names the file and section for messages, e.g. "config/tum_fr1.yaml: tracking".
    """
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(fields))}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        kwargs[key] = _coerce(value, hints[key], f"{where}.{key}")
    return cls(**kwargs)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return section(hint, value, where)
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: {value!r} does not match {hint}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        inner = args[0] if args else Any
        items = [_coerce(v, inner, where) for v in value]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        kt, vt = args if args else (Any, Any)
        return {_coerce(k, kt, where): _coerce(v, vt, where) for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value
