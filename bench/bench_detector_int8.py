"""INT8 vs fp32 detector: CPU per detection with 1 and 2 threads, and how well the INT8 detections agree with fp32's.

    nice -n 19 .venv/bin/python bench/bench_detector_int8.py [--int8 PATH] [--frames 60] [--sims DIR ...]

Four detectors (fp32 / INT8 x 1 / 2 intra-op threads), default settings otherwise (graph cut before the NMS,
slimmed, prepared-graph cache in a fresh temporary folder, no spinning), are timed round-robin, one frame each
in turn, so load from other processes hits all alike: compare the ratios. CPU = `time.process_time` per
`detect` call (all threads). Images: the real TUM fr3_walking frames in `../shared/data/tum_fr3_walking_frames/`
and the 10 TUM fr1_xyz frames in `../shared/data/tum_fr1_xyz_first10/rgb` (calibration images of the shipped
INT8 model).

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from changing_slam_ros.core.dynamic.detector import Detection, Detector, DetectorConfig, iou_matrix  # noqa: E402
from changing_slam_ros.io.dataset import open_dataset  # noqa: E402

DATA = REPO.parent / "shared" / "data"
DEFAULT_INT8 = REPO / "changing_slam_ros" / "models" / "ssd_mobilenet_v2_coco_int8.onnx"


@dataclass
class Timed:
    name: str
    detector: Detector
    cpu_ms: list[float] = field(default_factory=list)
    wall_ms: list[float] = field(default_factory=list)


@dataclass
class Agreement:
    """Counts and differences of INT8 detections matched to fp32 ones (same class, IoU >= 0.5)."""

    fp32: int = 0
    int8: int = 0
    ious: list[float] = field(default_factory=list)
    score_deltas: list[float] = field(default_factory=list)
    box_delta_px: float = 0.0

    def add(self, ref: tuple[Detection, ...], other: tuple[Detection, ...], min_iou: float = 0.5) -> None:
        self.fp32 += len(ref)
        self.int8 += len(other)
        if not ref or not other:
            return
        iou = iou_matrix(np.array([d.box_xyxy for d in ref]), np.array([d.box_xyxy for d in other]))
        same = np.array([[a.class_id == b.class_id for b in other] for a in ref])
        iou = np.where(same, iou, 0.0)
        taken: set[int] = set()
        for i in np.argsort([-d.score for d in ref], kind="stable"):
            row = [(iou[i, j], j) for j in range(len(other)) if j not in taken and iou[i, j] >= min_iou]
            if not row:
                continue
            best, j = max(row)
            taken.add(j)
            self.ious.append(float(best))
            self.score_deltas.append(other[j].score - ref[i].score)
            delta = np.abs(np.subtract(other[j].box_xyxy, ref[i].box_xyxy)).max()
            self.box_delta_px = max(self.box_delta_px, float(delta))

    def line(self) -> str:
        n = len(self.ious)
        if not n:
            return f"0 matched (fp32 {self.fp32}, int8 {self.int8})"
        abs_d = [abs(d) for d in self.score_deltas]
        return (
            f"matched {n}/{self.fp32} fp32 ({100 * n / max(self.fp32, 1):.1f} %), {n}/{self.int8} int8 "
            f"({100 * n / max(self.int8, 1):.1f} %); IoU median {statistics.median(self.ious):.3f} min {min(self.ious):.3f}; "
            f"score delta median {statistics.median(self.score_deltas):+.3f}, |max| {max(abs_d):.3f}; "
            f"box corner delta max {self.box_delta_px:.1f} px"
        )


def pngs(folder: Path) -> list[np.ndarray]:
    return [np.ascontiguousarray(cv2.imread(str(f), cv2.IMREAD_COLOR)[:, :, ::-1]) for f in sorted(folder.glob("*.png"))]


def sim_frames(folder: Path, stride: int) -> list[np.ndarray]:
    return [np.ascontiguousarray(r.rgb) for k, r in enumerate(open_dataset(folder, "sim")) if k % stride == 0]


def main() -> int:
    """Parse the options, measure, print the table.

    Agreement, per image set, all classes: each fp32 detection is matched to the unmatched INT8 detection of its
    class with the highest IoU (>= 0.5), best fp32 score first. Printed: matched / fp32 detections (recall against
    fp32), matched / INT8 detections (precision against fp32), median and smallest IoU of the matches, median and
    largest score difference, largest box-corner difference (px). `--sims` adds simulator renders (every `--stride`
    -th frame). Prints, never asserts.
    """
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--int8", type=Path, default=DEFAULT_INT8, help="INT8 model")
    parser.add_argument("--frames", type=int, default=60, help="timed frames per detector")
    parser.add_argument("--sims", nargs="*", type=Path, default=[], help="simulator renders for the agreement")
    parser.add_argument("--stride", type=int, default=5, help="every N-th frame of each render")
    args = parser.parse_args()
    sets = {
        "TUM fr3_walking (real)": pngs(DATA / "tum_fr3_walking_frames"),
        "TUM fr1_xyz (real, calibration)": pngs(DATA / "tum_fr1_xyz_first10" / "rgb"),
    }
    timing_images = [im for ims in sets.values() for im in ims]
    with tempfile.TemporaryDirectory(prefix="bench-int8-") as tmp:
        timed = [
            Timed(f"{name} {threads} thr", Detector(DetectorConfig(model_path=path, intra_op_threads=threads, cache_dir=tmp)))
            for threads in (1, 2)
            for name, path in (("fp32", ""), ("int8", str(args.int8)))
        ]
        for t in timed:
            t.detector.detect(timing_images[0])  # warm-up
        print(f"load average before: {os.getloadavg()}")
        for i in range(args.frames):
            rgb = timing_images[i % len(timing_images)]
            for t in timed:
                c0, w0 = time.process_time(), time.perf_counter()
                t.detector.detect(rgb)
                t.cpu_ms.append((time.process_time() - c0) * 1e3)
                t.wall_ms.append((time.perf_counter() - w0) * 1e3)
        print(f"load average after: {os.getloadavg()}")
        med = statistics.median
        print(f"{args.frames} frames per detector, round-robin, {len(timing_images)} real 640x480 images")
        for t in timed:
            ref = next(r for r in timed if r.name == t.name.replace("int8", "fp32"))
            print(
                f"  {t.name:12s} CPU median {med(t.cpu_ms):6.1f} ms (x{med(t.cpu_ms) / med(ref.cpu_ms):.2f} of fp32), "
                f"wall median {med(t.wall_ms):6.1f} ms (x{med(t.wall_ms) / med(ref.wall_ms):.2f})"
            )
        fp32, int8 = timed[0].detector, timed[1].detector
        for folder in args.sims:
            sets[f"sim {folder.name} (every {args.stride}th)"] = sim_frames(folder, args.stride)
        print("agreement of INT8 with fp32 (same class, IoU >= 0.5):")
        for name, images in sets.items():
            every, person = Agreement(), Agreement()
            for rgb in images:
                a, b = fp32.detect(rgb).detections, int8.detect(rgb).detections
                every.add(a, b)
                person.add(tuple(d for d in a if d.class_id == 0), tuple(d for d in b if d.class_id == 0))
            print(f"  {name}, {len(images)} images\n    all classes: {every.line()}\n    person:      {person.line()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
