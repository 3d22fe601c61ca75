"""The frame records behind the trajectories: one per input frame, kept for the whole run in compact rows.

A frame's record holds its tracking state, the map and reference keyframe it was tracked against, its pose relative
to that keyframe (`T_ref_cam`: the final trajectory re-expresses it from the keyframe's pose after all optimisation)
and its pose as tracked (`T_world_cam_online`). Both trajectories are written at the end of a run, so every record
stays; `FrameRecords` keeps them as rows of numpy blocks (224 bytes a frame: the top three rows of each pose and a
few integers) rather than a Python object with two (4, 4) arrays (~770 bytes). A pose's bottom row other than
exactly (0, 0, 0, 1) is kept apart, so every pose reads back bit for bit as it was stored.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.slam.tracking import TrackingState

F64 = npt.NDArray[np.float64]

# Poses first, then the integers from the widest down: aligned, 224 bytes a row.
ROW = np.dtype([
    ("T_ref_cam", np.float64, (3, 4)), ("T_world_cam_online", np.float64, (3, 4)),
    ("stamp_ns", np.int64), ("index", np.int64), ("ref_kf_id", np.int64), ("map_id", np.int32),
    ("state", np.int8), ("has_ref", np.bool_), ("has_online", np.bool_),
], align=True)  # fmt: skip
BLOCK_ROWS = 512  # rows per block (112 KiB, allocated as the previous one fills)
_POSES = {"T_ref_cam": "has_ref", "T_world_cam_online": "has_online"}
_UNIT_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_UNIT_ROW_BYTES = _UNIT_ROW.tobytes()


class FrameRecord:
    """One frame's record, read from its row in `FrameRecords`; setting `map_id` or `T_ref_cam` writes the row."""

    __slots__ = ("_records", "_i")

    def __init__(self, records: FrameRecords, i: int) -> None:
        self._records, self._i = records, i

    @property
    def stamp_ns(self) -> int:
        return int(self._records.field(self._i, "stamp_ns"))

    @property
    def index(self) -> int:
        return int(self._records.field(self._i, "index"))

    @property
    def state(self) -> TrackingState:
        return TrackingState(int(self._records.field(self._i, "state")))

    @property
    def map_id(self) -> int:
        return int(self._records.field(self._i, "map_id"))

    @map_id.setter
    def map_id(self, value: int) -> None:
        self._records.set_field(self._i, "map_id", value)

    @property
    def ref_kf_id(self) -> int:
        return int(self._records.field(self._i, "ref_kf_id"))

    @property
    def T_ref_cam(self) -> F64 | None:  # noqa: N802
        """The pose relative to the reference keyframe (4, 4), a new array; None when there is none."""
        return self._records.pose(self._i, "T_ref_cam")

    @T_ref_cam.setter
    def T_ref_cam(self, value: F64 | None) -> None:  # noqa: N802
        self._records.set_pose(self._i, "T_ref_cam", value)

    @property
    def T_world_cam_online(self) -> F64 | None:  # noqa: N802
        """The pose as tracked (4, 4), a new array; None for a frame without one."""
        return self._records.pose(self._i, "T_world_cam_online")

    def __repr__(self) -> str:
        return (f"FrameRecord(stamp_ns={self.stamp_ns}, index={self.index}, state={self.state.name}, "
                f"map_id={self.map_id}, ref_kf_id={self.ref_kf_id})")  # fmt: skip


