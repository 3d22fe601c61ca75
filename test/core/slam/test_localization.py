"""core/slam/localization.py and localisation-only mode in the system: the map is only read, a forced loss
relocalises in it, objects are found present or missing at their mapped place by depth."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.objects.map_object import MapObject
from changing_slam_ros.core.slam.localization import Mode, SightingConfig, Sightings
from changing_slam_ros.core.slam.tracking import TrackingState
from changing_slam_ros.core.system import SlamSystem
from changing_slam_ros.errors import ConfigError
from changing_slam_ros.io.map_file import load_map, map_arrays, npz_bytes, save_map

CAM = CameraIntrinsics(fx=100.0, fy=100.0, cx=50.0, cy=40.0, width=100, height=80)


def box_object(object_id: int, z_m: float) -> MapObject:
    """A 20 x 20 grid of points on a 0.4 m square facing the camera at depth `z_m`, centred on the optical axis."""
    xs, ys = np.meshgrid(np.linspace(-0.2, 0.2, 20), np.linspace(-0.2, 0.2, 20))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(400, z_m)])
    return MapObject(id=object_id, class_id=56, first_box_xyxy=(0, 0, 1, 1), current_box_xyxy=(0, 0, 1, 1),
                     first_keyframe=0, last_seen_keyframe=0, point_ids=-np.arange(1, 401), points_w=pts)  # fmt: skip


def test_an_object_is_present_where_the_depth_meets_its_points_missing_where_the_camera_sees_past_them() -> None:
    s = Sightings(SightingConfig(min_points=10, tolerance_m=0.05, tolerance_rel=0.03, fraction=0.5))
    chair, gone, hidden = box_object(1, 2.0), box_object(2, 2.0), box_object(3, 2.0)
    depth = np.full((80, 100), 2.03, np.float32)  # a surface 3 cm behind the points: within 5 cm + 3 % of 2 m
    assert s.update(10, np.eye(4), CAM, depth, [chair]) == [1]
    depth_past = np.full((80, 100), 3.0, np.float32)  # the wall behind: the object is not there any more
    assert s.update(11, np.eye(4), CAM, depth_past, [gone]) == []
    depth_occluded = np.full((80, 100), 1.0, np.float32)  # a person in front: no verdict
    assert s.update(12, np.eye(4), CAM, depth_occluded, [hidden]) == []
    assert s.update(13, np.eye(4), CAM, np.zeros((80, 100), np.float32), [chair]) == []  # no depth: not in view
    a, b, c = s.by_object[1], s.by_object[2], s.by_object[3]
    assert (a.frames_in_view, a.frames_present, a.frames_missing, a.last_present_stamp_ns) == (1, 1, 0, 10)
    assert (b.frames_in_view, b.frames_present, b.frames_missing) == (1, 0, 1)
    assert (c.frames_in_view, c.frames_present, c.frames_missing) == (1, 0, 0)
    # Looking away (180 degrees about y): behind the camera, not in view, not recorded.
    T_turned = np.diag([-1.0, 1.0, -1.0, 1.0])  # noqa: N806
    assert s.update(14, T_turned, CAM, depth, [chair]) == [] and s.by_object[1].frames_in_view == 1


def test_mode_names_the_choices_and_localisation_needs_a_map() -> None:
    assert Mode.parse("localization") is Mode.LOCALIZATION
    with pytest.raises(ConfigError, match="mode 'slam' unknown; expected mapping or localization"):
        Mode.parse("slam")
    with pytest.raises(ConfigError, match="localization mode needs a map"):
        SlamSystem().set_mode(Mode.LOCALIZATION)


def fr1_system():  # noqa: ANN201
    from changing_slam_ros.commands.run import system_config_from_mapping
    from changing_slam_ros.config import find_config, load_yaml
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.dataset_config import settings_from_mapping

    path = find_config("tum_fr1")
    data = load_yaml(path)
    frames = list(open_dataset(str(require(FR1_XYZ_10)), settings_from_mapping(data, str(path))))
    return SlamSystem(system_config_from_mapping(data, str(path))), frames


def test_localisation_leaves_the_map_as_loaded_and_relocalises_after_a_forced_loss(tmp_path) -> None:
    mapping, frames = fr1_system()
    for f in frames:
        mapping.process(f)
    save_map(tmp_path / "map.npz", mapping.atlas, None, mapping.tracker.next_kf_id)
    before = (tmp_path / "map.npz").read_bytes()
    loaded = load_map(tmp_path / "map.npz")
    system, _ = fr1_system()
    system.start_from_map(loaded.atlas, loaded.next_keyframe_id, loaded.objects, Mode.LOCALIZATION)
    black = RgbdFrame(stamp_ns=frames[4].stamp_ns - 1_000_000, rgb=np.zeros_like(frames[4].rgb),
                      depth_m=np.zeros_like(frames[4].depth_m), camera=frames[4].camera, index=4)  # fmt: skip
    outs = [system.process(f) for f in [*frames[:4], black, *frames[4:]]]
    states = [o.state for o in outs]
    assert states == [TrackingState.OK] * 4 + [TrackingState.LOST] + [TrackingState.OK] * 5
    assert outs[0].relocalised and outs[5].relocalised and not any(o.relocalised for o in outs[1:4] + outs[6:])
    assert all(o.keyframe is None and not o.new_map and not o.loop_corrected for o in outs)
    assert npz_bytes(map_arrays(system.atlas, None, system.tracker.next_kf_id)) == before
    # The poses: where the mapping run put the same frames, within 5 mm.
    got = np.array([o.T_world_cam[:3, 3] for o in outs if o.T_world_cam is not None])
    ref = mapping.online_trajectory().positions
    assert len(got) == 9 and np.abs(got - ref).max() < 0.005
