"""FrameRecords: every field and pose reads back bit for bit, across blocks; a record writes its row; whole-run
reads."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.slam.frame_records import ROW, FrameRecords
from changing_slam_ros.core.slam.tracking import TrackingState


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.eye(4)  # noqa: N806
    T[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    T[:3, 3] = rng.normal(size=3)
    return T


def _filled(n: int, block_rows: int = 3) -> tuple[FrameRecords, list[tuple]]:
    records = FrameRecords(block_rows)
    rows = []
    for i in range(n):
        state = (TrackingState.OK, TrackingState.LOST, TrackingState.NOT_INITIALISED)[i % 3]
        T_ref = _pose(i) if state is TrackingState.OK else None  # noqa: N806
        online = _pose(100 + i) if state is not TrackingState.NOT_INITIALISED else None
        row = (1_700_000_000_123_456_789 + i * 33_333_333, i, state, i % 2, 10 + i, T_ref, online)
        records.append(*row)
        rows.append(row)
    return records, rows


def test_rows_are_224_bytes() -> None:
    assert ROW.itemsize == 224


def test_every_field_reads_back_as_appended_across_blocks() -> None:
    records, rows = _filled(8)
    assert len(records) == 8 and len(records._blocks) == 3  # noqa: SLF001
    for rec, row in zip(records, rows, strict=True):
        stamp_ns, index, state, map_id, ref_kf_id, T_ref, online = row  # noqa: N806
        assert (rec.stamp_ns, rec.index, rec.state, rec.map_id, rec.ref_kf_id) == (stamp_ns, index, state, map_id,
                                                                                   ref_kf_id)  # fmt: skip
        assert isinstance(rec.stamp_ns, int) and isinstance(rec.state, TrackingState)
        for got, want in ((rec.T_ref_cam, T_ref), (rec.T_world_cam_online, online)):
            assert (got is None) == (want is None)
            if want is not None:
                assert got.tobytes() == want.tobytes() and got.flags.c_contiguous
    assert records[-1].index == 7 and records[-8].index == 0
    with pytest.raises(IndexError, match="out of range"):
        _ = records[8]
    with pytest.raises(IndexError):
        _ = records[-9]


def test_a_bottom_row_other_than_0001_reads_back_bit_for_bit() -> None:
    records = FrameRecords(2)
    T = _pose(1)  # noqa: N806
    T[3] = [1e-17, -0.0, 0.0, 1.0 - 2**-52]
    records.append(5, 0, TrackingState.OK, 0, 0, T, T)
    assert records[0].T_ref_cam.tobytes() == T.tobytes()
    assert records[0].T_world_cam_online.tobytes() == T.tobytes()
    records[0].T_ref_cam = _pose(2)  # a unit bottom row again: nothing kept apart
    assert records[0].T_ref_cam.tobytes() == _pose(2).tobytes()
    assert records[0].T_world_cam_online.tobytes() == T.tobytes()


def test_setting_map_id_and_the_relative_pose_writes_the_row() -> None:
    records, _ = _filled(5)
    records[4].map_id = 7
    records[1].T_ref_cam = _pose(9)
    records[0].T_ref_cam = None
    assert records[4].map_id == 7 and records[1].T_ref_cam.tobytes() == _pose(9).tobytes()
    assert records[0].T_ref_cam is None


def test_rename_map_touches_only_that_maps_records() -> None:
    records, rows = _filled(7)
    records.rename_map(0, 5)
    assert [r.map_id for r in records] == [5 if row[3] == 0 else row[3] for row in rows]
    records.append(1, 7, TrackingState.OK, 0, 1, None, None)  # a row of a block written after the rename
    assert records[7].map_id == 0


def test_whole_run_reads() -> None:
    records, rows = _filled(8)
    assert records.n_in_state(TrackingState.OK) == sum(r[2] is TrackingState.OK for r in rows)
    rel = list(records.relative_poses())
    want = [(r[0], r[3], r[4], r[5]) for r in rows if r[5] is not None]
    assert [x[:3] for x in rel] == [w[:3] for w in want]
    assert all(a[3].tobytes() == b[3].tobytes() for a, b in zip(rel, want, strict=True))
    online = list(records.online_poses())
    want_online = [(r[0], r[6]) for r in rows if r[2] is TrackingState.OK and r[6] is not None]
    assert [s for s, _ in online] == [s for s, _ in want_online]
    assert all(a.tobytes() == b.tobytes() for (_, a), (_, b) in zip(online, want_online, strict=True))
    assert records.column("index").tolist() == list(range(8))
    assert FrameRecords().column("stamp_ns").shape == (0,)
