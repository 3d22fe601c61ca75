"""Flag regions: a mover's keypoints that the point-wise cues missed are flagged from the flagged ones around them,
and nothing behind it, beside it or on a static scene with a few stray flags."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.movers.flag_regions import FlagRegionConfig, flag_groups, grow_flags
from changing_slam_ros.errors import ConfigError


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """640x480 keypoints: a wall at 3.5-4 m everywhere, a person at 1.4-1.7 m covering x 200..330, y 60..470, and a
    box on a table at 2.4 m (x 450..560, y 250..330) that does not move."""
    px = np.column_stack([rng.uniform(0, 640, 3000), rng.uniform(0, 480, 3000)])
    depth = rng.uniform(3.5, 4.0, 3000)
    person = (px[:, 0] >= 200) & (px[:, 0] <= 330) & (px[:, 1] >= 60) & (px[:, 1] <= 470)
    depth[person] = rng.uniform(1.4, 1.7, person.sum())
    box = (px[:, 0] >= 450) & (px[:, 0] <= 560) & (px[:, 1] >= 250) & (px[:, 1] <= 330)
    depth[box] = rng.normal(2.4, 0.01, box.sum())
    depth[rng.random(3000) < 0.05] = 0.0  # holes
    return px, depth, {"person": person & (depth > 0), "box": box & (depth > 0), "wall": ~person & ~box & (depth > 0)}


def test_a_person_flagged_in_part_is_flagged_whole_and_nothing_behind_or_beside_it() -> None:
    rng = np.random.default_rng(3)
    px, depth, r = _scene(rng)
    # the cues caught 40 % of the person's keypoints, spread over its body, and two stray flags on the wall
    moving = r["person"] & (rng.random(len(px)) < 0.4)
    stray = np.flatnonzero(r["wall"])[:2]
    moving[stray] = True
    out = grow_flags(moving, px, depth, 640, FlagRegionConfig())
    assert out[r["person"]].mean() > 0.97
    assert out[r["wall"]].sum() == 2  # the strays stay alone: no region, no more wall flagged
    assert not out[r["box"]].any()
    assert (out | ~moving).all()  # a flag is never taken back


def test_groups_split_by_depth_and_distance_and_scale_with_the_image_width() -> None:
    px = np.array([[10, 10], [20, 10], [30, 10], [40, 10], [200, 10], [210, 10]], dtype=float)
    depth = np.array([1.0, 1.1, 1.2, 2.0, 1.0, 1.0])
    labels = flag_groups(px, depth, 15.0, 0.25)
    assert labels[0] == labels[1] == labels[2] and labels[3] != labels[2]  # 0.8 m behind: another surface
    assert labels[4] == labels[5] and labels[4] != labels[0]
    # At 320 wide, link_px 24 (640-wide pixels) is 12 px: a group of 6 flags 10 px apart links, at 14 px it does not
    cfg = FlagRegionConfig(min_flags=6, pad_px=0.0, depth_margin_m=0.0)
    between = np.array([[55.0, 100.0]])
    for step, grown in ((10.0, True), (14.0, False)):
        pts = np.vstack([np.column_stack([np.arange(6) * step + 50, np.full(6, 100.0)]), between])
        z = np.full(7, 1.5)
        flags = np.r_[np.ones(6, bool), False]
        assert grow_flags(flags, pts, z, 320, cfg)[-1] == grown, step


def test_too_few_flags_change_nothing_and_bad_settings_are_refused() -> None:
    rng = np.random.default_rng(5)
    px, depth, r = _scene(rng)
    moving = np.zeros(len(px), bool)
    moving[np.flatnonzero(r["person"])[:5]] = True
    assert (grow_flags(moving, px, depth, 640, FlagRegionConfig(min_flags=6)) == moving).all()
    with pytest.raises(ConfigError, match="flag_region.min_flags"):
        FlagRegionConfig(min_flags=0)
    with pytest.raises(ConfigError, match="flag_region.link_px"):
        FlagRegionConfig(link_px=float("nan"))
