"""The tracking node's in-process backend: the whole `core.system.SlamSystem` built from a config (ROS-free).

With `in_process_backend:=true` the tracking node runs tracking -> local mapping -> object layer -> loop
closing in its own process, exactly as `changing-slam run` wires them (same config sections, same classes),
and only the transport around it is ROS: deterministic, one process instead of the split graph's three. This
module builds that system and writes its outputs; no rclpy here.

    setup = build_backend(load_backend_config("tum_fr1"), loop=True, dynamic="config", objects="config")
    out = setup.system.process(rgbd, detections)
    write_backend_outputs(Path("out"), setup, stats)
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from changing_slam_ros.config import load_config, section
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
from changing_slam_ros.core.objects.object_layer import ObjectLayer, object_layer_config
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.atomic import atomic_write_text
from changing_slam_ros.io.tum_trajectory import write_tum_trajectory

SWITCH_VALUES = ("config", "on", "off")


@dataclass(frozen=True)
class BackendConfig:
    """A parsed config file: its mapping and where it came from (for error messages)."""

    data: dict[str, Any]
    where: str

    def with_mapping(self, why: str, **values: Any) -> BackendConfig:
        """A copy with `values` set in the `mapping:` section (a node parameter over the file), `why` in `where`."""
        mapping = {**(self.data.get("mapping") or {}), **values}
        return BackendConfig({**self.data, "mapping": mapping}, f"{self.where} ({why})")


@dataclass
class Backend:
    """The system and the optional stages it was built with (None = off)."""

    system: SlamSystem
    dynamic: DynamicFilter | None
    objects: ObjectLayer | None
    loop_closing: Any | None
    config: BackendConfig

    @property
    def wants_detections(self) -> bool:
        """True when the dynamic filter classifies keypoints with detection boxes."""
        return self.dynamic is not None and self.dynamic.config.detection_filtering


def load_backend_config(name_or_path: str) -> BackendConfig:
    """`""` = defaults; otherwise a shipped config name (`tum_fr1`) or a YAML path."""
    if not name_or_path:
        return BackendConfig({}, "defaults")
    from changing_slam_ros.io.dataset_config import settings_from_mapping

    data, where = load_config(name_or_path)
    settings_from_mapping(data, where)  # camera and dataset sections checked at start, not at the first frame
    return BackendConfig(data, where)


def _switch(value: str, config_value: bool, what: str) -> bool:
    if value not in SWITCH_VALUES:
        raise ConfigError(f"tracking: parameter {what}: '{value}' unknown; expected one of {', '.join(SWITCH_VALUES)}")
    return config_value if value == "config" else value == "on"


def build_backend(cfg: BackendConfig, loop: bool = True, dynamic: str = "config", objects: str = "config") -> Backend:
    """SlamSystem with loop closing (unless `loop` is False or `loop.enabled` is false), the dynamic filter and
    the object layer switched by `dynamic` / `objects` ('config' = the section's `enabled`, 'on', 'off')."""
    from changing_slam_ros.commands.run import system_config_from_mapping

    data, where = cfg.data, cfg.where
    system_config = system_config_from_mapping(data, where)
    dyn_cfg = section(DynamicConfig, data.get("dynamic"), f"{where}: dynamic")
    dyn_cfg = dataclasses.replace(dyn_cfg, enabled=_switch(dynamic, dyn_cfg.enabled, "dynamic"))
    obj_cfg = object_layer_config(data.get("objects"), f"{where}: objects")
    obj_cfg = dataclasses.replace(obj_cfg, enabled=_switch(objects, obj_cfg.enabled, "objects"))
    closing = _loop_closing(data, where) if loop else None
    dyn = DynamicFilter(dyn_cfg) if dyn_cfg.enabled else None
    layer = ObjectLayer(obj_cfg)
    system = SlamSystem(system_config, loop_closer=closing, keyframe_index=closing, dynamic_filter=dyn, object_layer=layer)
    return Backend(system, dyn, layer if obj_cfg.enabled else None, closing, cfg)


def _loop_closing(data: dict[str, Any], where: str) -> Any | None:
    from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
    from changing_slam_ros.core.features.vocabulary import Vocabulary

    cfg = section(LoopConfig, data.get("loop"), f"{where}: loop")
    return SlamMapLoopClosing(LoopCloser(cfg, Vocabulary.load())) if cfg.enabled else None


def config_camera(cfg: BackendConfig) -> CameraIntrinsics | None:
    """The config's `camera:` section as intrinsics (None when it has none)."""
    from changing_slam_ros.io.dataset_config import CameraConfig

    cam = cfg.data.get("camera")
    if cam is None:
        return None
    return section(CameraConfig, cam, f"{cfg.where}: camera").intrinsics(f"{cfg.where}: camera")


def intrinsics_source(cfg: BackendConfig) -> str:
    """'camera_info' or 'config': the config's `dataset.bag_intrinsics_from` (TUM bags carry ROS defaults)."""
    ds = cfg.data.get("dataset") or {}
    value = ds.get("bag_intrinsics_from", "camera_info") if isinstance(ds, dict) else "camera_info"
    return "config" if value == "config" and cfg.data.get("camera") is not None else "camera_info"


def write_backend_outputs(out_dir: Path, backend: Backend, stats: dict[str, Any]) -> list[Path]:
    """Write, atomically: trajectory.txt (final), trajectory_online.txt, keyframes.txt (TUM), tracking_stats.json
    and, with the object layer on, semantic_map.json (the current map's §4.8 map). Returns the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    system = backend.system
    written: list[Path] = []
    if system.records:
        for name, traj in (
            ("trajectory.txt", system.final_trajectory()),
            ("trajectory_online.txt", system.online_trajectory()),
            ("keyframes.txt", system.keyframe_trajectory()),
        ):
            write_tum_trajectory(out_dir / name, traj)
            written.append(out_dir / name)
    if backend.objects is not None and system.records:
        from changing_slam_ros.io.semantic_map_file import write_semantic_map

        path = out_dir / "semantic_map.json"
        write_semantic_map(path, backend.objects.semantic_map(system.atlas.current.id))
        written.append(path)
    full = dict(stats)
    full.update({
        "frames_processed": len(system.records), "frames_tracked": system.n_tracked(),
        "keyframes": system.atlas.n_keyframes, "maps": len(system.atlas.maps), "loops_closed": system.n_loops,
        "timing_ms": system.timing_summary() if system.records else {},
    })  # fmt: skip
    path = out_dir / "tracking_stats.json"
    atomic_write_text(path, json.dumps(full, indent=2) + "\n")
    written.append(path)
    return written
