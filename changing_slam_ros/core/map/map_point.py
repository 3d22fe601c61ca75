"""Map points, stored as columns (struct of arrays) so that tracking can project thousands at once.

A map point has an id (its row), a world position, a representative ORB descriptor, the keyframes
observing it (`observations[id]`: keyframe id -> keypoint index), a mean viewing direction and the
scale-invariance distance range of ORB-SLAM, Changing-SLAM's class / object labels, and two flags:
`bad` (culled or fused: gone for good) and `active` (Changing-SLAM §4.6: a point on an object that
has left the scene is kept but deactivated; every consumer skips inactive points via `usable()`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MapPoint:
    """A read-only view of one map point (use `PointStore.get`)."""

    id: int
    position: F64
    descriptor: npt.NDArray[np.uint8]
    observations: dict[int, int]
    normal: F64
    min_distance_m: float
    max_distance_m: float
    class_id: int
    object_id: int
    active: bool
    bad: bool


class PointStore:
    """All map points of one map. Arrays grow by doubling; ids are never reused."""

    def __init__(self, capacity: int = 4096) -> None:
        self.size = 0
        self.positions = np.zeros((capacity, 3))
        self.descriptors = np.zeros((capacity, 32), np.uint8)
        self.normals = np.zeros((capacity, 3))
        self.min_dist = np.zeros(capacity)
        self.max_dist = np.zeros(capacity)
        self.n_visible = np.zeros(capacity, np.int64)
        self.n_found = np.zeros(capacity, np.int64)
        self.first_kf = np.zeros(capacity, np.int64)
        self.ref_kf = np.zeros(capacity, np.int64)
        self.class_id = np.zeros(capacity, np.int64)
        self.object_id = np.full(capacity, -1, np.int64)
        self.active = np.ones(capacity, bool)
        self.bad = np.zeros(capacity, bool)
        self.last_seen_frame = np.full(capacity, -1, np.int64)
        self.observations: list[dict[int, int]] = []

    _COLUMNS = (
        "positions", "descriptors", "normals", "min_dist", "max_dist", "n_visible", "n_found",
        "first_kf", "ref_kf", "class_id", "object_id", "active", "bad", "last_seen_frame",
    )

    def __len__(self) -> int:
        return self.size

    def _grow(self, needed: int) -> None:
        cap = len(self.positions)
        if needed <= cap:
            return
        new_cap = max(needed, 2 * cap)
        for name in self._COLUMNS:
            old = getattr(self, name)
            fill = {"active": True, "object_id": -1, "last_seen_frame": -1}.get(name, 0)
            new = np.full((new_cap,) + old.shape[1:], fill, dtype=old.dtype)
            new[: self.size] = old[: self.size]
            setattr(self, name, new)

    def add(
        self,
        positions_w: F64,
        descriptors: npt.NDArray[np.uint8],
        kf_id: int,
        kp_indices: npt.NDArray[np.int64],
        camera_centre_w: F64,
        octaves: npt.NDArray[np.int64],
        level_scales: F64,
    ) -> npt.NDArray[np.int64]:
        """Create points (M rows) first seen by keyframe `kf_id` at keypoints `kp_indices`; return ids (M,).

        Distances follow ORB-SLAM: `max = dist * scale[octave]`, `min = max / scale[last level]`.
        """
        m = len(positions_w)
        ids = np.arange(self.size, self.size + m, dtype=np.int64)
        self._grow(self.size + m)
        s = slice(self.size, self.size + m)
        self.positions[s] = positions_w
        self.descriptors[s] = descriptors
        view = positions_w - camera_centre_w
        dist = np.linalg.norm(view, axis=1)
        self.normals[s] = view / np.maximum(dist, 1e-9)[:, None]
        self.max_dist[s] = dist * level_scales[octaves]
        self.min_dist[s] = self.max_dist[s] / level_scales[-1]
        self.n_visible[s] = 1
        self.n_found[s] = 1
        self.first_kf[s] = kf_id
        self.ref_kf[s] = kf_id
        self.class_id[s] = 0
        self.object_id[s] = -1
        self.active[s] = True
        self.bad[s] = False
        self.last_seen_frame[s] = -1
        self.observations.extend({kf_id: int(k)} for k in kp_indices)
        self.size += m
        return ids

    def usable(self) -> npt.NDArray[np.bool_]:
        """(size,) points that tracking, mapping and loop closing may use: not bad and active."""
        return ~self.bad[: self.size] & self.active[: self.size]

    def n_obs(self, ids: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        return np.array([len(self.observations[i]) for i in ids.tolist()], dtype=np.int64)

    def found_ratio(self, ids: npt.NDArray[np.int64]) -> F64:
        return self.n_found[ids] / np.maximum(self.n_visible[ids], 1)

    def set_bad(self, ids: npt.NDArray[np.int64]) -> None:
        """Mark points as removed; the caller erases their keyframe observations."""
        self.bad[ids] = True

    def get(self, point_id: int) -> MapPoint:
        i = point_id
        if not 0 <= i < self.size:
            raise KeyError(f"map point {point_id} does not exist (map has {self.size})")
        return MapPoint(
            i, self.positions[i].copy(), self.descriptors[i].copy(), dict(self.observations[i]),
            self.normals[i].copy(), float(self.min_dist[i]), float(self.max_dist[i]),
            int(self.class_id[i]), int(self.object_id[i]), bool(self.active[i]), bool(self.bad[i]),
        )

    # Serialisation (a saved map, `io.map_file`) ------------------------------------------------------
    COLUMNS = _COLUMNS

    @classmethod
    def column_specs(cls) -> tuple[tuple[str, tuple[int, ...], np.dtype], ...]:
        """(name, per-row shape, dtype) of every column (`COLUMNS`), read off an empty store so that the
        schema is written once, in `__init__`."""
        empty = cls(1)
        return tuple((name, getattr(empty, name).shape[1:], getattr(empty, name).dtype) for name in cls._COLUMNS)

    def column_arrays(self) -> dict[str, npt.NDArray[np.generic]]:
        """Every column cut to `size` rows (copies), by column name (`COLUMNS`)."""
        return {name: getattr(self, name)[: self.size].copy() for name in self._COLUMNS}

    @classmethod
    def from_columns(cls, columns: dict[str, npt.NDArray[np.generic]], observations: list[dict[int, int]]) -> PointStore:
        """A store holding `columns` (every name of `COLUMNS`, same row count) and `observations` (one dict per
        row: keyframe id -> keypoint index). Raises ValueError naming the column whose shape is wrong."""
        size = len(observations)
        store = cls(max(size, 16))
        for name in cls._COLUMNS:
            col = np.asarray(columns[name])
            want = getattr(store, name)
            if col.shape != (size,) + want.shape[1:]:
                raise ValueError(f"column {name}: expected shape {(size,) + want.shape[1:]}, got {col.shape}")
            want[:size] = col.astype(want.dtype, copy=False)
        store.observations = [dict(o) for o in observations]
        store.size = size
        return store