class FrameRecords:
    """Every frame's record, in input order: `append`, `len`, `records[i]` (a `FrameRecord`, negative i from the end),
    iteration, and the whole-run reads the trajectories and merges use."""

    def __init__(self, block_rows: int = BLOCK_ROWS) -> None:
        self.block_rows = int(block_rows)
        self._blocks: list[np.ndarray] = []
        self._n = 0
        self._bottom: dict[tuple[str, int], F64] = {}  # (pose field, record) -> its bottom row, when not (0, 0, 0, 1)

    def __len__(self) -> int:
        return self._n

    def append(self, stamp_ns: int, index: int, state: TrackingState, map_id: int, ref_kf_id: int,
               T_ref_cam: F64 | None, T_world_cam_online: F64 | None) -> None:  # noqa: N803  # fmt: skip
        """One frame's record (the poses are copied)."""
        i = self._n
        if i // self.block_rows >= len(self._blocks):
            self._blocks.append(np.zeros(self.block_rows, ROW))
        block, k = self._at(i)
        row = block[k]
        row["stamp_ns"], row["index"], row["state"] = stamp_ns, index, state.value
        row["map_id"], row["ref_kf_id"] = map_id, ref_kf_id
        self._n += 1
        self.set_pose(i, "T_ref_cam", T_ref_cam)
        self.set_pose(i, "T_world_cam_online", T_world_cam_online)

    def __getitem__(self, i: int) -> FrameRecord:
        return FrameRecord(self, self._index(i))

    def __iter__(self) -> Iterator[FrameRecord]:
        return (FrameRecord(self, i) for i in range(self._n))

    # -- one record's fields ----------------------------------------------------------------------------
    def field(self, i: int, name: str) -> np.generic:
        block, k = self._at(self._index(i))
        return block[name][k]

    def set_field(self, i: int, name: str, value: int) -> None:
        block, k = self._at(self._index(i))
        block[name][k] = value

    def pose(self, i: int, name: str) -> F64 | None:
        """Pose field `name` of record `i` as a new (4, 4) array, None when the record has none."""
        i = self._index(i)
        block, k = self._at(i)
        if not block[_POSES[name]][k]:
            return None
        T = np.empty((4, 4))  # noqa: N806
        T[:3] = block[name][k]
        T[3] = self._bottom.get((name, i), _UNIT_ROW)
        return T

    def set_pose(self, i: int, name: str, T: F64 | None) -> None:  # noqa: N803
        i = self._index(i)
        block, k = self._at(i)
        self._bottom.pop((name, i), None)
        block[_POSES[name]][k] = T is not None
        if T is None:
            block[name][k] = 0.0
            return
        T = np.asarray(T, np.float64)  # noqa: N806
        block[name][k] = T[:3]
        if T[3].tobytes() != _UNIT_ROW_BYTES:
            self._bottom[(name, i)] = T[3].copy()

    # -- the whole run --------------------------------------------------------------------------------
    def column(self, name: str) -> np.ndarray:
        """A scalar field of every record, in order (a new array)."""
        parts = [b[name][: self._n - j * self.block_rows] for j, b in enumerate(self._blocks)]
        return np.concatenate(parts) if parts else np.zeros(0, ROW[name])

    def rename_map(self, from_map_id: int, into_map_id: int) -> None:
        """The records of map `from_map_id` name `into_map_id` (a merge welded the first into the second)."""
        for j, b in enumerate(self._blocks):
            ids = b["map_id"][: self._n - j * self.block_rows]  # the rows written
            ids[ids == from_map_id] = into_map_id

    def n_in_state(self, state: TrackingState) -> int:
        return int(np.count_nonzero(self.column("state") == state.value))

    def relative_poses(self) -> Iterator[tuple[int, int, int, F64]]:
        """(stamp_ns, map_id, ref_kf_id, T_ref_cam (4, 4)) of every record with a relative pose, in order."""
        for i in np.flatnonzero(self.column("has_ref")).tolist():
            block, k = self._at(i)
            T = self.pose(i, "T_ref_cam")  # noqa: N806
            assert T is not None
            yield int(block["stamp_ns"][k]), int(block["map_id"][k]), int(block["ref_kf_id"][k]), T

    def online_poses(self) -> Iterator[tuple[int, F64]]:
        """(stamp_ns, T_world_cam_online (4, 4)) of every record tracked (state OK) with a pose, in order."""
        ok = (self.column("state") == TrackingState.OK.value) & self.column("has_online")
        for i in np.flatnonzero(ok).tolist():
            block, k = self._at(i)
            T = self.pose(i, "T_world_cam_online")  # noqa: N806
            assert T is not None
            yield int(block["stamp_ns"][k]), T

    def _index(self, i: int) -> int:
        j = i + self._n if i < 0 else i
        if not 0 <= j < self._n:
            raise IndexError(f"frame record {i} out of range ({self._n} records)")
        return j

    def _at(self, i: int) -> tuple[np.ndarray, int]:
        return self._blocks[i // self.block_rows], i % self.block_rows
