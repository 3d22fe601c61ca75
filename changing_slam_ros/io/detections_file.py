"""Per-frame detections from a file: the simulator's oracle `detections.json` beside a TUM folder.

Format (`changing_slam_ros sim oracle detections v1`, written by `sim/writer.py`)::

    {"format": ..., "frames": [{"stamp_ns": int, "detections": [{"box_xyxy": [x0, y0, x1, y1],
      "class_id": int, "score": float, ...}, ...]}, ...]}

Boxes are pixels with the max exclusive; class ids are 0-based COCO, as `core.dynamic.detector.Detection` has them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from changing_slam_ros.core.dynamic.detector import Detection
from changing_slam_ros.errors import DatasetError

DETECTIONS_FILE_NAME = "detections.json"


class DetectionsFile:
    """Detections per frame stamp (ns), looked up exactly or within `max_diff_ns`."""

    def __init__(self, frames: dict[int, tuple[Detection, ...]], path: Path, max_diff_ns: int = 1_000_000) -> None:
        self.frames = frames
        self.path = path
        self.max_diff_ns = max_diff_ns
        self._stamps = sorted(frames)

    def __len__(self) -> int:
        return len(self.frames)

    def for_stamp(self, stamp_ns: int) -> tuple[Detection, ...]:
        """The detections of the frame at `stamp_ns`; DatasetError when the file has no such frame."""
        found = self.frames.get(stamp_ns)
        if found is not None:
            return found
        import bisect

        i = bisect.bisect_left(self._stamps, stamp_ns)
        near = [s for s in self._stamps[max(i - 1, 0) : i + 1] if abs(s - stamp_ns) <= self.max_diff_ns]
        if not near:
            raise DatasetError(f"{self.path}: no detections for the frame at stamp {stamp_ns} ns")
        return self.frames[near[0]]


def find_detections_file(source: str | Path) -> Path:
    """`detections.json` inside a TUM folder (or beside a bag file); DatasetError when absent."""
    p = Path(source)
    candidate = (p if p.is_dir() else p.parent) / DETECTIONS_FILE_NAME
    if not candidate.is_file():
        raise DatasetError(f"{candidate}: no oracle detections file (give one with --detections-file)")
    return candidate


def read_detections_file(path: str | Path) -> DetectionsFile:
    """Parse a detections JSON file; errors name the file and the field."""
    p = Path(path)
    try:
        doc: Any = json.loads(p.read_text())
    except (OSError, ValueError) as err:
        raise DatasetError(f"{p}: cannot read detections JSON ({err})") from err
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise DatasetError(f"{p}: expected an object with a 'frames' list")
    frames: dict[int, tuple[Detection, ...]] = {}
    for k, fr in enumerate(doc["frames"]):
        where = f"{p}: frames[{k}]"
        try:
            stamp = int(fr["stamp_ns"])
            dets = tuple(
                Detection(
                    tuple(float(v) for v in d["box_xyxy"]),  # type: ignore[arg-type]
                    int(d["class_id"]),
                    float(d.get("score", 1.0)),
                )
                for d in fr["detections"]
            )
        except (KeyError, TypeError, ValueError) as err:
            raise DatasetError(f"{where}: expected stamp_ns and detections with box_xyxy, class_id ({err})") from err
        if any(len(d.box_xyxy) != 4 for d in dets):
            raise DatasetError(f"{where}: box_xyxy must have 4 numbers")
        frames[stamp] = dets
    return DetectionsFile(frames, p)
