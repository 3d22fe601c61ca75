"""The map file (`io.map_file`): a real map (3 s of the simulated `static` room, oracle boxes, object layer) saved,
loaded and saved again gives the same bytes and equal fields; damaged files give errors naming file and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.core.dynamic.dynamic_filter import DynamicFilter
from changing_slam_ros.core.slam.loop_closing import LoopCloser, LoopConfig, SlamMapLoopClosing
from changing_slam_ros.core.objects.object_layer import ObjectLayer
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.core.features.vocabulary import Vocabulary
from changing_slam_ros.errors import MapFileError
from changing_slam_ros.io.map_file import load_map, npz_bytes, read_map_arrays, save_map

FPS, FRAMES = 15.0, 45


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> tuple[SlamSystem, Path]:
    from changing_slam_ros.errors import SimError
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.detections_file import find_detections_file, read_detections_file
    from changing_slam_ros.sim import renderer  # noqa: F401 - sets MUJOCO_GL before mujoco loads
    from changing_slam_ros.sim.scenarios import build_scenario
    from changing_slam_ros.sim.sequence import RenderOptions, simulate

    root = tmp_path_factory.mktemp("map_file")
    try:
        simulate(build_scenario("static", 0), root / "static", RenderOptions(width=320, height=240, frames=FRAMES, fps=FPS), 0)
    except SimError as err:
        pytest.skip(f"no offscreen rendering here: {err}")
    source = open_dataset(root / "static", "sim")
    oracle = read_detections_file(find_detections_file(root / "static"))
    closing = SlamMapLoopClosing(LoopCloser(LoopConfig(), Vocabulary.load()))
    system = SlamSystem(loop_closer=closing, keyframe_index=closing, dynamic_filter=DynamicFilter(),
                        object_layer=ObjectLayer())
    for rgbd in source:
        system.process(rgbd, oracle.for_stamp(rgbd.stamp_ns))
    path = root / "map.npz"
    save_map(path, system.atlas, system.object_layer, system.tracker.next_kf_id)
    return system, path


def test_save_load_save_is_byte_identical_and_field_equal(mapped: tuple[SlamSystem, Path], tmp_path: Path) -> None:
    system, path = mapped
    assert system.object_layer is not None
    m0 = system.atlas.maps[0]
    assert len(m0.keyframes) >= 3 and m0.points.size > 500 and len(system.object_layer.objects(0)) >= 2

    loaded = load_map(path)
    again = tmp_path / "again.npz"
    save_map(again, loaded.atlas, loaded.objects, loaded.next_keyframe_id)
    assert again.read_bytes() == path.read_bytes()

    m1 = loaded.atlas.maps[0]
    assert loaded.next_keyframe_id == system.tracker.next_kf_id and loaded.atlas.current.id == system.atlas.current.id
    # keyframes: every feature array, pose and camera
    assert sorted(m1.keyframes) == sorted(m0.keyframes)
    for k, kf in m0.keyframes.items():
        back = m1.keyframes[k]
        assert (back.stamp_ns, back.camera, back.map_id) == (kf.stamp_ns, kf.camera, kf.map_id)
        np.testing.assert_array_equal(back.T_world_cam, kf.T_world_cam)
        for name in ("keypoints_px", "octaves", "descriptors", "depths_m", "point_ids", "kp_classes", "object_ids"):
            a, b = getattr(kf, name), getattr(back, name)
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
    # points: every column, observations in order
    assert m1.points.size == m0.points.size
    for name, col in m0.points.column_arrays().items():
        np.testing.assert_array_equal(m1.points.column_arrays()[name], col, err_msg=name)
    assert [list(o.items()) for o in m1.points.observations] == [list(o.items()) for o in m0.points.observations[: m0.points.size]]
    # graph
    assert m1.covisibility == m0.covisibility and m1.parent == m0.parent and m1.children == m0.children
    assert m1.loop_edges == m0.loop_edges and m1.origin_kf_id == m0.origin_kf_id
    assert m1.removed.keys() == m0.removed.keys()
    for k, r in m0.removed.items():
        assert m1.removed[k].parent_id == r.parent_id
        np.testing.assert_array_equal(m1.removed[k].T_parent_kf, r.T_parent_kf)
    # object map: beliefs, points, anchors
    saved = system.object_layer.saved_objects(0)
    back_objects = loaded.objects[0]
    assert [(o.id, o.class_id, o.belief, o.active, o.last_seen_keyframe) for o in back_objects.objects] == \
           [(o.id, o.class_id, o.belief, o.active, o.last_seen_keyframe) for o in saved.objects]
    for a, b in zip(saved.objects, back_objects.objects):
        np.testing.assert_array_equal(a.point_ids, b.point_ids)
        np.testing.assert_allclose(a.points_w, b.points_w, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(back_objects.anchor_ids, saved.anchor_ids)
    np.testing.assert_array_equal(back_objects.anchor_kf_ids, saved.anchor_kf_ids)
    np.testing.assert_array_equal(back_objects.anchor_points_cam, saved.anchor_points_cam)
    assert back_objects.next_sample_id == saved.next_sample_id < -2


def _rewrite(path: Path, out: Path, change) -> Path:  # noqa: ANN001 - test helper
    arrays = read_map_arrays(path)
    change(arrays)
    out.write_bytes(npz_bytes(arrays))
    return out


@pytest.mark.parametrize(("change", "message"), [
    (lambda a: a.pop("m0_kp_px"), "m0_kp_px: missing"),
    (lambda a: a.pop("m0_objects_json"), None),  # a map without object layer is valid
    (lambda a: a.__setitem__("m0_kf_poses", a["m0_kf_poses"][:-1]), "m0_kf_poses: expected shape"),
    (lambda a: a.__setitem__("m0_pt_positions", a["m0_pt_positions"].astype(np.float32) * np.nan), "m0_pt_positions: holds non-finite"),
    (lambda a: a.__setitem__("m0_kp_point_ids", a["m0_kp_point_ids"] + 10**6), "m0_kp_point_ids: ids outside"),
    (lambda a: a.__setitem__("m0_pt_obs", a["m0_pt_obs"][1:]), "m0_kp_point_ids: keyframe"),
    (lambda a: a.__setitem__("m0_pt_descriptors", a["m0_pt_descriptors"].astype(np.float64)), "m0_pt_descriptors: expected dtype"),
    (lambda a: a.__setitem__("current_map_id", np.array(7)), "current_map_id: 7 is not one of"),
    (lambda a: a.__setitem__("m0_objects_json", np.array("{not json")), "m0_objects_json: not valid JSON"),
    (lambda a: a.__setitem__("m0_parent", np.array([[10**6, 0]])), "m0_parent: unknown keyframe ids"),
    (lambda a: a.__setitem__("format_version", np.array(1)), "version 1, expected one of .2, 3, 4. .written before multi-session"),
    (lambda a: a.__setitem__("m0_obj_thumbs", a["m0_obj_thumbs"][:, :10]), "m0_obj_thumbs: expected shape"),
    (lambda a: a.__setitem__("m0_gs_kf_ids", a["m0_gs_kf_ids"] + 10**6), "m0_gs_kf_ids: unknown or repeated"),
    (lambda a: a.__setitem__("m0_gs_dynamic", a["m0_gs_dynamic"][1:]), "m0_gs_dynamic: expected shape"),
])
def test_damaged_fields_are_named(mapped: tuple[SlamSystem, Path], tmp_path: Path, change, message) -> None:  # noqa: ANN001
    _, path = mapped
    bad = _rewrite(path, tmp_path / "bad.npz", change)
    if message is None:
        assert load_map(bad).objects == {}
        return
    with pytest.raises(MapFileError, match=message) as err:
        load_map(bad)
    assert str(bad) in str(err.value)


def test_truncated_corrupt_and_foreign_files(mapped: tuple[SlamSystem, Path], tmp_path: Path) -> None:
    _, path = mapped
    data = path.read_bytes()
    cut = tmp_path / "cut.npz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError, match=f"{cut}: cannot read map"):
        load_map(cut)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"\x00" * 1000)
    with pytest.raises(MapFileError, match="cannot read map"):
        load_map(junk)
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, x=np.arange(3))
    with pytest.raises(MapFileError, match="not a map file"):
        load_map(foreign)
    with pytest.raises(MapFileError, match="no such file"):
        load_map(tmp_path / "none.npz")


def test_culled_keyframes_and_loop_edges_round_trip(mapped: tuple[SlamSystem, Path], tmp_path: Path) -> None:
    """A keyframe culled after a loop closed on it: its removal record and the loop edge naming it survive."""
    _, path = mapped
    loaded = load_map(path)
    m = loaded.atlas.maps[0]
    last = max(m.keyframes)
    assert m.remove_keyframe(last - 1)
    m.loop_edges = {last: {last - 1}}
    out = tmp_path / "culled.npz"
    save_map(out, loaded.atlas, loaded.objects, loaded.next_keyframe_id)
    back = load_map(out).atlas.maps[0]
    assert back.loop_edges == {last: {last - 1}} and sorted(back.keyframes) == sorted(m.keyframes)
    assert back.removed[last - 1].parent_id == m.removed[last - 1].parent_id
    np.testing.assert_array_equal(back.pose_of(last - 1), m.pose_of(last - 1))
    assert back.covisibility == m.covisibility and back.children == m.children and back.parent == m.parent


def test_merged_away_maps_round_trip(mapped: tuple[SlamSystem, Path], tmp_path: Path) -> None:
    """An Atlas whose map 1 was merged into map 0 (left empty, `Atlas.merged_into`) saves and loads as it was."""
    from changing_slam_ros.core.map.slam_map import SlamMap

    _, path = mapped
    loaded = load_map(path)
    loaded.atlas.maps.append(SlamMap(1))
    loaded.atlas.merged_into = {1: 0}
    out = tmp_path / "merged.npz"
    save_map(out, loaded.atlas, loaded.objects, loaded.next_keyframe_id)
    back = load_map(out).atlas
    assert back.merged_into == {1: 0} and len(back.maps) == 2 and not back.maps[1].keyframes
    assert back.resolve(1) is back.maps[0] and back.current is back.maps[0]


def test_object_evidence_and_thumbnails_round_trip(mapped: tuple[SlamSystem, Path]) -> None:
    system, path = mapped
    assert system.object_layer is not None
    saved = system.object_layer.saved_objects(0)
    back = load_map(path).objects[0]
    assert saved.thumbnails and sorted(back.thumbnails) == sorted(saved.thumbnails)
    named = {k for o in saved.objects for k in (*o.seen_keyframes, *(r[0] for r in o.belief_history))}
    assert set(saved.thumbnails) <= named  # only the keyframes the evidence names keep a thumbnail
    for k, img in saved.thumbnails.items():
        assert img.shape == (72, 96, 3) and img.dtype == np.uint8
        np.testing.assert_array_equal(back.thumbnails[k], img)
    for a, b in zip(saved.objects, back.objects):
        assert a.belief_history and a.belief_history[0][2] == "new"
        assert b.belief_history == a.belief_history and b.seen_keyframes == a.seen_keyframes


def test_a_version_2_map_still_loads_without_evidence(mapped: tuple[SlamSystem, Path], tmp_path: Path) -> None:
    import json

    _, path = mapped

    def to_v2(a: dict) -> None:  # noqa: ANN001
        a["format_version"] = np.array(2)
        a.pop("m0_obj_thumbs")
        a.pop("m0_obj_thumb_kf_ids")
        doc = json.loads(str(a["m0_objects_json"]))
        for item in doc["objects"]:
            item.pop("belief_history")
            item.pop("seen_keyframes")
        a["m0_objects_json"] = np.array(json.dumps(doc))

    old = load_map(_rewrite(path, tmp_path / "v2.npz", to_v2))
    new = load_map(path)
    assert old.objects[0].thumbnails == {}
    assert [o.belief_history for o in old.objects[0].objects] == [[] for _ in new.objects[0].objects]
    assert [(o.id, o.belief) for o in old.objects[0].objects] == [(o.id, o.belief) for o in new.objects[0].objects]


def test_grid_scans_round_trip_and_a_version_3_map_loads_without_them(mapped: tuple[SlamSystem, Path],
                                                                         tmp_path: Path) -> None:
    system, path = mapped
    m0 = system.atlas.maps[0]
    kept = {k: kf.grid_scan for k, kf in m0.keyframes.items() if kf.grid_scan is not None}
    assert set(kept) == set(m0.keyframes) and all(len(s) > 1000 for s in kept.values())
    back = load_map(path).atlas.maps[0]
    for k, scan in kept.items():
        got = back.keyframes[k].grid_scan
        assert got is not None
        np.testing.assert_array_equal(got.points_cam, scan.points_cam)
        np.testing.assert_array_equal(got.dynamic, scan.dynamic)
        np.testing.assert_array_equal(got.object_ids, scan.object_ids)

    def to_v3(a: dict) -> None:  # noqa: ANN001
        a["format_version"] = np.array(3)
        for key in [k for k in a if k.startswith("m0_gs_")]:
            a.pop(key)

    old = load_map(_rewrite(path, tmp_path / "v3.npz", to_v3)).atlas.maps[0]
    assert sorted(old.keyframes) == sorted(m0.keyframes)
    assert all(kf.grid_scan is None for kf in old.keyframes.values())
