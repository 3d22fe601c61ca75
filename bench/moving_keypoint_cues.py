"""Which cue catches the moving keypoints: per-cue recall and the stage's precision against simulator masks.

Prints, never asserts. Runs `SlamSystem` with the dynamic stage over a rendered TUM folder of the simulator
(`changing-slam simulate NAME --out DIR`: masks/ and objects.json hold the ground truth) and scores every
keypoint of every frame. A keypoint is *moving* when its mask pixel belongs to an object whose pose changes
faster than `--min-speed` m/s between neighbouring frames; keypoints on an object of a moving kind that
stands still (a person pausing) count neither way. Cues, per keypoint:

- `detector`: dropped for a box alone: inside a person box (class DYNAMIC by §4.1), or a box whose keypoints
  §4.1 disables (UNUSED: occluded, depth spread too high);
- `ekf`: inside a box of a movable object that the EKF / segmentation fraction called dynamic;
- `segmentation`: on an object target of the two-frame segmentation;
- `any`: dropped by the stage (what tracking never sees). Precision is that of `any`.

    .venv/bin/python bench/moving_keypoint_cues.py DIR [--frames N] [--detections oracle|none|model]
        [--config sim] [--set segmentation_method=correlation ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.commands.run import system_config_from_mapping  # noqa: E402
from changing_slam_ros.config import find_config, load_yaml, section  # noqa: E402
from changing_slam_ros.core.dynamic.detector import Detector, DetectorConfig  # noqa: E402
from changing_slam_ros.core.dynamic.dynamic_filter import DynamicConfig, DynamicFilter  # noqa: E402
from changing_slam_ros.core.dynamic.dynamic_objects import ObjectMotion  # noqa: E402
from changing_slam_ros.core.map.keyframe import KeypointClass  # noqa: E402
from changing_slam_ros.core.system import SlamSystem  # noqa: E402
from changing_slam_ros.eval.ate import ate  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402
from changing_slam_ros.io.dataset_config import load_dataset_settings, settings_from_mapping  # noqa: E402
from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file  # noqa: E402


def moving_ids_per_frame(objects: dict[str, Any], min_speed_mps: float) -> tuple[list[set[int]], set[int]]:
    """Per frame, the mask ids of objects moving faster than `min_speed_mps`; and the ids of moving kinds."""
    stamps = np.asarray(objects["stamps_ns"], dtype=np.float64) / 1e9
    per_frame: list[set[int]] = [set() for _ in stamps]
    kinds = set()
    for obj in objects["objects"]:
        if not obj.get("moving"):
            continue
        kinds.add(int(obj["id"]))
        pos = np.array([np.nan * np.ones(3) if p is None else p[:3] for p in obj["poses"]], dtype=np.float64)
        for k in range(len(stamps)):
            a, b = max(k - 1, 0), min(k + 1, len(stamps) - 1)
            speed = np.linalg.norm(pos[b] - pos[a]) / max(stamps[b] - stamps[a], 1e-9)
            if np.isfinite(speed) and speed > min_speed_mps:
                per_frame[k].add(int(obj["id"]))
    return per_frame, kinds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--detections", choices=("oracle", "none", "model"), default="oracle")
    parser.add_argument("--config", default="", help="config name or file (default: none, the package defaults)")
    parser.add_argument("--min-speed", type=float, default=0.05, help="m/s above which an object counts as moving")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="dynamic.KEY overrides (Python literals)")
    args = parser.parse_args()

    data = load_yaml(find_config(args.config)) if args.config else {}
    settings = settings_from_mapping(data, args.config) if args.config else load_dataset_settings(None)
    source = open_dataset(str(args.folder), settings)
    overrides = {k: eval(v) for k, v in (s.split("=", 1) for s in args.set)}  # noqa: S307 - a bench's own flags
    config = dataclasses.replace(section(DynamicConfig, data.get("dynamic"), "dynamic"), **overrides)
    flt = DynamicFilter(config)
    system = SlamSystem(system_config_from_mapping(data, args.config or "defaults"), dynamic_filter=flt)
    oracle = read_detections_file(find_detections_file(args.folder)) if args.detections == "oracle" else None
    detector = Detector(section(DetectorConfig, data.get("detector"), "detector")) if args.detections == "model" else None
    objects = json.loads((args.folder / "objects.json").read_text())
    moving_ids, kinds = moving_ids_per_frame(objects, args.min_speed)
    stamp_index = {int(s): k for k, s in enumerate(objects["stamps_ns"])}

    captured: dict[str, Any] = {}
    original = flt.before_tracking

    def before_tracking(rgbd: Any, features: Any, detections: Any) -> Any:
        captured["px"] = features.raw_px
        return original(rgbd, features, detections)

    flt.before_tracking = before_tracking  # type: ignore[method-assign]
    counts = {k: 0 for k in ("moving", "detector", "ekf", "segmentation", "any", "dropped_static", "static")}
    n = min(args.frames, len(source)) if args.frames else len(source)
    for i, rgbd in enumerate(source):
        if i >= n:
            break
        if oracle is not None:
            dets = oracle.for_stamp(rgbd.stamp_ns)
        elif detector is not None:
            dets = detector.detect(rgbd.rgb, rgbd.stamp_ns).detections
        else:
            dets = ()
        out = system.process(rgbd, dets)
        dyn = out.dynamic
        k = stamp_index.get(int(rgbd.stamp_ns))
        if dyn is None or k is None:
            continue
        mask = cv2.imread(str(args.folder / "masks" / f"{rgbd.stamp_ns / 1e9:.6f}.png"), cv2.IMREAD_UNCHANGED)
        px = np.rint(captured["px"]).astype(np.int64)
        px[:, 0] = np.clip(px[:, 0], 0, mask.shape[1] - 1)
        px[:, 1] = np.clip(px[:, 1], 0, mask.shape[0] - 1)
        ids = mask[px[:, 1], px[:, 0]].astype(np.int64)
        moving = np.isin(ids, list(moving_ids[k]))
        ignore = np.isin(ids, list(kinds)) & ~moving
        static = ~moving & ~ignore
        dynamic_objects = {o.object_id for o in dyn.objects if o.motion == ObjectMotion.DYNAMIC}
        cue_det = (dyn.kp_classes == KeypointClass.DYNAMIC) | (dyn.kp_classes == KeypointClass.UNUSED)
        cue_ekf = (dyn.kp_classes == KeypointClass.MOVABLE) & np.isin(dyn.object_ids, list(dynamic_objects))
        counts["moving"] += int(moving.sum())
        counts["static"] += int(static.sum())
        counts["detector"] += int((cue_det & moving).sum())
        counts["ekf"] += int((cue_ekf & moving).sum())
        counts["segmentation"] += int((dyn.moving & moving).sum())
        counts["any"] += int((~dyn.keep & moving).sum())
        counts["dropped_static"] += int((~dyn.keep & static).sum())
    mv = max(counts["moving"], 1)
    dropped = counts["any"] + counts["dropped_static"]
    seg = flt.segmentation_cpu_ms
    print(f"{args.folder.name}: {n} frames, detections {args.detections}, overrides {overrides or 'none'}")
    print(f"  moving keypoints {counts['moving']}; recall by cue: detector {counts['detector'] / mv:.3f}, "
          f"ekf {counts['ekf'] / mv:.3f}, segmentation {counts['segmentation'] / mv:.3f}, any {counts['any'] / mv:.3f}")
    print(f"  precision of the dropped keypoints {counts['any'] / max(dropped, 1):.3f}; static keypoints dropped "
          f"{counts['dropped_static'] / max(counts['static'], 1):.3f}")
    if seg:
        print(f"  segmentation CPU ms per frame: median {np.median(seg):.1f}, p90 {np.percentile(seg, 90):.1f}")
    if source.groundtruth is not None and system.n_tracked() >= 3:
        print(f"  tracked {system.n_tracked()}/{n}, ATE {ate(source.groundtruth, system.final_trajectory()).stats.rmse * 100:.2f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
