"""The point store: ids stay stable while the rows of culled points are compacted away."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.map.map_point import PointStore

SCALES = np.array([1.2**i for i in range(8)])


def _add(store: PointStore, rng: np.random.Generator, m: int, kf_id: int) -> np.ndarray:
    pos = rng.normal(size=(m, 3)) + np.array([0.0, 0.0, 3.0])
    desc = rng.integers(0, 256, size=(m, 32), dtype=np.uint8)
    return store.add(pos, desc, kf_id, np.arange(m), np.zeros(3), rng.integers(0, 8, m), SCALES)


def _row(store: PointStore, pid: int) -> tuple:
    p = store.get(pid)
    return (p.position.tolist(), p.descriptor.tolist(), p.observations, p.normal.tolist(), p.min_distance_m,
            p.max_distance_m, p.class_id, p.object_id, p.active, int(store.n_visible[pid]), int(store.ref_kf[pid]))


def test_storage_stays_bounded_while_points_are_made_and_culled_over_and_over() -> None:
    rng = np.random.default_rng(0)
    store = PointStore(64)
    live: dict[int, tuple] = {}
    next_id = 0
    for kf_id in range(400):
        ids = _add(store, rng, 200, kf_id)
        np.testing.assert_array_equal(ids, np.arange(next_id, next_id + 200))  # ids in order, never reused
        next_id += 200
        store.class_id[ids[::7]] = 3
        store.n_visible[ids[::5]] += 4
        for pid in ids.tolist():
            live[pid] = _row(store, pid)
        # Cull at random so that about 2000 points stay live, some of them old.
        alive = np.array(sorted(live))
        cull = alive[rng.random(len(alive)) < max(0.0, 1.0 - 2000 / len(alive))]
        store.set_bad(cull)
        for pid in cull.tolist():
            store.observations[pid] = {}
            del live[pid]
        # Storage doubles only when over half its rows are live: at most 4x the live points and a batch.
        assert store.n_slots <= store.capacity <= 4 * (2000 + 200)
    assert store.size == 80000 and len(live) <= 2000  # the rows, not the 80000 ids ever handed out
    for pid, row in live.items():  # every live point's data is intact after the compactions
        assert _row(store, pid) == row
    gone = np.setdiff1d(np.arange(store.size), np.array(sorted(live)))
    assert store.bad[gone].all() and not store.usable()[gone].any()
    np.testing.assert_array_equal(np.flatnonzero(store.usable()), np.array(sorted(live)))


def test_a_compacted_point_reads_as_gone_and_ignores_writes() -> None:
    store = PointStore(8)
    ids = _add(store, np.random.default_rng(1), 6, 0)
    store.set_bad(ids[:3])
    store.compact()
    assert store.n_slots == 4 and store.n_dead_slots() == 0
    store.positions[ids[:2]] = 7.0
    store.active[ids[0]] = True
    store.observations[int(ids[1])][5] = 2
    assert store.bad[ids[:3]].all() and not store.active[ids[:3]].any()
    assert (store.positions[ids[:3]] == 0).all() and store.observations[int(ids[1])] == {}
    assert store.n_obs(ids).tolist() == [0, 0, 0, 1, 1, 1]
    cols = store.column_arrays()
    assert cols["bad"].tolist() == [True] * 3 + [False] * 3 and (cols["ref_kf"][:3] == -1).all()


def test_a_compacted_point_told_live_again_gets_a_row() -> None:
    store = PointStore(8)
    ids = _add(store, np.random.default_rng(2), 4, 0)
    store.set_bad(ids[:1])
    store.compact()
    store.revive(ids[:1])
    store.bad[ids[0]] = False
    store.positions[ids[0]] = [1.0, 2.0, 3.0]
    assert store.positions[ids[0]].tolist() == [1.0, 2.0, 3.0] and store.usable()[0]


def test_truncated_ids_are_handed_out_again_with_fresh_rows() -> None:
    store = PointStore(8)
    rng = np.random.default_rng(3)
    _add(store, rng, 5, 0)
    store.truncate(3)
    assert store.size == 3 and store.observations[:] == [{0: 0}, {0: 1}, {0: 2}]
    ids = _add(store, rng, 4, 1)
    assert ids.tolist() == [3, 4, 5, 6] and store.observations[4] == {1: 1} and not store.bad[ids].any()


def test_a_column_is_not_read_as_a_whole_array() -> None:
    with pytest.raises(TypeError, match="indexed by point ids"):
        np.asarray(PointStore(4).positions)
