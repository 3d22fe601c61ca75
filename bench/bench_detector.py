"""Detector speed: ms per 640x480 frame, old and new settings measured in the same run (prints, never asserts).

    .venv/bin/python bench/bench_detector.py [--model PATH] [--frames 30] [--threads 2] [--int8] [--graph-nms]
        [--spin-us 500]

Every setting gets its own `Detector`; frames are timed round-robin (one frame per setting in turn), so load
from other processes hits all settings alike and the ratios hold even when the absolute figures do not. The
images are the real TUM fr3_walking frames in `../shared/data/tum_fr3_walking_frames/` (a random image when
absent). Per part: pre-processing (input tensor), `session.run`, post-processing (decoding, NMS), as
`Detector.last_timing` reports them; CPU = process CPU time per frame, all threads together (spinning counts);
load = constructing the `Detector` (creating its onnxruntime session; the first start of a
cached setting prepares its graph, later ones load it, so run twice to see both).

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.dynamic.detector import Detector, DetectorConfig, class_name, iou_matrix

FRAMES_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "tum_fr3_walking_frames"


@dataclass
class Setting:
    name: str
    config: DetectorConfig
    detector: Detector | None = None
    load_s: float = 0.0
    total_ms: list[float] = field(default_factory=list)
    pre_ms: list[float] = field(default_factory=list)
    run_ms: list[float] = field(default_factory=list)
    post_ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)


def load_images() -> list[tuple[str, np.ndarray]]:
    files = sorted(FRAMES_DIR.glob("*.png")) if FRAMES_DIR.is_dir() else []
    if not files:
        return [("random 640x480", np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8))]
    return [(f.name, np.ascontiguousarray(cv2.imread(str(f), cv2.IMREAD_COLOR)[:, :, ::-1])) for f in files]


def settings(model: str, threads: int, cache_dir: str, int8: bool, graph_nms: bool, spin_us: int) -> list[Setting]:
    base = DetectorConfig(model_path=model, intra_op_threads=threads, cache_dir=cache_dir)
    out = [
        Setting("old: numpy NMS, not slim, no spin", replace(base, slim_graph=False)),
        Setting("slim, no spinning", base),
        Setting("slim, spinning", replace(base, allow_spinning=True)),
        Setting(f"slim, spinning <= {spin_us} us", replace(base, allow_spinning=True, spin_duration_us=spin_us)),
        Setting("slim, 1 thread", replace(base, intra_op_threads=1)),
    ]
    if graph_nms:
        out.append(Setting("graph NMS, no spinning", replace(base, nms="graph", model_cache=False)))
    if int8:
        out.append(Setting("slim, no spinning, INT8", replace(base, quantize_int8=True)))
    return out


def compare_exact(reference: Detector, other: Detector, images: list[tuple[str, np.ndarray]]) -> str:
    """Over all images: do the class lists match, and the largest box (px) and score differences."""
    same, box, score, n = 0, 0.0, 0.0, 0
    for _, rgb in images:
        a, b = reference.detect(rgb).detections, other.detect(rgb).detections
        n += len(a)
        if [d.class_id for d in a] != [d.class_id for d in b]:
            continue
        same += 1
        if a:
            box = max(box, float(np.abs(np.array([d.box_xyxy for d in a]) - np.array([d.box_xyxy for d in b])).max()))
            score = max(score, max(abs(x.score - y.score) for x, y in zip(a, b)))
    return f"same classes on {same}/{len(images)} images ({n} detections), max box diff {box:.2e} px, max score diff {score:.2e}"


def compare(reference: Detector, other: Detector, images: list[tuple[str, np.ndarray]]) -> str:
    """Per image: person/chair boxes of `reference` matched in `other` (same class, IoU >= 0.5), largest score gap."""
    lines = []
    for name, rgb in images:
        a, b = reference.detect(rgb).detections, other.detect(rgb).detections
        parts = []
        for cls in (0, 56):
            da = [d for d in a if d.class_id == cls]
            db = [d for d in b if d.class_id == cls]
            if not da and not db:
                continue
            iou = iou_matrix(np.array([d.box_xyxy for d in da]).reshape(-1, 4), np.array([d.box_xyxy for d in db]).reshape(-1, 4))
            matched = int(np.sum(iou.max(axis=1) >= 0.5)) if len(db) else 0
            gap = max((abs(d.score - db[int(np.argmax(iou[i]))].score) for i, d in enumerate(da) if len(db) and iou[i].max() >= 0.5), default=0.0)
            parts.append(f"{class_name(cls)} {matched}/{len(da)} matched (other has {len(db)}), max score gap {gap:.3f}")
        lines.append(f"    {name}: " + "; ".join(parts))
    return "\n".join(lines)


def main() -> int:
    """Parse the options, measure, print the table.

    The baseline (first row) is the graph cut before its NMS, not slimmed, no spinning. The
    other rows: the slimmed graph (`detector.slim_graph`) without spinning, with spinning, with spinning bounded to
    `--spin-us` microseconds, and on one thread; `--graph-nms` adds the graph's own NMS (20-45 s to load). At the
    end every setting's detections are compared with the baseline's on all images (class lists, boxes, scores).
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="", help="ONNX detector (default: the shipped SSD-MobileNetV2)")
    parser.add_argument("--frames", type=int, default=30, help="timed frames per setting")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--int8", action="store_true", help="also time dynamic INT8 quantisation")
    parser.add_argument("--graph-nms", action="store_true", help="also time the graph's own NMS (slow to load)")
    parser.add_argument("--spin-us", type=int, default=500, help="bounded spinning setting (microseconds)")
    parser.add_argument("--cache-dir", default="", help="prepared-graph cache (default: a fresh temporary folder)")
    parser.add_argument("--images", default="", help="folder of extra PNG frames for the detection comparison")
    args = parser.parse_args()
    images = load_images()
    with tempfile.TemporaryDirectory(prefix="bench-detector-") as tmp:
        cache_dir = args.cache_dir or tmp
        runs = settings(args.model, args.threads, cache_dir, args.int8, args.graph_nms, args.spin_us)
        print(f"load average before: {os.getloadavg()}")
        for s in runs:
            t0 = time.perf_counter()
            s.detector = Detector(s.config)
            s.load_s = time.perf_counter() - t0
            s.detector.detect(images[0][1])  # warm-up
        for i in range(args.frames):
            rgb = images[i % len(images)][1]
            for s in runs:
                assert s.detector is not None
                c0, t0 = time.process_time(), time.perf_counter()
                s.detector.detect(rgb)
                s.total_ms.append((time.perf_counter() - t0) * 1e3)
                s.cpu_ms.append((time.process_time() - c0) * 1e3)
                t = s.detector.last_timing
                s.pre_ms.append(t.preprocess_ms)
                s.run_ms.append(t.run_ms)
                s.post_ms.append(t.postprocess_ms)
        print(f"load average after: {os.getloadavg()}")
        old, old_cpu = statistics.median(runs[0].total_ms), statistics.median(runs[0].cpu_ms)
        print(f"{args.frames} frames per setting, round-robin, {args.threads} threads, images: {', '.join(n for n, _ in images)}")
        med = statistics.median
        for s in runs:
            assert s.detector is not None
            print(
                f"  {s.name:40s} median {med(s.total_ms):6.1f} ms/frame (x{med(s.total_ms) / old:.2f} of old), "
                f"min {min(s.total_ms):6.1f}, CPU {med(s.cpu_ms):6.1f} (x{med(s.cpu_ms) / old_cpu:.2f}); pre {med(s.pre_ms):.2f} run {med(s.run_ms):.1f} post {med(s.post_ms):.2f}; "
                f"load {s.load_s:.1f} s{' (cache hit)' if s.detector.cache_hit else ''}"
            )
        ref = runs[0].detector
        assert ref is not None
        found = ", ".join(f"{class_name(d.class_id)} {d.score:.2f}" for d in ref.detect(images[0][1]).detections)
        print(f"  detections (old) on {images[0][0]}: {found}")
        checked = images + [(f.name, np.ascontiguousarray(cv2.imread(str(f), cv2.IMREAD_COLOR)[:, :, ::-1]))
                            for f in sorted(Path(args.images).glob("*.png"))] if args.images else images
        for s in runs[1:]:
            assert s.detector is not None
            print(f"  {s.name} vs old: {compare_exact(ref, s.detector, checked)}")
            if len(images) <= 4:
                print(compare(ref, s.detector, images))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
