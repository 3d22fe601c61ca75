"""Map points, stored as columns (struct of arrays) so that tracking can project thousands at once.

A map point has an id, a world position, a representative ORB descriptor, the keyframes observing it
(`observations[id]`: keyframe id -> keypoint index), a mean viewing direction and the scale-invariance distance
range of ORB-SLAM, Changing-SLAM's class / object labels, and two flags: `bad` (culled or fused: gone for good)
and `active` (Changing-SLAM §4.6: a point on an object that has left the scene is kept but deactivated; every
consumer skips inactive points via `usable()`). Every column is read and written by point id; the rows behind
the ids are compacted as points die (`PointStore`), so ids stay stable while storage follows the live points.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


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


class IdColumn:
    """One per-point column of a `PointStore`, indexed by point id like an array of `store.size` rows: an int,
    an id array, a bool mask over ids or a slice of the id range; `col[ids]` gathers the ids' storage rows
    (`data`, one per slot) and `col[ids] = v` scatters to them. Writes aimed at a compacted id are dropped."""

    __slots__ = ("_store", "data", "fill", "new")

    def __init__(self, store: PointStore, data: npt.NDArray[Any], fill: Any, new: Any) -> None:
        self._store = store
        self.data = data  # (slots, ...) storage rows; row 0 is the gone row
        self.fill = fill  # the gone row's value
        self.new = new  # the value of a row handed out before it is written

    def _slots(self, key: Any) -> Any:
        slot_of = self._store._slot_of  # noqa: SLF001 - the column belongs to the store
        if isinstance(key, (int, np.integer)):
            return slot_of[key]
        if isinstance(key, slice):
            return slot_of[: self._store.size][key]
        ids = np.asarray(key)
        if ids.dtype == np.bool_:
            ids = np.flatnonzero(ids)
        return slot_of[ids]

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, tuple):
            return self.data[(self._slots(key[0]), *key[1:])]
        return self.data[self._slots(key)]

    def __setitem__(self, key: Any, value: Any) -> None:
        if isinstance(key, tuple):
            self.data[(self._slots(key[0]), *key[1:])] = value
        else:
            self.data[self._slots(key)] = value
        self.data[0] = self.fill  # the gone row absorbs writes to compacted ids

    def __len__(self) -> int:
        return self._store.size

    @property
    def shape(self) -> tuple[int, ...]:
        return (self._store.size, *self.data.shape[1:])

    @property
    def dtype(self) -> np.dtype[Any]:
        return self.data.dtype

    def __array__(self, dtype: Any = None, copy: Any = None) -> npt.NDArray[Any]:
        raise TypeError("a PointStore column is indexed by point ids: take col[ids] or col[:store.size]")


class IdObservations:
    """`observations[id]`: the point's dict keyframe id -> keypoint index (insertion order kept). A compacted id
    reads as a new empty dict, so that writes into it are dropped; slices and iteration run over the id range."""

    __slots__ = ("_store",)

    def __init__(self, store: PointStore) -> None:
        self._store = store

    def __getitem__(self, key: Any) -> Any:
        store = self._store
        if isinstance(key, slice):
            return [self[i] for i in range(store.size)[key]]
        slot = int(store._slot_of[key])  # noqa: SLF001
        return store._obs[slot] if slot else {}  # noqa: SLF001

    def __setitem__(self, key: int, value: dict[int, int]) -> None:
        slot = int(self._store._slot_of[key])  # noqa: SLF001
        if slot:
            self._store._obs[slot] = value  # noqa: SLF001

    def __len__(self) -> int:
        return self._store.size

    def __iter__(self) -> Iterator[dict[int, int]]:
        return (self[i] for i in range(self._store.size))


# column -> (value of the gone row, value of a row handed out before it is written)
_DEFAULTS: dict[str, tuple[Any, Any]] = {
    "first_kf": (-1, 0), "ref_kf": (-1, 0), "object_id": (-1, -1), "active": (False, True), "bad": (True, False),
    "last_seen_frame": (-1, -1),
}


class PointStore:
    """All map points of one map. Ids are handed out in order and never reused.

    Storage is decoupled from ids: `_slot_of` (id -> slot) points each id at a row of the compact columns. When
    storage is full and at least half of its rows hold bad points, they are compacted away instead of growing
    (amortised, as doubling is): over a long run points are made and culled over and over, and storage stays in
    proportion to the live points. A compacted id reads as slot 0, the gone row: bad, inactive, no observations.
    """

    def __init__(self, capacity: int = 4096) -> None:
        self.size = 0  # ids handed out: 0 .. size-1
        cap = max(int(capacity), 1) + 1  # + the gone row
        self._slot_of = np.zeros(cap, np.int64)  # id -> slot, 0 for a compacted id
        self._id_of = np.full(cap, -1, np.int64)  # slot -> id, -1 for a free slot
        self.n_slots = 1  # slots in use, the gone row included
        self._obs: list[dict[int, int]] = [{}]  # per slot
        self.observations = IdObservations(self)
        self.positions = self._column(np.zeros((cap, 3)), "positions")
        self.descriptors = self._column(np.zeros((cap, 32), np.uint8), "descriptors")
        self.normals = self._column(np.zeros((cap, 3)), "normals")
        self.min_dist = self._column(np.zeros(cap), "min_dist")
        self.max_dist = self._column(np.zeros(cap), "max_dist")
        self.n_visible = self._column(np.zeros(cap, np.int64), "n_visible")
        self.n_found = self._column(np.zeros(cap, np.int64), "n_found")
        self.first_kf = self._column(np.zeros(cap, np.int64), "first_kf")
        self.ref_kf = self._column(np.zeros(cap, np.int64), "ref_kf")
        self.class_id = self._column(np.zeros(cap, np.int64), "class_id")
        self.object_id = self._column(np.zeros(cap, np.int64), "object_id")
        self.active = self._column(np.zeros(cap, bool), "active")
        self.bad = self._column(np.zeros(cap, bool), "bad")
        self.last_seen_frame = self._column(np.zeros(cap, np.int64), "last_seen_frame")

    _COLUMNS = (
        "positions", "descriptors", "normals", "min_dist", "max_dist", "n_visible", "n_found",
        "first_kf", "ref_kf", "class_id", "object_id", "active", "bad", "last_seen_frame",
    )

    def _column(self, data: npt.NDArray[Any], name: str) -> IdColumn:
        fill, new = _DEFAULTS.get(name, (0, 0))
        data[:] = new
        data[0] = fill
        return IdColumn(self, data, fill, new)

    def __len__(self) -> int:
        return self.size

    # Storage ----------------------------------------------------------------------------------------------
    @property
    def capacity(self) -> int:
        """Storage rows allocated (the gone row included)."""
        return len(self._id_of)

    def n_dead_slots(self) -> int:
        """Storage rows held by bad points, given back at the next compaction."""
        n = self.n_slots
        return int(self.bad.data[1:n].sum())

    def compact(self) -> None:
        """Give the rows of bad points back: live rows move down in slot order, their ids follow."""
        n = self.n_slots
        keep = ~self.bad.data[:n]
        keep[0] = True
        dead = self._id_of[1:n][~keep[1:]]
        self._slot_of[dead[dead >= 0]] = 0
        rows = np.flatnonzero(keep)
        m = len(rows)
        for name in self._COLUMNS:
            col: IdColumn = getattr(self, name)
            col.data[:m] = col.data[rows]
            col.data[m:n] = col.new
        ids = self._id_of[rows]
        self._id_of[:m] = ids
        self._id_of[m:n] = -1
        self._slot_of[ids[1:]] = np.arange(1, m)
        obs = self._obs
        self._obs = [obs[i] for i in rows.tolist()]
        self.n_slots = m

    def _reserve(self, m: int) -> None:
        """Room for `m` more slots: compaction when half the rows are bad, else doubling."""
        if self.n_slots + m <= self.capacity:
            return
        if 2 * self.n_dead_slots() >= self.n_slots - 1:
            self.compact()
        needed = self.n_slots + m
        if needed <= self.capacity:
            return
        new_cap = max(needed, 2 * self.capacity)
        for name in self._COLUMNS:
            col: IdColumn = getattr(self, name)
            new = np.full((new_cap, *col.data.shape[1:]), col.new, dtype=col.data.dtype)
            new[: self.n_slots] = col.data[: self.n_slots]
            col.data = new
        id_of = np.full(new_cap, -1, np.int64)
        id_of[: self.n_slots] = self._id_of[: self.n_slots]
        self._id_of = id_of

    def _new_slots(self, ids: I64) -> None:
        """Fresh rows (every column at its `new` value, no observations) for `ids`."""
        m = len(ids)
        self._reserve(m)
        top = int(ids.max()) + 1 if m else 0
        if top > len(self._slot_of):
            slot_of = np.zeros(max(top, 2 * len(self._slot_of)), np.int64)
            slot_of[: len(self._slot_of)] = self._slot_of
            self._slot_of = slot_of
        s = np.arange(self.n_slots, self.n_slots + m)
        self._slot_of[ids] = s
        self._id_of[s] = ids
        self._obs.extend({} for _ in range(m))
        self.n_slots += m

    def extend_ids(self, n: int) -> I64:
        """Hand out ids `size` .. `n`-1 with fresh rows for the caller to write (a replica filling rows its owner
        allocated, or rows coming back); returns them."""
        ids = np.arange(self.size, max(n, self.size), dtype=np.int64)
        self._new_slots(ids)
        self.size = max(n, self.size)
        return ids

    def revive(self, ids: I64) -> None:
        """Fresh rows for those of `ids` (< size) that were compacted (a replica told they are live again)."""
        ids = np.asarray(ids, np.int64)
        gone = ids[self._slot_of[ids] == 0]
        if len(gone):
            self._new_slots(np.unique(gone))

    def truncate(self, n: int) -> None:
        """Forget ids `n` and up (their rows are freed; the ids will be handed out again)."""
        if n >= self.size:
            return
        slots = self._slot_of[n : self.size]
        slots = slots[slots > 0]
        self.bad.data[slots] = True
        self._id_of[slots] = -1
        for s in slots.tolist():
            self._obs[s] = {}
        self._slot_of[n : self.size] = 0
        self.size = n

    def live_ids(self) -> I64:
        """Ids of the points that have a storage row, sorted (every point not compacted away)."""
        ids = self._id_of[1 : self.n_slots]
        return np.sort(ids[ids >= 0])

    # Points -------------------------------------------------------------------------------------------------
    def add(
        self,
        positions_w: F64,
        descriptors: npt.NDArray[np.uint8],
        kf_id: int,
        kp_indices: npt.NDArray[np.int64],
        camera_centre_w: F64,
        octaves: npt.NDArray[np.int64],
        level_scales: F64,
    ) -> I64:
        """Create points (M rows) first seen by keyframe `kf_id` at keypoints `kp_indices`; return ids (M,).

        Distances follow ORB-SLAM: `max = dist * scale[octave]`, `min = max / scale[last level]`.
        """
        m = len(positions_w)
        ids = self.extend_ids(self.size + m)
        self.positions[ids] = positions_w
        self.descriptors[ids] = descriptors
        view = positions_w - camera_centre_w
        dist = np.linalg.norm(view, axis=1)
        self.normals[ids] = view / np.maximum(dist, 1e-9)[:, None]
        max_dist = dist * level_scales[octaves]
        self.max_dist[ids] = max_dist
        self.min_dist[ids] = max_dist / level_scales[-1]
        self.n_visible[ids] = 1
        self.n_found[ids] = 1
        self.first_kf[ids] = kf_id
        self.ref_kf[ids] = kf_id
        obs = self._obs
        for s, k in zip(self._slot_of[ids].tolist(), kp_indices.tolist()):
            obs[s] = {kf_id: int(k)}
        return ids

    def usable(self) -> npt.NDArray[np.bool_]:
        """(size,) points that tracking, mapping and loop closing may use: not bad and active."""
        slots = self._slot_of[: self.size]
        return ~self.bad.data[slots] & self.active.data[slots]

    def n_obs(self, ids: I64) -> I64:
        obs, slot_of = self._obs, self._slot_of
        return np.array([len(obs[s]) if s else 0 for s in slot_of[ids].tolist()], dtype=np.int64)

    def found_ratio(self, ids: I64) -> F64:
        slots = self._slot_of[ids]
        return self.n_found.data[slots] / np.maximum(self.n_visible.data[slots], 1)

    def set_bad(self, ids: I64) -> None:
        """Mark points as removed; the caller erases their keyframe observations."""
        self.bad[ids] = True

    def add_counters(self, ids: I64, n_visible: I64, n_found: I64, last_seen_frame: I64) -> None:
        """Add tracking's increments (ids may repeat) and keep the later `last_seen_frame`."""
        slots = self._slot_of[ids]
        np.add.at(self.n_visible.data, slots, n_visible)
        np.add.at(self.n_found.data, slots, n_found)
        self.last_seen_frame[ids] = np.maximum(self.last_seen_frame.data[slots], last_seen_frame)
        for name in ("n_visible", "n_found"):
            col: IdColumn = getattr(self, name)
            col.data[0] = col.fill

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
    def column_specs(cls) -> tuple[tuple[str, tuple[int, ...], np.dtype[Any]], ...]:
        """(name, per-row shape, dtype) of every column (`COLUMNS`), read off an empty store so that the
        schema is written once, in `__init__`."""
        empty = cls(1)
        return tuple((name, getattr(empty, name).shape[1:], getattr(empty, name).dtype) for name in cls._COLUMNS)

    def column_arrays(self, ids: I64 | None = None) -> dict[str, npt.NDArray[np.generic]]:
        """Every column for `ids` (default: every id, 0 .. size-1), by name (copies). A bad point reads as the
        gone row whether or not it was compacted yet, so that two stores holding the same points give the same
        arrays whenever each compacted."""
        slots = self._slot_of[: self.size] if ids is None else self._slot_of[np.asarray(ids, np.int64)]
        slots = np.where(self.bad.data[slots], 0, slots)
        return {name: getattr(self, name).data[slots] for name in self._COLUMNS}

    @classmethod
    def from_columns(cls, columns: dict[str, npt.NDArray[np.generic]], observations: list[dict[int, int]]) -> PointStore:
        """A store holding `columns` (every name of `COLUMNS`, same row count) and `observations` (one dict per
        row: keyframe id -> keypoint index). Raises ValueError naming the column whose shape is wrong."""
        size = len(observations)
        store = cls(max(size, 16))
        for name in cls._COLUMNS:
            col = np.asarray(columns[name])
            want = getattr(store, name).data
            if col.shape != (size,) + want.shape[1:]:
                raise ValueError(f"column {name}: expected shape {(size,) + want.shape[1:]}, got {col.shape}")
        ids = store.extend_ids(size)
        for name in cls._COLUMNS:
            getattr(store, name)[ids] = np.asarray(columns[name])
        for i, o in enumerate(observations):
            store.observations[i] = dict(o)
        store.compact()
        return store
