"""Multi-session evaluation: a second run started from a first run's saved map, in a room that changed.

Both runs' ground truths share the simulator's world frame, and the second run reports its poses in the
first run's map frame. The map-to-world transform `T_gt_map` is therefore fixed once, by the first run
(SE(3) alignment of its final trajectory to its ground truth), and the second run is evaluated *without*
re-aligning it: `map_frame_errors_m` is the honest "did it land in the old map" figure, next to the usual
aligned ATE.

Moved objects (`moved_places`): every simulated object whose box centre at the last frame lies more than
`min_move_m` from the one at the first frame (and that is not a mover like a walking person) gives two
places, its old and its new box centre. At each place the map objects of the same class whose centroid (moved
into the world frame by `T_gt_map`) lies within `max_distance_m` are found; the place reports the highest
belief among them (an old place is cleared only when every object left there has a low belief) and the
distance of the nearest one.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.eval.object_metrics import GroundTruthObjects

F64 = npt.NDArray[np.float64]
MAX_STAMP_GAP_S = 0.02


@dataclass(frozen=True)
class PlaceBelief:
    """One place of a moved object: `place` is "old" or "new"; `gt_center_w` (3,) its box centre (world);
    `n_objects` same-class map objects within the radius, `belief` the highest of their beliefs and `active`
    whether that one is active (None / False when there is none), `distance_m` the nearest one's centroid
    distance (None when there is none)."""

    name: str
    class_id: int
    place: str
    gt_center_w: tuple[float, float, float]
    n_objects: int
    belief: float | None
    active: bool
    distance_m: float | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def map_frame_errors_m(gt: Trajectory, est: Trajectory, T_gt_map: F64) -> F64:
    """Position errors (M,) of `est` (map frame) moved by the fixed T_gt_map (4, 4), against ground truth at the
    nearest stamp (within 20 ms; farther estimates are skipped)."""
    if len(est) == 0 or len(gt) == 0:
        return np.zeros(0)
    idx = np.searchsorted(gt.stamps_s, est.stamps_s).clip(1, max(1, len(gt) - 1))
    idx = np.minimum(idx, len(gt) - 1)
    prev = np.maximum(idx - 1, 0)
    nearer = np.where(np.abs(gt.stamps_s[prev] - est.stamps_s) < np.abs(gt.stamps_s[idx] - est.stamps_s), prev, idx)
    ok = np.abs(gt.stamps_s[nearer] - est.stamps_s) <= MAX_STAMP_GAP_S
    p = est.positions[ok] @ T_gt_map[:3, :3].T + T_gt_map[:3, 3]
    errors: F64 = np.linalg.norm(p - gt.positions[nearer[ok]], axis=1)
    return errors


def moved_places(objects: list[MapObject], T_gt_map: F64, truth: GroundTruthObjects, min_move_m: float = 0.3,
                 max_distance_m: float = 0.4) -> list[PlaceBelief]:
    """Old and new place of every object moved between the first and last ground-truth frame (see module doc)."""
    R, t = T_gt_map[:3, :3], T_gt_map[:3, 3]
    centroids = {o.id: o.centroid_w @ R.T + t for o in objects if o.n_points}
    out: list[PlaceBelief] = []
    last = len(truth.stamps_ns) - 1
    for g in truth.objects:
        first_box, last_box = g.box_at(0), g.box_at(last)
        if g.moving or first_box is None or last_box is None:
            continue
        old, new = (first_box[0] + first_box[1]) / 2, (last_box[0] + last_box[1]) / 2
        if np.linalg.norm(new - old) <= min_move_m:
            continue
        for place, centre in (("old", old), ("new", new)):
            near = [(float(np.linalg.norm(centroids[o.id] - centre)), o) for o in objects
                    if o.class_id == g.class_id and o.id in centroids]
            near = [(d, o) for d, o in near if d < max_distance_m]
            top = max(near, key=lambda p: p[1].belief)[1] if near else None
            out.append(PlaceBelief(g.name, g.class_id, place, (float(centre[0]), float(centre[1]), float(centre[2])),
                                   len(near), None if top is None else float(top.belief),
                                   bool(top is not None and top.active),
                                   min((d for d, _ in near), default=None)))
    return out
