"""MapObject (Changing-SLAM §4.2) and the configuration of the object layer (§4.6-4.8).

A MapObject groups the map points created inside the boxes of one detected object: its image boxes, COCO
class (0-based), map point ids, centroid, 3D box (§4.2, `box_extent`), global id, persistence belief
(§4.6), the keyframe where it was last seen and whether its points are active (§4.7). The centroid is
a weighted mean of its points (ours, `object_point_weights.py`); see `MapObject`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from changing_slam_ros.config import section
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


# Typical depth in metres (the smaller horizontal side) of indoor COCO classes (0-based ids), for box completion:
# round figures of common furniture and household objects, not fitted to the simulator's models. Chairs (56) are
# left out: an open frame is seen through (legs, seat and back from one side), so its points already span most of
# its depth, and the prior only pushed it back: on the six PUC-like renders, with chair 0.5 m, the chairs' box
# centres went from 0.5-10.9 cm to 0.9-15.4 cm from the ground truth's.
TYPICAL_CLASS_DEPTH_M: dict[int, float] = {
    13: 0.4,   # bench
    24: 0.2,   # backpack
    26: 0.12,  # handbag
    28: 0.25,  # suitcase
    39: 0.07,  # bottle
    41: 0.08,  # cup
    57: 0.85,  # couch
    58: 0.35,  # potted plant
    59: 1.4,   # bed
    60: 0.75,  # dining table
    61: 0.55,  # toilet
    62: 0.1,   # tv
    63: 0.25,  # laptop
    68: 0.35,  # microwave
    69: 0.6,   # oven
    71: 0.45,  # sink
    72: 0.65,  # refrigerator
    73: 0.2,   # book
    75: 0.12,  # vase
    77: 0.2,   # teddy bear
}

# COCO classes (0-based) whose seen face may lie in a wall plane as real objects: flat or thin things that hang on
# or lean against a wall (a clock, a screen, a book on a shelf) and appliances built in flush with a wall of
# cupboards (the oven's door in the cupboard fronts). Every other class is 3-D, so a detection of it whose points
# lie in a wall is a picture of one (a poster of a plant, a photo of a person).
FLAT_CLASSES: tuple[int, ...] = (
    62,  # tv (screens, monitors)
    63,  # laptop
    64,  # mouse
    65,  # remote
    66,  # keyboard
    67,  # cell phone
    68,  # microwave (built in)
    69,  # oven (built in)
    72,  # refrigerator (built in)
    73,  # book
    74,  # clock
    76,  # scissors
)

# Evidence kept per MapObject for the change report: at most this many belief steps and sighting keyframes, the
# first EVIDENCE_HEAD of them always (how it was first mapped) and the most recent ones after that.
EVIDENCE_CAP = 24
EVIDENCE_HEAD = 4


@dataclass(frozen=True)
class ObjectMapConfig:
    """YAML section `objects:`. The paper names these thresholds but gives no values; ours are chosen
    for the simulated PUC-USP-like scenes and documented beside each field.

    Long-term data association (§4.7, Algorithm 1):
    - `ltda_threshold_m`: a candidate closer than this (centroid to centroid, same class) is the mapped object.
    - `n_keyframes_unseen`: N of Algorithm 1, an object is belief-updated only if not seen in the last N keyframes.
    - `belief_threshold`: BeliefThreshold; below it an object's points are inactive. Above 0.5 so that new
      objects (belief 0.5) start inactive, as §4.7 says ("initially all MapPoints that belong to MapObjects
      are inactive").
    Persistence filter (§4.6, see `persistence_filter.py` for the model):
    - `p_detect`: probability that a present object in view is detected and associated.
    - `p_false`: probability that a same-class candidate appears at an absent object's place.
    - `sigma_point_m`, `sigma_floor_m`, `sigma_size_fraction`: centroid covariance
      (sigma_point^2 / n_points + sigma_floor^2 + (sigma_size_fraction * largest box side)^2) I3; the last
      term is ours: a partial view of a large object (a table) moves its candidate centroid by a good
      fraction of its size, however many points the mapped object has.
    - `belief_min`, `belief_max`: the belief is clamped to [belief_min, belief_max] inside (0, 1).
    Visibility ("should have been seen", `object_visibility.py`):
    - `margin_px`: the centroid must project this far inside the image border.
    - `min_range_m`, `max_range_m`: distance of the centroid along the optical axis.
    - `occlusion_tolerance_m`: measured depth may be this much (plus half the object's largest box side)
      in front of the centroid before the object counts as occluded.
    - `depth_window_px`: half-size of the window whose median depth is read at the projected centroid.
    - `min_projected_area_fraction`, `min_projected_area_px`: an object whose box would cover less than
      max(min_projected_area_fraction * image width * height, min_projected_area_px) pixels ((fx / depth)^2
      times the product of its two largest box sides) is not expected: detectors miss objects of a few pixels.
      The limit is a fraction of the image because detectors resize their input to a fixed size (SSD 300x300,
      YOLO's letterbox), so their smallest reliable box scales with the image. 5.2e-4 is the oracle
      detector's 40-pixel minimum at 320x240 (the resolution the changing-scene bench runs at): 40 px there,
      160 px at 640x480, 10 px at 160x120. A fixed 100 px (the earlier default) never expected a 10 cm cup
      2.5 m away at 320x240 (under 100 px), so a removed cup was never missed and kept belief 0.5.
      `min_projected_area_px` (0: none) is an absolute floor for a detector with a fixed pixel minimum.
    - `truncated_views`: a candidate whose box touches the image border (a close-up view cut by the
      image) makes a new object when no mapped object of its class is within `ltda_threshold_m`; near one,
      its map points are labelled with it and follow its active flag, but stay out of its centroid and box
      and update no belief (`long_term_association`). §4.2 gives every map point created in a box its
      MapObject, inactive until confirmed; without this an object seen only close up (its box cut by the
      image bottom) had no MapObject and its map points stayed active for place recognition:
      `one_chair_closeup` with the chair's keypoints passed as static closed the wrong loop on the moved
      chair with the layer on. On by default: a camera at a robot's height (1 m, about level) sees the lower part
      of a floor-standing object leave the image bottom within about 2 m, so in a room most furniture is seen
      cut in every view. On the changing-room family (tuning seeds 0-9, oracle boxes) 21 of the 51 objects
      present at the end were never boxed whole in any frame at their final place and 22 never in a keyframe:
      with cut views skipped none of them had a MapObject (recall 0.37 -> 0.67 with them on, camera ATE within 0.25 cm on
      every seed).
      In the full pipeline a cut box gives the EKF no measurement (`dynamic_objects.cut_box_border_px`), so its
      object stays UNKNOWN and its keypoints make no map points: its candidate is depth samples, and turning
      this on deactivates no map point tracking used. Without the dynamic filter (`--no-dynamic`) the cut boxes'
      map points are deactivated: there, on the six PUC-like renders, it cost camera ATE up to +2.6 cm
      (vanishing 3.8 -> 6.5 cm) and moved shift's chair centroid 5.7 -> 26.7 cm from its volume centre (a
      chair first mapped from a cut view). Off: cut views are skipped.
    - `cut_only_views_join`: with `truncated_views`, an object known only from cut views (no whole view yet,
      `MapObject.n_observations` 0) takes the points of its later cut views into its point set (no belief
      update, no sighting), and cut boxes give depth samples like whole ones: such an object has nothing
      better, and the union of its cut views covers what was seen of it. Off: it keeps the points of the
      view that created it (a plant whose top the camera never saw: 29 map points of one keyframe).
    Centroid and box (ours, `object_point_weights.py`):
    - `centroid_voxel_m`: each occupied cube of this side counts once in the centroid (0: every point counts).
    - `structure_plane_dist_m`: object points closer than this to one of the room's large planes (floor,
      walls, table top) are structure and left out of centroid and box (0: off). The planes are fitted by
      RANSAC to the static map points (no object): up to `structure_max_planes` planes, each holding at least
      `structure_plane_min_fraction` of them, with `structure_plane_iterations` hypotheses scored on at most
      `structure_plane_max_points` points, refitted every `structure_refit_keyframes` keyframes.
    - `shared_point_dist_m`: an object's points within this of the points of another object whose box is
      smaller (the teddy bear on a chair) are that object's and left out (0: off).
    An object keeps all its points (uniform weights) when fewer than `min_points` would be left.
    Box completion (ours, `object_box_completion.py`):
    - `box_completion`: the semantic map's 3D box of an object seen from one side only is grown away from the
      camera until its depth along the mean viewing direction reaches its class's typical depth
      (`class_depth_m`, COCO 0-based id -> metres; classes not listed are never grown). A camera sees the front of
      a plant, never its back: the box of its points ends 10-15 cm short of the real one, and so does its centre.
    - `completion_min_concentration`: the object's viewing directions must agree (length of their mean unit
      vector >= this; 1 = one direction, 0.64 = spread evenly over a half circle): an object seen from around has
      its depth in its points already.
    Pictures (ours, `picture_check.py`):
    - `picture_plane_dist_m`: a candidate of a 3-D class (not in `flat_classes`) with at least
      `picture_min_fraction` of its points within this of one wall (a structure plane whose normal makes an angle
      of at least `wall_min_tilt_deg` with the map's up) is a picture on that wall, not an object (0: off). A box in
      front of the wall has its front face a box depth away; a clock or a screen (`flat_classes`) stays an object.
      Walls are structure planes whose static points span at least `wall_min_extent_m` along the plane.
    Floor patches (ours, `floor_check.py`):
    - `floor_patch_min_fraction`: a candidate of a class outside `flat_classes` with at least this fraction of its
      points within `floor_patch_dist_m` of the floor (found in the keyframes' depth scans) is the floor seen in
      its box, not an object (0: off). A chair, a plant or a suitcase stands up from the floor: on the changing
      family's tuning seeds the objects mapped right held at most 0.29 of their points there, the floor patches
      0.46 to all of them.
    Moved objects (ours, §4.7 read for a changed room):
    - `relocation`: a candidate does not merge into a lost object (belief below `semantic_min_belief`: the room
      contradicted it) when it is where that object's position model says it is not (the "seen" likelihood ratio
      of `persistence_filter` below 1, i.e. farther than about 2 centroid sigmas): the class seen at a new place
      is a new object (moved, re-found), not evidence for the old place; close to the old place it merges and
      the object is back.
    Duplicates of cut views (ours, `object_fusion.py`):
    - `fuse_cut_duplicates`: after each keyframe, two same-class objects, one at least known only from cut views
      and neither lost, whose 3D boxes share at least `fuse_min_overlap` of the smaller box's volume and that no
      keyframe saw together, are one object: a view cut by the image border has its centroid anywhere inside a
      large object (a couch), so two cut views from far-apart places lie farther apart than `ltda_threshold_m`.
      The object with whole views survives (else the older); its belief stays. Off: each stays an object.
    - `fuse_min_overlap`: intersection over the smaller box's volume, in (0, 1]; two chairs side by side share a
      sliver of their boxes, two cut views of one couch most of the smaller one.
    Semantic map (§4.8):
    - `min_points`: objects with fewer points are left out of the semantic map and never merged into.
    - `semantic_min_belief`: the semantic map holds the objects with belief >= this (0.5: every object seen
      and not contradicted), each flagged `confirmed` when its belief reaches `belief_threshold` (its points
      are then active). Objects seen in one continuous pass only stay at 0.5 (Algorithm 1 updates a belief
      only on a long-term re-observation), so with the map at `belief_threshold` a moved object seen once at
      its new place would be missing; objects some evidence contradicts (belief < 0.5) are left out. The
      semantic map answers "what is where", the threshold "which points may localise the robot" (see
      docs/changing_scenes.md).
    """

    ltda_threshold_m: float = 0.5
    n_keyframes_unseen: int = 5
    belief_threshold: float = 0.6
    p_detect: float = 0.8
    p_false: float = 0.1
    sigma_point_m: float = 1.0
    sigma_floor_m: float = 0.1
    sigma_size_fraction: float = 0.25
    belief_min: float = 0.01
    belief_max: float = 0.99
    margin_px: float = 20.0
    min_range_m: float = 0.3
    max_range_m: float = 4.0
    occlusion_tolerance_m: float = 0.2
    depth_window_px: int = 2
    min_projected_area_fraction: float = 5.2e-4
    min_projected_area_px: float = 0.0
    min_points: int = 5
    semantic_min_belief: float = 0.5
    truncated_views: bool = True
    cut_only_views_join: bool = True
    centroid_voxel_m: float = 0.025
    structure_plane_dist_m: float = 0.02
    structure_plane_min_fraction: float = 0.05
    structure_max_planes: int = 6
    structure_plane_iterations: int = 150
    structure_plane_max_points: int = 4000
    structure_refit_keyframes: int = 5
    shared_point_dist_m: float = 0.03
    box_completion: bool = True
    class_depth_m: dict[int, float] = field(default_factory=lambda: dict(TYPICAL_CLASS_DEPTH_M))
    completion_min_concentration: float = 0.75
    picture_plane_dist_m: float = 0.04
    picture_min_fraction: float = 0.8
    wall_min_tilt_deg: float = 60.0
    wall_min_extent_m: float = 1.0
    flat_classes: tuple[int, ...] = FLAT_CLASSES
    floor_patch_dist_m: float = 0.04
    floor_patch_min_fraction: float = 0.4
    relocation: bool = True
    fuse_cut_duplicates: bool = True
    fuse_min_overlap: float = 0.5

    def __post_init__(self) -> None:
        where = "objects"
        if any(v < 0.0 for v in self.class_depth_m.values()):
            raise ConfigError(f"{where}.class_depth_m: expected depths >= 0, got {self.class_depth_m}")
        if not 0.0 <= self.completion_min_concentration <= 1.0:
            raise ConfigError(f"{where}.completion_min_concentration: expected within [0, 1], got "
                              f"{self.completion_min_concentration}")
        if self.picture_plane_dist_m < 0.0 or not 0.0 < self.picture_min_fraction <= 1.0:
            raise ConfigError(f"{where}.picture_plane_dist_m / picture_min_fraction: expected >= 0 / within (0, 1], "
                              f"got {self.picture_plane_dist_m} / {self.picture_min_fraction}")
        if self.floor_patch_dist_m <= 0.0 or not 0.0 <= self.floor_patch_min_fraction <= 1.0:
            raise ConfigError(f"{where}.floor_patch_dist_m / floor_patch_min_fraction: expected > 0 / within [0, 1], "
                              f"got {self.floor_patch_dist_m} / {self.floor_patch_min_fraction}")
        if not 0.0 <= self.wall_min_tilt_deg <= 90.0:
            raise ConfigError(f"{where}.wall_min_tilt_deg: expected within [0, 90], got {self.wall_min_tilt_deg}")
        if not 0.0 < self.fuse_min_overlap <= 1.0:
            raise ConfigError(f"{where}.fuse_min_overlap: expected within (0, 1], got {self.fuse_min_overlap}")
        if self.ltda_threshold_m <= 0.0:
            raise ConfigError(f"{where}.ltda_threshold_m: expected > 0, got {self.ltda_threshold_m}")
        if self.n_keyframes_unseen < 0:
            raise ConfigError(f"{where}.n_keyframes_unseen: expected >= 0, got {self.n_keyframes_unseen}")
        if not 0.0 < self.belief_min < self.belief_max < 1.0:
            raise ConfigError(f"{where}.belief_min / belief_max: expected 0 < min < max < 1, got "
                              f"{self.belief_min} / {self.belief_max}")
        if not self.belief_min <= self.belief_threshold <= self.belief_max:
            raise ConfigError(f"{where}.belief_threshold: expected within [belief_min, belief_max], got "
                              f"{self.belief_threshold}")
        for name in ("p_detect", "p_false"):
            v = getattr(self, name)
            if not 0.0 < v < 1.0:
                raise ConfigError(f"{where}.{name}: expected a probability in (0, 1), got {v}")
        if self.p_detect <= self.p_false:
            raise ConfigError(f"{where}.p_detect ({self.p_detect}) must exceed p_false ({self.p_false}): "
                              "otherwise seeing an object would lower its belief")
        if self.sigma_point_m <= 0.0 or self.sigma_floor_m < 0.0 or self.sigma_size_fraction < 0.0:
            raise ConfigError(f"{where}.sigma_point_m / sigma_floor_m / sigma_size_fraction: expected > 0 / >= 0 / >= 0")
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise ConfigError(f"{where}.min_range_m / max_range_m: expected 0 <= min < max")
        if (self.margin_px < 0.0 or self.occlusion_tolerance_m < 0.0 or self.depth_window_px < 0
                or self.min_projected_area_px < 0.0):
            raise ConfigError(f"{where}.margin_px, occlusion_tolerance_m, depth_window_px, min_projected_area_px: "
                              "expected >= 0")
        if not 0.0 <= self.min_projected_area_fraction < 1.0:
            raise ConfigError(f"{where}.min_projected_area_fraction: expected within [0, 1), got "
                              f"{self.min_projected_area_fraction}")
        if not self.belief_min <= self.semantic_min_belief <= self.belief_max:
            raise ConfigError(f"{where}.semantic_min_belief: expected within [belief_min, belief_max], got "
                              f"{self.semantic_min_belief}")
        if self.min_points < 1:
            raise ConfigError(f"{where}.min_points: expected >= 1, got {self.min_points}")
        for name in ("centroid_voxel_m", "structure_plane_dist_m", "shared_point_dist_m"):
            if getattr(self, name) < 0.0:
                raise ConfigError(f"{where}.{name}: expected >= 0 (0: off), got {getattr(self, name)}")
        if not 0.0 < self.structure_plane_min_fraction <= 1.0:
            raise ConfigError(f"{where}.structure_plane_min_fraction: expected within (0, 1], got "
                              f"{self.structure_plane_min_fraction}")
        for name in ("structure_max_planes", "structure_plane_iterations", "structure_plane_max_points",
                     "structure_refit_keyframes"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{where}.{name}: expected >= 1, got {getattr(self, name)}")


def object_map_config(data: dict[str, Any] | None, where: str = "objects") -> ObjectMapConfig:
    """Build the config from the `objects:` mapping of a YAML file (None gives the defaults)."""
    return section(ObjectMapConfig, data, where)


def box_extent(points_w: F64, fraction: float = 0.05) -> tuple[F64, F64]:
    """Robust axis-aligned box of points (N, 3): (centre (3,), dimensions (3,)) in metres.

    Per axis: median of the `fraction` largest minus median of the `fraction` smallest coordinates
    (at least one point each side). Empty input gives zeros.

    §4.2: "the median of the 5 % maximum and minimum x, y and z coordinates"; this trims stray points
    the way a plain max - min would not.
    """
    pts = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(3), np.zeros(3)
    k = max(1, int(round(fraction * len(pts))))
    srt = np.sort(pts, axis=0)
    lo = np.median(srt[:k], axis=0)
    hi = np.median(srt[-k:], axis=0)
    return (lo + hi) / 2.0, hi - lo


BoxXyxy = tuple[float, float, float, float]


@dataclass
class MapObject:
    """One object of the map. `point_ids` (N,), `points_w` (N, 3) and `point_weights` (N,) are kept row-aligned.

    `centroid_w` (3,) is the mean of `points_w` weighted by `point_weights` (None: all 1); `box_center_w` (3,)
    and `box_size_m` (3,) the robust world-axis-aligned box (see `box_extent`) of the points of positive weight. Boxes are pixel (x_min, y_min, x_max, y_max).
    `n_observations`: keyframes whose whole (untruncated) view went into the object; 0 for an object known
    only from views cut by the image border so far. `view_sum_w` (3,): sum of the unit vectors from the camera
    to the view's centroid over the views whose points went into the object (whole views, and the cut views of
    an object known only from cut views; `add_view`), map frame; its length over `n_views` says how
    much the viewing directions agree; `up_sum_w` (3,) the sum of the up directions known at those views (the
    floor's normal, `object_box_completion.gravity_up`; zero: none known). Both serve box completion only.
    Evidence for the change report (`change_report.py`), each bounded (`EVIDENCE_CAP`): `belief_history`, rows
    (keyframe id, belief after the step, reason: "new", "seen", "missed", "session"), and `seen_keyframes`, the
    keyframes whose whole view went into the object, ascending.

    Points are active when the belief is >= `belief_threshold` (§4.7). Point weights (ours): without
    weights (`point_weights` None) every point weighs 1, the paper's mean. The object layer sets them
    (`object_point_weights.py`): 0 for a point on one of the room's large planes or on a smaller object
    inside the box, 1 / (its voxel's count) otherwise, so that each occupied `centroid_voxel_m` cube of the
    object's surface counts once however many views sampled it. The box is centred half-way between the
    per-axis medians (`box_center_w`), which for a surface-sampled object differs from the centroid (the
    centroid leans toward the side the camera saw).
    """

    id: int
    class_id: int
    first_box_xyxy: BoxXyxy
    current_box_xyxy: BoxXyxy
    first_keyframe: int
    last_seen_keyframe: int
    belief: float = 0.5
    active: bool = False
    point_ids: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    points_w: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    centroid_w: F64 = field(default_factory=lambda: np.zeros(3))
    box_center_w: F64 = field(default_factory=lambda: np.zeros(3))
    box_size_m: F64 = field(default_factory=lambda: np.zeros(3))
    last_belief_update_keyframe: int = -1
    n_observations: int = 1
    point_weights: F64 | None = None
    view_sum_w: F64 = field(default_factory=lambda: np.zeros(3))
    n_views: int = 0
    up_sum_w: F64 = field(default_factory=lambda: np.zeros(3))
    belief_history: list[tuple[int, float, str]] = field(default_factory=list)
    seen_keyframes: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.view_sum_w = np.asarray(self.view_sum_w, dtype=np.float64).reshape(3)
        self.up_sum_w = np.asarray(self.up_sum_w, dtype=np.float64).reshape(3)
        self.set_points(self.point_ids, self.points_w, self.point_weights)

    @property
    def n_points(self) -> int:
        return len(self.point_ids)

    def set_points(self, point_ids: I64, points_w: F64, weights: F64 | None = None) -> None:
        """Replace the points (ids (N,), positions (N, 3), optional weights (N,) >= 0; None: all 1) and
        recompute centroid and box. Weights that sum to 0 count as None."""
        ids = np.asarray(point_ids, dtype=np.int64).reshape(-1)
        pts = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        if len(ids) != len(pts):
            raise ValueError(f"MapObject {self.id}: {len(ids)} point ids for {len(pts)} positions")
        w = None if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        if w is not None and (len(w) != len(pts) or not np.all(np.isfinite(w)) or np.any(w < 0.0)):
            raise ValueError(f"MapObject {self.id}: point weights must be {len(pts)} finite values >= 0")
        if w is not None and not w.sum() > 0.0:
            w = None
        self.point_ids, self.points_w, self.point_weights = ids, pts, w
        if len(pts):
            if w is None:
                self.centroid_w = pts.mean(axis=0)
                self.box_center_w, self.box_size_m = box_extent(pts)
            else:
                self.centroid_w = (w @ pts) / w.sum()
                self.box_center_w, self.box_size_m = box_extent(pts[w > 0.0])

    def add_view(self, camera_center_w: F64, centroid_w: F64, up_w: F64 | None = None) -> None:
        """Count one whole view: the camera at `camera_center_w` (3,) saw the object's points around `centroid_w`
        (3,); `up_w` (3,) unit: the map's up direction as known at that view (None: not known)."""
        d = np.asarray(centroid_w, np.float64).reshape(3) - np.asarray(camera_center_w, np.float64).reshape(3)
        n = float(np.linalg.norm(d))
        if n > 0.0 and np.isfinite(n):
            self.view_sum_w = self.view_sum_w + d / n
            self.n_views += 1
            if up_w is not None:
                self.up_sum_w = self.up_sum_w + np.asarray(up_w, np.float64).reshape(3)

    def record_belief(self, keyframe_id: int, reason: str) -> None:
        """Append the current belief to `belief_history` with the keyframe and the reason of the step."""
        self.belief_history.append((int(keyframe_id), float(self.belief), reason))
        _bound(self.belief_history)

    def record_sighting(self, keyframe_id: int) -> None:
        """Append a keyframe whose whole view went into the object to `seen_keyframes` (once per keyframe)."""
        if not self.seen_keyframes or self.seen_keyframes[-1] != int(keyframe_id):
            self.seen_keyframes.append(int(keyframe_id))
            _bound(self.seen_keyframes)

    def set_weights(self, weights: F64 | None) -> None:
        """Re-weight the current points (see `set_points`)."""
        self.set_points(self.point_ids, self.points_w, weights)

    def add_points(self, point_ids: I64, points_w: F64) -> None:
        """Union with more points (ids already held keep their stored row, new ones are appended)."""
        ids = np.asarray(point_ids, dtype=np.int64).reshape(-1)
        pts = np.asarray(points_w, dtype=np.float64).reshape(-1, 3)
        new = ~np.isin(ids, self.point_ids)
        ids, pts = ids[new], pts[new]
        _, first = np.unique(ids, return_index=True)  # a repeated id in the input is added once
        first.sort()
        w = self.point_weights
        if w is not None:  # until the layer re-weights them, new points weigh what an old point does on average
            w = np.concatenate([w, np.full(len(first), w.mean())])
        self.set_points(np.concatenate([self.point_ids, ids[first]]), np.vstack([self.points_w, pts[first]]), w)

    def refresh_points(self, positions_w: F64, keep: npt.NDArray[np.bool_] | None = None) -> None:
        """Move the points to `positions_w` (N, 3), row-aligned with `point_ids` (after bundle
        adjustment or loop correction); `keep` (N,) drops culled points."""
        pts = np.asarray(positions_w, dtype=np.float64).reshape(-1, 3)
        w = self.point_weights
        if keep is None:
            self.set_points(self.point_ids, pts, w)
        else:
            self.set_points(self.point_ids[keep], pts[keep], None if w is None else w[keep])


def _bound(rows: list[Any]) -> None:
    """Keep at most EVIDENCE_CAP rows: the first EVIDENCE_HEAD and the newest (the oldest after the head goes)."""
    while len(rows) > EVIDENCE_CAP:
        del rows[EVIDENCE_HEAD]
