"""`changing-slam run --map-in M --localization` on the TUM fr1_xyz frames replayed against their own map: the map
comes back byte for byte, poses as accurate as the mapping run's, the mapped objects seen at their place."""

from __future__ import annotations

import json

from helpers import FR1_XYZ_10, require

from changing_slam_ros.cli import main as cli_main


def test_localisation_writes_the_loaded_map_back_unchanged_and_tracks_as_well_as_mapping(tmp_path, capsys) -> None:
    data = str(require(FR1_XYZ_10))
    first, loc = tmp_path / "map", tmp_path / "loc"
    assert cli_main(["run", data, "--out", str(first), "--config", "tum_fr1", "--quiet", "--no-plot"]) == 0
    assert cli_main(["run", data, "--out", str(loc), "--config", "tum_fr1", "--quiet", "--no-plot",
                     "--map-in", str(first / "map.npz"), "--localization"]) == 0  # fmt: skip
    assert (loc / "map.npz").read_bytes() == (first / "map.npz").read_bytes()
    m1 = json.loads((first / "metrics.json").read_text())
    m2 = json.loads((loc / "metrics.json").read_text())
    assert m2["frames_tracked"] == 9 and m2["keyframes"] == m1["keyframes"] == 1 and m2["maps"] == 1
    assert m2["multi_session"]["relocalised_frame"] == 0
    # Mapping run 0.35 cm; localisation in its map: the same frames against the same points.
    assert m2["ate_rmse_m"] <= 1.2 * m1["ate_rmse_m"] and m2["ate_rmse_m"] < 0.005
    # The detector's 5 objects of the first run (COCO 41 cup, 62 tv, 63 laptop, 66 keyboard, 73 book), each
    # present at its mapped place in all 9 frames.
    seen = json.loads((loc / "object_sightings.json").read_text())
    assert sorted(s["class_id"] for s in seen) == [41, 62, 63, 66, 73]
    assert all(s["frames_present"] == 9 and s["frames_missing"] == 0 for s in seen)
    assert m2["localization"] == {"objects_seen": 5, "frames_lost": 0}
    rc = cli_main(["run", data, "--out", str(tmp_path / "bad"), "--config", "tum_fr1", "--quiet", "--localization"])
    assert rc == 1 and "--localization needs --map-in" in capsys.readouterr().err
