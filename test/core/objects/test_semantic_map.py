"""The semantic map keeps every object seen and not contradicted, flagging the unconfirmed ones."""

from __future__ import annotations

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import MapObject, ObjectMapConfig, object_map_config
from changing_slam_ros.core.objects.semantic_map import build_semantic_map
from changing_slam_ros.errors import ConfigError


def _objects(cfg: ObjectMapConfig) -> list[MapObject]:
    rng = np.random.default_rng(1)
    out = []
    # confirmed (re-observed on a later pass), seen in one pass only (0.5), mixed evidence (0.55), contradicted
    # (missed where expected), and a confirmed one with fewer than min_points points
    for oid, belief, n in ((4, 0.89, 40), (2, 0.5, 40), (7, 0.55, 40), (1, 0.18, 40), (9, 0.9, 3)):
        pts = np.array([oid, 0.0, 1.0]) + rng.uniform(-0.1, 0.1, (n, 3))
        out.append(MapObject(oid, 56, (0, 0, 10, 10), (0, 0, 10, 10), 0, 5, belief=belief,
                             active=belief >= cfg.belief_threshold, point_ids=np.arange(n) + 100 * oid, points_w=pts))
    return out


def test_default_map_keeps_unconfirmed_objects_flagged_and_drops_contradicted_ones() -> None:
    cfg = ObjectMapConfig()
    assert cfg.semantic_min_belief == 0.5 and cfg.belief_threshold == 0.6
    smap = build_semantic_map(_objects(cfg), cfg)
    assert smap.belief_threshold == 0.5
    assert [(o.id, o.confirmed) for o in smap.objects] == [(2, False), (4, True), (7, False)]
    confirmed = build_semantic_map(_objects(cfg), cfg, min_belief=cfg.belief_threshold)
    assert [o.id for o in confirmed.objects] == [4]
    # a map limited to confirmed objects by configuration
    strict = ObjectMapConfig(semantic_min_belief=0.6)
    assert [o.id for o in build_semantic_map(_objects(strict), strict).objects] == [4]


def test_semantic_min_belief_must_lie_within_the_belief_clamp() -> None:
    with pytest.raises(ConfigError, match="objects.semantic_min_belief"):
        ObjectMapConfig(semantic_min_belief=0.995)
    with pytest.raises(ConfigError, match="objects.semantic_min_belief"):
        ObjectMapConfig(semantic_min_belief=0.0)
    assert ObjectMapConfig(belief_threshold=0.4).semantic_min_belief == 0.5  # a low threshold stays valid
    with pytest.raises(ConfigError, match="objects.min_projected_area_fraction"):
        object_map_config({"min_projected_area_fraction": 1.5})
    assert object_map_config({"semantic_min_belief": 0.3}).semantic_min_belief == 0.3
