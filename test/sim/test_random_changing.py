"""The randomised changing-room family: ranges, determinism, per-lap ground truth, changes out of view."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.random_changing import (
    CHANGE_KINDS, PICTURE_PHOTOS, draw_changing_room, footprint_radius_m, random_changing,
)
from changing_slam_ros.sim.scenarios import build_scenario, check_changes_out_of_view
from changing_slam_ros.sim.sequence import RenderOptions, simulate

SEEDS = range(0, 12)


def _truth(seed: int, with_changes: bool = True) -> dict:
    s = random_changing(seed, with_changes)
    return json.loads(dict(s.extra_files)["changing_truth.json"])


def test_the_same_seed_gives_the_same_draw_and_two_seeds_differ() -> None:
    assert _truth(3) == _truth(3)
    a, b = _truth(3)["params"], _truth(4)["params"]
    assert a != b
    assert a["room_half_x_m"] != b["room_half_x_m"] and a["robot"] != b["robot"]


@pytest.mark.parametrize("seed", SEEDS)
def test_drawn_parameters_lie_in_their_ranges(seed: int) -> None:
    room = draw_changing_room(seed)
    p = room.params
    assert 2.3 <= room.half_x_m <= 3.3 and 2.0 <= room.half_y_m <= 2.8 and 2.4 <= room.height_m <= 3.0
    assert room.n_laps in (2, 3)
    r = p["robot"]
    assert 0.6 <= r["side_m"] <= 1.0 and 0.2 <= r["speed_m_s"] <= 0.3 and 15.0 <= r["turn_deg_s"] <= 22.0
    initial = [n for n, pose in room.initial.items() if pose is not None and n != "table"]
    assert 3 <= len(initial) <= 8
    assert 3 <= len(room.pictures) <= 7 and all(pic.texture in PICTURE_PHOTOS for pic in room.pictures)
    assert 1 <= len(room.changes) <= 4
    for c in room.changes:
        assert c.kind in CHANGE_KINDS and 1 <= c.lap < room.n_laps
        assert (c.lap - 0.5) * room.lap_s <= c.t_s <= (c.lap + 0.5) * room.lap_s
    assert len({n for c in room.changes for n in c.to_poses}) == sum(len(c.to_poses) for c in room.changes)


@pytest.mark.parametrize("seed", SEEDS)
def test_objects_stay_in_the_room_apart_and_every_change_is_out_of_view(seed: int) -> None:
    room = draw_changing_room(seed)
    scenario = random_changing(seed)
    check_changes_out_of_view(scenario)  # raises on a change in view
    truth = json.loads(dict(scenario.extra_files)["changing_truth.json"])
    for lap in truth["laps"]:
        floor = []
        for o in lap["objects"]:
            lo, hi = np.array(o["box_min_w"]), np.array(o["box_max_w"])
            assert np.all(np.abs(lo[:2]) <= [room.half_x_m + 1e-6, room.half_y_m + 1e-6])
            assert np.all(np.abs(hi[:2]) <= [room.half_x_m + 1e-6, room.half_y_m + 1e-6])
            assert lo[2] >= -1e-6 and hi[2] <= room.height_m
            if o["support"] == "floor" and o["name"] != "table":
                floor.append((np.array(o["pose"][:2]), footprint_radius_m(room.items[o["name"]])))
        for i, (a, ra) in enumerate(floor):
            for b, rb in floor[i + 1:]:
                assert np.linalg.norm(a - b) >= ra + rb - 1e-6


@pytest.mark.parametrize("seed", SEEDS)
def test_per_lap_truth_follows_each_change(seed: int) -> None:
    truth = _truth(seed)
    states = [{o["name"]: o for o in objects} for objects in [truth["initial"]] + [lap["objects"] for lap in truth["laps"]]]
    for c in truth["changes"]:
        lap = truth["laps"][c["lap"]]
        assert lap["t_start_s"] <= c["t_s"] <= lap["t_end_s"]
        before, after = states[c["lap"]], states[c["lap"] + 1]
        for move in c["objects"]:
            name = move["object"]
            if move["from"] is None:  # added (or the replacement)
                assert name not in before and name in after
                assert after[name]["pose"] == move["to"]
            elif move["to"] is None:  # removed (or replaced)
                assert name in before and name not in after
            else:
                assert before[name]["pose"] == move["from"] and after[name]["pose"] == move["to"]
                if c["kind"] == "moved_short":
                    assert 0.3 - 1e-6 <= move["distance_m"] <= 0.8 + 1e-6 and abs(move["turn_deg"]) >= 22.0
                if c["kind"] == "moved_long":
                    assert move["distance_m"] >= 1.2 - 1e-6
        if c["kind"] == "replaced":
            old, new = c["objects"]
            assert old["class_name"] != new["class_name"] and new["to"][:2] == old["from"][:2]
        if c["kind"] == "swapped":
            a, b = c["objects"]
            assert a["class_name"] != b["class_name"] and a["to"] == b["from"] and b["to"] == a["from"]


def test_the_control_keeps_the_draw_without_changes() -> None:
    for seed in (0, 2):
        changed, control = random_changing(seed), random_changing(seed, with_changes=False)
        assert control.changes == () and control.camera.end_s == changed.camera.end_s
        truth = _truth(seed, with_changes=False)
        assert truth["changes"] == [] and truth["laps"][0]["objects"] == truth["laps"][-1]["objects"]
        assert truth["params"] == _truth(seed)["params"]
        added = {m["object"] for c in _truth(seed)["changes"] for m in c["objects"] if m["from"] is None}
        assert added.isdisjoint(a.name for a in control.actors)


def test_wall_items_tell_pictures_from_hung_objects() -> None:
    kinds = set()
    for seed in SEEDS:
        for w in _truth(seed)["wall_items"]:
            kinds.add((w["is_object"], w.get("kind", "picture")))
            if not w["is_object"]:
                assert w["texture"] in PICTURE_PHOTOS and w["depicts"] == PICTURE_PHOTOS[w["texture"]]
                thickness = np.array(w["box_max_w"]) - np.array(w["box_min_w"])
                assert thickness.min() == pytest.approx(0.012, abs=1e-3)
    assert {(False, "picture"), (True, "wall_clock"), (True, "wall_tv")} <= kinds


def test_a_negative_seed_is_refused() -> None:
    with pytest.raises(SimError, match="seed -1"):
        draw_changing_room(-1)


def test_rendering_writes_the_truth_beside_the_frames(tmp_path: Path) -> None:
    out = tmp_path / "scene"
    simulate(build_scenario("random_changing", 5), out, RenderOptions(width=64, height=48, frames=2), 5)
    truth = json.loads((out / "changing_truth.json").read_text())
    objects = json.loads((out / "objects.json").read_text())
    assert truth["seed"] == 5 and truth["scenario"] == "random_changing"
    assert {o["name"] for o in objects["objects"]} >= {o["name"] for o in truth["laps"][0]["objects"]}
    assert len(objects["stamps_ns"]) == 2
