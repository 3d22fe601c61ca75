"""Keypoint filtering against simulated ground truth (prints a table, never asserts).

    .venv/bin/python bench/eval_dynamic_filtering_sim.py [--scenarios walking_xyz ...] [--step 5] [--variants ...]
        [--detector oracle|ssd]

`--detector ssd` runs the shipped SSD-MobileNetV2 on the rendered colour images instead of the oracle boxes
(score >= 0.3), which also reports the detector's person recall on the simulated people.

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import cv2
import numpy as np

from changing_slam_ros.core.dynamic.detector import Detection, Detector, DetectorConfig, iou_matrix
from changing_slam_ros.core.dynamic.dynamic_objects import DynamicObjectsConfig, DynamicObjectTracker
from changing_slam_ros.core.dynamic.keypoint_classification import KeypointClassificationConfig
from changing_slam_ros.sim.oracle import oracle_detections
from changing_slam_ros.sim.renderer import SimRenderer
from changing_slam_ros.sim.scenarios import build_scenario
from changing_slam_ros.sim.scene import SceneSpec

WALKING = ["walking_xyz", "walking_static", "walking_rpy", "walking_halfsphere", "sitting_xyz"]
BASE = KeypointClassificationConfig()
NO_EKF = 10**9  # min_updates never reached: movable objects are never found static
# The ablation's rows (bench/ablation_dynamic.py) at keypoint level (ATE needs the tracking integration):
ABLATION: dict[str, DynamicObjectsConfig] = {
    "+detection_filtering": DynamicObjectsConfig(classification=replace(BASE, repopulation=False), min_updates=NO_EKF),
    "+repopulation": DynamicObjectsConfig(min_updates=NO_EKF),
    "+ekf_doc": DynamicObjectsConfig(),
}
VARIANTS: dict[str, KeypointClassificationConfig] = {
    "default": BASE,
    "no_repopulation": replace(BASE, repopulation=False),
    "centre_band_check": replace(BASE, check_centre_in_object_band=True),
    "no_depth_window": replace(BASE, keypoint_depth_window_px=0),
    "depth_window_1px": replace(BASE, keypoint_depth_window_px=1),
    "no_occlusion_checks": replace(BASE, check_centre_in_object_band=False, centre_occlusion_margin_m=1e9, max_depth_std_m=1e9),
    "person_margin_0.5": replace(BASE, background_margin_m={**BASE.background_margin_m, 0: 0.5}),
    "person_margin_1.0": replace(BASE, background_margin_m={**BASE.background_margin_m, 0: 1.0}),
}


def main() -> int:
    """Parse the options, measure, print the table.

    For each walking scenario, frames are rendered with the simulator, ORB keypoints detected, oracle detections
    taken from the instance masks, and `DynamicObjectTracker` run with the ground-truth camera pose. A keypoint's
    truth is the actor under its pixel: a moving actor (person) = dynamic, anything else = static. Reported:
    - `leak`: dynamic keypoints used for tracking / dynamic keypoints (must be ~0);
    - `kept`: static keypoints used for tracking / static keypoints;
    - `kept_in_person_boxes`: static keypoints inside person boxes used (what repopulation recovers);
    The "plain" system (no dynamic handling) uses every keypoint: leak 100 %, kept 100 %.
    `--variants +detection_filtering +repopulation +ekf_doc` gives the keypoint-level rows of the ablation (`bench/ablation_dynamic.py`).
    - `ms`: classification + association + EKF per frame.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=WALKING)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), help=f"of {', '.join([*ABLATION, *VARIANTS])}")
    parser.add_argument("--step", type=int, default=5, help="use every step-th frame (30 fps scenarios)")
    parser.add_argument("--frames", type=int, default=900, help="frames of each scenario considered")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--detector", choices=["oracle", "ssd"], default="oracle")
    args = parser.parse_args()
    orb = cv2.ORB_create(1000)
    detector = Detector(DetectorConfig()) if args.detector == "ssd" else None
    print(f"{'scenario':20s} {'variant':20s} {'leak %':>7s} {'kept %':>7s} {'kept in person boxes %':>23s} {'ms':>6s}")
    for name in args.scenarios:
        sc = build_scenario(name, args.seed)
        spec = SceneSpec(sc.room, sc.actors, sc.fovy_deg, 640, 480, shadows=False)
        frames = []
        recall_hits = [0, 0]
        with SimRenderer(spec) as renderer:
            for k in range(0, min(args.frames, sc.n_frames()), args.step):
                t_s = k / sc.fps
                T = sc.camera.pose_at(t_s)
                f = renderer.render(T, [a.track.pose_at(t_s) for a in sc.actors])
                oracle = [Detection(tuple(float(c) for c in d.box_xyxy), d.class_id, 1.0)
                          for d in oracle_detections(f.instance_ids, sc.actors)]  # fmt: skip
                dets = oracle if detector is None else list(detector.detect(f.rgb).detections)
                persons_true = np.array([d.box_xyxy for d in oracle if d.class_id == 0]).reshape(-1, 4)
                persons_found = np.array([d.box_xyxy for d in dets if d.class_id == 0]).reshape(-1, 4)
                if len(persons_true):
                    found = iou_matrix(persons_true, persons_found).max(axis=1, initial=0.0) >= 0.5
                    recall_hits[0] += int(found.sum())
                    recall_hits[1] += len(persons_true)
                kps = np.array([kp.pt for kp in orb.detect(cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY), None)])
                u = np.clip(np.rint(kps[:, 0]).astype(int), 0, 639)
                v = np.clip(np.rint(kps[:, 1]).astype(int), 0, 479)
                moving = np.array([False] + [a.moving for a in sc.actors])[f.instance_ids[v, u]]
                frames.append((int(t_s * 1e9), kps, f.depth_m, dets, T, moving))
        print(f"{name}: person boxes found by the {args.detector} detector (IoU >= 0.5): "
              f"{recall_hits[0]}/{recall_hits[1]}")
        for variant in args.variants:
            config = ABLATION.get(variant) or DynamicObjectsConfig(classification=VARIANTS[variant])
            tracker = DynamicObjectTracker(renderer.camera, config)
            dyn = dyn_used = sta = sta_used = box_sta = box_sta_used = 0
            ms = []
            for stamp, kps, depth, dets, T, moving in frames:
                t0 = time.perf_counter()
                res = tracker.process(stamp, kps, depth, dets, T)
                ms.append((time.perf_counter() - t0) * 1e3)
                used = res.use_for_tracking
                person_box = np.zeros(len(kps), bool)
                for d in dets:
                    if d.class_id == 0:
                        x0, y0, x1, y1 = d.box_xyxy
                        person_box |= (kps[:, 0] >= x0) & (kps[:, 0] < x1) & (kps[:, 1] >= y0) & (kps[:, 1] < y1)
                dyn += moving.sum()
                dyn_used += (used & moving).sum()
                sta += (~moving).sum()
                sta_used += (used & ~moving).sum()
                box_sta += (person_box & ~moving).sum()
                box_sta_used += (person_box & ~moving & used).sum()
            print(f"{name:20s} {variant:20s} {100 * dyn_used / max(dyn, 1):7.2f} {100 * sta_used / max(sta, 1):7.1f} "
                  f"{100 * box_sta_used / max(box_sta, 1):23.1f} {np.median(ms):6.2f}"
                  f"   ({dyn} dynamic, {sta} static, {box_sta} static in person boxes, {len(frames)} frames)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
