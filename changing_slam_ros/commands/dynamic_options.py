"""Dynamic-scene options of `changing-slam run` (a helper of `commands/run.py`, not a subcommand).

    --detections {none,model,oracle}   where boxes come from (default: model, the shipped SSD-MobileNetV2
                                       or `detector.model_path`); oracle = the simulator's detections.json
                                       inside the TUM folder, or --detections-file
    --detections-file FILE             oracle detections JSON given explicitly
    --detect-every N                   the detector on every N-th frame only, boxes carried between
    --dynamic / --no-dynamic           dynamic handling on (default, or `dynamic.enabled`) / off (plain engine)
    --[no-]detection-filtering --[no-]repopulation --[no-]ekf-doc --[no-]segmentation --[no-]free-space-check
                                       the ablation switches (default: the `dynamic:` config section)

Config sections read: `dynamic:` (`core.dynamic_filter.DynamicConfig`) and `detector:`
(`core.dynamic.detector.DetectorConfig`).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from changing_slam_ros.config import section
from changing_slam_ros.core.dynamic.detection_cadence import DetectionCadence
from changing_slam_ros.core.dynamic.detector import Detection, DetectionSet, Detector, DetectorConfig
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.detections_file import DetectionsFile, find_detections_file, read_detections_file

DETECTION_SOURCES = ("none", "model", "oracle")
SWITCHES = ("detection_filtering", "repopulation", "ekf_doc", "segmentation", "free_space_check")


def add_dynamic_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("dynamic scenes (detector, EKFs, segmentation)")
    group.add_argument("--detections", choices=DETECTION_SOURCES, default="model",
                       help="object boxes: none, model (ONNX detector, default) or oracle (simulator detections.json)")
    group.add_argument("--detections-file", type=Path, default=None, metavar="FILE",
                       help="oracle detections JSON (default: detections.json inside SOURCE)")
    group.add_argument("--dynamic", action=argparse.BooleanOptionalAction, default=None,
                       help="dynamic-scene keypoint filtering (default on, or the config's dynamic.enabled)")
    group.add_argument("--detect-every", type=int, default=1, metavar="N",
                       help="run the detector on every N-th frame only; the frames between take the last boxes "
                            "carried forward by their image motion (default 1: every frame)")
    for name in SWITCHES:
        group.add_argument(f"--{name.replace('_', '-')}", dest=name, action=argparse.BooleanOptionalAction,
                           default=None, help=f"ablation switch dynamic.{name} (default from the config)")


@dataclass
class DynamicSetup:
    """The run's dynamic filter (None = plain engine) and where each frame's detections come from."""

    filter: DynamicFilter | None
    source: str
    detector: Detector | None = None
    oracle: DetectionsFile | None = None
    detection_ms: list[float] = field(default_factory=list)

    detect_every: int = 1
    cadence: DetectionCadence | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        if self.detector is not None:
            self.cadence = DetectionCadence(self._detect, self.detect_every)

    def detections_for(self, rgbd: RgbdFrame) -> tuple[Detection, ...] | None:
        """The frame's detections; frames must come in order (with `detect_every` > 1 the frames between two
        detected ones take the earlier's boxes carried forward, `core.dynamic.detection_cadence`)."""
        if self.filter is None or not self.filter.config.detection_filtering:
            return None
        if self.cadence is not None:
            return self.cadence(rgbd)
        if self.oracle is not None:
            return self.oracle.for_stamp(rgbd.stamp_ns)
        return ()

    def _detect(self, rgbd: RgbdFrame) -> DetectionSet:
        assert self.detector is not None
        t0 = time.perf_counter()
        found = self.detector.detect(rgbd.rgb, rgbd.stamp_ns)
        self.detection_ms.append((time.perf_counter() - t0) * 1e3)
        return found

    def summary(self) -> dict[str, Any]:
        """For metrics.json: switches, detection source, keypoints kept, milliseconds per frame."""
        if self.filter is None:
            return {"enabled": False}
        f = self.filter
        out: dict[str, Any] = {"enabled": True, "detections": self.source}
        out.update({name: getattr(f.config, name) for name in SWITCHES})
        out["kept_fraction"] = f.kept_fraction()
        out["filter_ms_median"] = float(np.median(f.frames_ms)) if f.frames_ms else 0.0
        if self.detection_ms:
            out["detection_ms_median"] = float(np.median(self.detection_ms))
        if self.cadence is not None:
            out["detect_every"] = self.cadence.every
            out["frames_detected"], out["frames_carried"] = self.cadence.n_detected, self.cadence.n_carried
        for name, values in (("segmentation", f.segmentation_cpu_ms), ("free_space", f.free_space_cpu_ms)):
            if values:  # thread CPU of the class-agnostic cues
                out[f"{name}_cpu_ms_median"] = float(np.median(values))
        return out


def dynamic_setup(args: argparse.Namespace, data: dict[str, Any], where: str) -> DynamicSetup:
    """Build the filter and the detection source from the config sections and the command line."""
    config = section(DynamicConfig, data.get("dynamic"), f"{where}: dynamic")
    overrides = {name: getattr(args, name) for name in SWITCHES if getattr(args, name) is not None}
    if args.dynamic is not None:
        overrides["enabled"] = args.dynamic
    config = dataclasses.replace(config, **overrides)
    if not config.enabled:
        return DynamicSetup(None, "none")
    flt = DynamicFilter(config)
    source = args.detections if config.detection_filtering else "none"
    if source == "model":
        every = getattr(args, "detect_every", 1)
        if every < 1:
            raise ConfigError(f"--detect-every {every}: expected a frame count >= 1")
        return DynamicSetup(flt, source, detector=Detector(section(DetectorConfig, data.get("detector"), f"{where}: detector")),
                            detect_every=every)  # fmt: skip
    if source == "oracle":
        path = args.detections_file or find_detections_file(args.source)
        return DynamicSetup(flt, source, oracle=read_detections_file(path))
    return DynamicSetup(flt, source)
