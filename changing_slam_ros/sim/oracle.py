"""Oracle detections: the boxes a perfect detector would return, taken from the instance masks.

They let the dynamic and changing logic be tested apart from the real detector. A box is
`(x_min, y_min, x_max, y_max)` in pixels with the max exclusive (x_max = last column + 1), i.e. the
continuous extent of the visible pixels. Only objects with a COCO class produce detections (a detector
cannot name an unknown object); objects with fewer than `min_pixels` visible pixels are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.sim.actors import Actor


@dataclass(frozen=True)
class OracleDetection:
    """One object seen in one frame: instance id (actor index + 1), COCO class, box, pixel count.

    `truncated`: the box touches the image border (the object continues outside the image).
    """

    object_id: int
    class_id: int
    class_name: str
    box_xyxy: tuple[int, int, int, int]
    pixels: int
    truncated: bool

    def as_dict(self) -> dict[str, object]:
        return {
            "object_id": self.object_id, "class_id": self.class_id, "class_name": self.class_name,
            "box_xyxy": list(self.box_xyxy), "pixels": self.pixels, "truncated": self.truncated, "score": 1.0,
        }


def oracle_detections(instance_ids: npt.NDArray[np.integer], actors: tuple[Actor, ...],
                      min_pixels: int = 40, include_unknown: bool = False) -> list[OracleDetection]:
    """Detections from an instance mask (H, W) of ids (0 = room, i + 1 = actor i), ordered by id."""
    h, w = instance_ids.shape
    ids = instance_ids.ravel()
    counts = np.bincount(ids, minlength=len(actors) + 1)
    out: list[OracleDetection] = []
    for obj_id in np.nonzero(counts[1:] >= min_pixels)[0] + 1:
        actor = actors[obj_id - 1]
        if actor.class_id < 0 and not include_unknown:
            continue
        rows, cols = np.nonzero(instance_ids == obj_id)
        x0, x1, y0, y1 = int(cols.min()), int(cols.max()) + 1, int(rows.min()), int(rows.max()) + 1
        out.append(OracleDetection(
            int(obj_id), actor.class_id, actor.class_name, (x0, y0, x1, y1), int(counts[obj_id]),
            x0 == 0 or y0 == 0 or x1 == w or y1 == h,
        ))
    return out
