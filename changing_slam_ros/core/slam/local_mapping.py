"""Local mapping (ORB-SLAM `LocalMapping` for RGB-D): what happens when tracking makes a keyframe.

1. insert the keyframe (its tracked points gain an observation) and update the covisibility graph;
2. create map points from its unmatched keypoints with valid depth (back-projected, RGB-D), and from
   depth-less keypoints matched and triangulated with its best covisible keyframes (`triangulation`);
   then fuse duplicates with the covisible keyframes (`map_fusion`);
3. cull recently created points that tracking rarely finds (found / visible < 0.25) or that fewer than
   `min_observations` keyframes (`triangulation.min_observations` for triangulated points) see after two
   more keyframes;
4. local bundle adjustment with gtsam (`backend.local_ba`); in real time `ba_stop` may cut it short when a
   new keyframe waits (ORB-SLAM's abort flag; the split graph's local_mapping node sets it, offline never);
5. cull keyframes whose points are 90 % seen by at least three other keyframes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.backend.local_ba import SOLVERS, FactorCache, LocalBAConfig, LocalBAResult, local_bundle_adjust
from changing_slam_ros.core.map.keyframe import Keyframe
from changing_slam_ros.core.movers.keyframe_segmentation import (
    KeyframeSegmentationConfig, KeyframeSegmentationResult, segment_keyframe_window,
)
from changing_slam_ros.core.slam.map_fusion import fuse_into, refresh_points
from changing_slam_ros.core.slam.map_merging import MergeConfig
from changing_slam_ros.core.features.orb_features import FeatureConfig
from changing_slam_ros.core.geometry.se3 import transform_points
from changing_slam_ros.core.map.slam_map import Atlas, SlamMap
from changing_slam_ros.core.slam.triangulation import TriangulationConfig, TwoView, triangulate_pair
from changing_slam_ros.errors import ConfigError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MappingConfig:
    """YAML section `mapping:`.

    - `max_new_point_depth_m`: keypoints deeper than this make no new point.
    - `cull_found_ratio`, `min_observations`: recent point culling (ORB-SLAM 0.25, 3 with stereo observations counted twice).
    - `local_ba`: enable local BA; `ba_window`, `ba_max_fixed`, `ba_iterations`, `ba_max_points`: its size and effort;
      `ba_disparity_sigma_ratio`: sigma of a keypoint's depth as disparity bf / depth, in units of its pixel sigma
      (`backend.local_ba.stereo_noise`): a property of the depth sensor. 1 (default) weighs a Kinect-class depth
      about as ORB-SLAM's virtual stereo does (0 = exactly ORB-SLAM's independent u_l, u_r, v); the simulator's
      exact depth takes 0.25 (config/sim.yaml). `ba_solver`: "gtsam"
      (default: its Levenberg-Marquardt on the factor graph) or "schur" (`backend.schur_lm`: the same cost and
      gtsam's LM policy in numpy, points eliminated first; ~0.35x the solver's CPU, trajectories within 1e-7 m of
      gtsam's on the simulated bags; what `changing-slam graph` uses in real time, where CPU is short;
      `bench/bench_local_mapping_cpu.py` measures both).
    - `keyframe_culling`: enable; `redundancy`: fraction of points seen by >= 3 others (0.9).
    - `fuse_neighbours`: covisible keyframes searched for duplicated points (0 = off); `fuse_radius_px`.
    - `triangulation`: points from depth-less keypoints (nested section, see `TriangulationConfig`).
    - `merge`: welding two maps of the Atlas that share a place (nested section, see `map_merging.MergeConfig`).
    - `segmentation`: moving points over the last keyframes, culled before local BA (slow movers, Dai et al.;
      nested section, see `keyframe_segmentation`; off by default).
    """

    max_new_point_depth_m: float = 6.0
    cull_found_ratio: float = 0.25
    min_observations: int = 2
    local_ba: bool = True
    ba_window: int = 10
    ba_max_fixed: int = 10
    ba_iterations: int = 5
    ba_max_points: int = 3000
    ba_disparity_sigma_ratio: float = 1.0
    ba_solver: str = "gtsam"
    keyframe_culling: bool = True
    redundancy: float = 0.9
    fuse_neighbours: int = 10
    fuse_radius_px: float = 3.0
    triangulation: TriangulationConfig = field(default_factory=TriangulationConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)
    segmentation: KeyframeSegmentationConfig = field(default_factory=KeyframeSegmentationConfig)

    def __post_init__(self) -> None:
        if self.ba_solver not in SOLVERS:
            raise ConfigError(f"mapping.ba_solver: {self.ba_solver!r} unknown; expected one of {', '.join(SOLVERS)}")


@dataclass
class MappingStats:
    new_points: int = 0
    triangulated: int = 0
    fused: int = 0
    culled_points: int = 0
    culled_keyframes: list[int] = field(default_factory=list)
    ba: LocalBAResult | None = None
    segmentation: KeyframeSegmentationResult | None = None


class LocalMapper:
    """Owns map growth and local optimisation for `atlas.current`."""

    def __init__(self, atlas: Atlas, features: FeatureConfig, config: MappingConfig | None = None) -> None:
        self.atlas = atlas
        self.fcfg = features
        self.cfg = config or MappingConfig()
        self.scales = features.level_scales()
        # (kf id that created, point ids, observations needed to survive): points still on probation
        self._recent: list[tuple[int, npt.NDArray[np.int64], int]] = []
        self._recent_map_id = atlas.current.id
        self.triangulated: dict[int, list[npt.NDArray[np.int64]]] = {}  # map id -> ids of triangulated points
        # Real time only: asked between local BA iterations; True (a new keyframe waits) ends the BA with what it
        # reached (`local_ba.optimise`). None (offline, lossless graph): the BA always runs to the end.
        self.ba_stop: Callable[[], bool] | None = None
        self.ba_factors = FactorCache()  # the last local BA's gtsam factors, reused where unchanged (exact)

    @property
    def map(self) -> SlamMap:
        return self.atlas.current

    def process(self, kf: Keyframe) -> MappingStats:
        m = self.map
        stats = MappingStats()
        if m.id != self._recent_map_id:  # a new map of the Atlas: recent points belong to the old one
            self._recent = []
            self._recent_map_id = m.id
        # 1. Insert.
        m.add_keyframe(kf)
        # 2. New points from depth.
        stats.new_points = self._create_points(kf)
        m.update_connections(kf.id)
        # 2a. New points by triangulation with the covisible keyframes (keypoints without depth).
        if self.cfg.triangulation.enabled:
            stats.triangulated = self._triangulate(kf)
            stats.new_points += stats.triangulated
        # 2b. Fuse duplicates with the neighbours, refresh descriptors and viewing directions.
        if self.cfg.fuse_neighbours > 0:
            stats.fused = self._fuse(kf)
            m.update_connections(kf.id)
        # 3. Recent point culling.
        stats.culled_points = self._cull_points(kf.id)
        # 3a. Moving points over the last keyframes culled (slow movers; `keyframe_segmentation`).
        if self.cfg.segmentation.enabled:
            stats.segmentation = segment_keyframe_window(m, kf.id, self.cfg.segmentation)
        # 4. Local BA.
        if self.cfg.local_ba and len(m.keyframes) > 1:
            stats.ba = local_bundle_adjust(m, kf.id, self.ba_config(), self.ba_stop, self.ba_factors)
            m.update_connections(kf.id)
        # 5. Keyframe culling.
        if self.cfg.keyframe_culling:
            stats.culled_keyframes = self._cull_keyframes(kf.id)
        return stats

    def ba_config(self) -> LocalBAConfig:
        """The local BA settings of this mapper (also used for the welding BA of a map merge)."""
        return LocalBAConfig(
            self.cfg.ba_window, self.cfg.ba_max_fixed, self.cfg.ba_iterations, self.cfg.ba_max_points,
            self.fcfg.bf_m_px, tuple(float(s) for s in self.scales), self.cfg.ba_disparity_sigma_ratio,
            self.cfg.ba_solver,
        )

    def _fuse(self, kf: Keyframe) -> int:
        m = self.map
        bf = self.fcfg.bf_m_px
        neighbours = [m.keyframes[k] for k in m.covisible(kf.id, self.cfg.fuse_neighbours)]
        total = 0
        own = kf.point_ids[kf.point_ids >= 0]
        for nb in neighbours:
            a, b = fuse_into(m, nb, own, self.scales, bf, self.cfg.fuse_radius_px)
            total += a + b
            own = kf.point_ids[kf.point_ids >= 0]
        theirs = m.local_point_ids([nb.id for nb in neighbours])
        theirs = theirs[~np.isin(theirs, kf.point_ids)]
        a, b = fuse_into(m, kf, theirs, self.scales, bf, self.cfg.fuse_radius_px)
        total += a + b
        refresh_points(m, kf.point_ids[kf.point_ids >= 0], self.scales)
        return total

    def _create_points(self, kf: Keyframe) -> int:
        d = kf.depths_m.astype(np.float64)
        idx = np.flatnonzero((kf.point_ids < 0) & (d > 0) & (d <= self.cfg.max_new_point_depth_m))
        if len(idx) == 0:
            return 0
        pc = kf.camera.backproject(kf.keypoints_px[idx].astype(np.float64), d[idx])
        pw = transform_points(kf.T_world_cam, pc)
        ids = self.map.points.add(
            pw, kf.descriptors[idx], kf.id, idx, kf.T_world_cam[:3, 3], kf.octaves[idx].astype(np.int64), self.scales,
        )
        kf.point_ids[idx] = ids
        self._recent.append((kf.id, ids, self.cfg.min_observations))
        return len(ids)

    def _no_depth_point(self, kf: Keyframe) -> npt.NDArray[np.int64]:
        """Keypoints without a map point whose depth cannot make one (missing or beyond the mapping range)."""
        d = kf.depths_m
        return np.flatnonzero((kf.point_ids < 0) & ((d <= 0) | (d > self.cfg.max_new_point_depth_m)))

    def _view(self, kf: Keyframe, rows: npt.NDArray[np.int64]) -> TwoView:
        return TwoView(kf.T_world_cam, kf.camera.K, kf.keypoints_px[rows].astype(np.float64),
                       kf.octaves[rows].astype(np.int64), kf.descriptors[rows])

    def _triangulate(self, kf: Keyframe) -> int:
        """Points from `kf`'s depth-less keypoints matched with its best covisible keyframes' (see `triangulation`)."""
        m = self.map
        tcfg = self.cfg.triangulation
        made: list[npt.NDArray[np.int64]] = []
        for nb_id in m.covisible(kf.id, tcfg.neighbours):
            nb = m.keyframes.get(nb_id)
            c1 = self._no_depth_point(kf)
            if nb is None or len(c1) == 0:
                continue
            c2 = self._no_depth_point(nb)
            if len(c2) == 0:
                continue
            tri = triangulate_pair(self._view(kf, c1), self._view(nb, c2), self.scales, tcfg)
            if len(tri.rows1) == 0:
                continue
            i1, i2 = c1[tri.rows1], c2[tri.rows2]
            ids = m.points.add(tri.points_w, kf.descriptors[i1], kf.id, i1, kf.T_world_cam[:3, 3],
                               kf.octaves[i1].astype(np.int64), self.scales)
            kf.point_ids[i1] = ids
            for pid, j in zip(ids.tolist(), i2.tolist()):
                m.add_observation(pid, nb.id, j)
            made.append(ids)
        if not made:
            return 0
        ids = np.concatenate(made)
        refresh_points(m, ids, self.scales)
        self._recent.append((kf.id, ids, tcfg.min_observations))
        self.triangulated.setdefault(m.id, []).append(ids)
        return len(ids)

    def n_triangulated_alive(self) -> int:
        """Triangulated points still in the maps (not culled, fused away or erased), over all maps."""
        n = 0
        for map_id, chunks in self.triangulated.items():
            bad = self.atlas.maps[map_id].points.bad
            n += sum(int((~bad[c]).sum()) for c in chunks)
        return n

    def points_moved(self, from_map: int, to_map: int, offset: int) -> None:
        """The points of map `from_map` now live in map `to_map` with ids shifted by `offset` (a map merge)."""
        if self._recent_map_id == from_map:
            self._recent = [(k, ids + offset, n) for k, ids, n in self._recent]
            self._recent_map_id = to_map
        moved = [c + offset for c in self.triangulated.pop(from_map, [])]
        if moved:
            self.triangulated.setdefault(to_map, []).extend(moved)

    def _cull_points(self, current_kf: int) -> int:
        m = self.map
        pts = m.points
        n_culled = 0
        keep: list[tuple[int, npt.NDArray[np.int64], int]] = []
        order = sorted(m.keyframes)
        rank = {k: i for i, k in enumerate(order)}
        cur = rank.get(current_kf, len(order))
        for kf_id, ids, min_obs in self._recent:
            ids = ids[~pts.bad[ids]]
            age = cur - rank.get(kf_id, -10**6) if kf_id in rank else 10**6
            if len(ids) == 0:
                continue
            bad = pts.found_ratio(ids) < self.cfg.cull_found_ratio
            if age >= 2:
                bad |= pts.n_obs(ids) < min_obs
            for pid in ids[bad].tolist():
                m.erase_point(pid)
            n_culled += int(bad.sum())
            if age < 3:
                keep.append((kf_id, ids[~bad], min_obs))
        self._recent = keep
        return n_culled

    def _cull_keyframes(self, current_kf: int) -> list[int]:
        m = self.map
        culled: list[int] = []
        for k in m.covisible(current_kf):
            if k == m.origin_kf_id or k == current_kf or k not in m.keyframes:
                continue
            ids = m.keyframes[k].point_ids
            ids = ids[ids >= 0]
            ids = ids[m.points.usable()[ids]]
            if len(ids) < 20:
                continue
            redundant = (m.points.n_obs(ids) >= 4).sum()  # itself + at least three others
            if redundant > self.cfg.redundancy * len(ids) and m.remove_keyframe(k):
                culled.append(k)
        return culled
