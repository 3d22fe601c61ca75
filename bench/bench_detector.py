"""Detector speed: ms per 640x480 frame, old and new settings measured in the same run (prints, never asserts).

    .venv/bin/python bench/bench_detector.py [--model PATH] [--frames 30] [--threads 2] [--int8]

Every setting gets its own `Detector`; frames are timed round-robin (one frame per setting in turn), so load
from other processes hits all settings alike and the ratios hold even when the absolute figures do not. The
images are the real TUM fr3_walking frames in `../shared/data/tum_fr3_walking_frames/` (a random image when
absent). Per part: pre-processing (input tensor), `session.run`, post-processing (decoding, NMS), as
`Detector.last_timing` reports them; CPU = process CPU time per frame, all threads together (spinning counts);
load = constructing the `Detector` (session creation; the first start of a
cached setting prepares its graph, later ones load it, so run twice to see both).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from changing_slam_ros.core.detector import Detector, DetectorConfig, class_name, iou_matrix

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


def settings(model: str, threads: int, cache_dir: str, int8: bool) -> list[Setting]:
    base = DetectorConfig(model_path=model, intra_op_threads=threads, cache_dir=cache_dir)
    out = [
        # The settings before this change: the graph's own NMS, onnxruntime's default spinning, no cache.
        Setting("old: graph NMS, spinning", DetectorConfig(model_path=model, intra_op_threads=threads,
                                                           nms="graph", allow_spinning=True, model_cache=False)),
        Setting("graph NMS, no spinning", DetectorConfig(model_path=model, intra_op_threads=threads,
                                                         nms="graph", allow_spinning=False, model_cache=False)),
        Setting("numpy NMS, spinning", DetectorConfig(model_path=model, intra_op_threads=threads,
                                                      allow_spinning=True, cache_dir=cache_dir)),
        Setting("new default: numpy NMS, no spinning", base),
    ]  # fmt: skip
    if int8:
        out.append(Setting("numpy NMS, no spinning, INT8", DetectorConfig(
            model_path=model, intra_op_threads=threads, quantize_int8=True, cache_dir=cache_dir)))  # fmt: skip
    return out


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
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="", help="ONNX detector (default: the shipped SSD-MobileNetV2)")
    parser.add_argument("--frames", type=int, default=30, help="timed frames per setting")
    parser.add_argument("--threads", type=int, default=2, help="onnxruntime intra-op threads")
    parser.add_argument("--int8", action="store_true", help="also time dynamic INT8 quantisation")
    parser.add_argument("--cache-dir", default="", help="prepared-graph cache (default: a fresh temporary folder)")
    args = parser.parse_args()
    images = load_images()
    with tempfile.TemporaryDirectory(prefix="bench-detector-") as tmp:
        cache_dir = args.cache_dir or tmp
        runs = settings(args.model, args.threads, cache_dir, args.int8)
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
        old = statistics.median(runs[0].total_ms)
        print(f"{args.frames} frames per setting, round-robin, {args.threads} threads, images: {', '.join(n for n, _ in images)}")
        med = statistics.median
        for s in runs:
            assert s.detector is not None
            print(
                f"  {s.name:40s} median {med(s.total_ms):6.1f} ms/frame (x{med(s.total_ms) / old:.2f} of old), "
                f"min {min(s.total_ms):6.1f}, CPU {med(s.cpu_ms):6.1f}; pre {med(s.pre_ms):.2f} run {med(s.run_ms):.1f} post {med(s.post_ms):.2f}; "
                f"load {s.load_s:.1f} s{' (cache hit)' if s.detector.cache_hit else ''}"
            )
        ref = runs[0].detector
        assert ref is not None
        found = ", ".join(f"{class_name(d.class_id)} {d.score:.2f}" for d in ref.detect(images[0][1]).detections)
        print(f"  detections (old) on {images[0][0]}: {found}")
        for s in runs[1:]:
            assert s.detector is not None
            print(f"  {s.name} vs old:\n{compare(ref, s.detector, images)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
