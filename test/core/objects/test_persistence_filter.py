"""Persistence filter (Changing-SLAM §4.6, eqs. 14-17): hand-computed steps, monotonicity, clamping."""

from __future__ import annotations

import math

import numpy as np
import pytest

from changing_slam_ros.core.objects.map_object import ObjectMapConfig, object_map_config
from changing_slam_ros.core.objects.persistence_filter import (
    bayes_update, centroid_sigma_m, likelihood_missed, likelihood_seen, update_missed, update_seen,
)
from changing_slam_ros.errors import ConfigError

CFG = ObjectMapConfig(p_detect=0.8, p_false=0.1, sigma_point_m=1.0, sigma_floor_m=0.1, belief_min=0.01,
                      belief_max=0.99)
C0 = np.array([1.0, 2.0, 0.5])


def test_seen_at_the_mapped_centroid_matches_eqs_14_to_17_by_hand() -> None:
    # p(Y|M=1) = 0.8, p(Y|M=0) = 0.1, prior 0.5: bel1 = 0.4, bel0 = 0.05, eta = 1 / 0.45
    upd = update_seen(0.5, C0, C0, 100, CFG)
    assert upd.likelihood_present == pytest.approx(0.8)
    assert upd.likelihood_absent == pytest.approx(0.1)
    assert upd.posterior == pytest.approx(0.4 / 0.45, abs=1e-12)  # 0.888889
    # second step, prior 0.888889: 0.8 * 0.888889 / (0.8 * 0.888889 + 0.1 * 0.111111) = 0.984615
    upd2 = update_seen(upd.posterior, C0, C0, 100, CFG)
    assert upd2.posterior == pytest.approx(0.9846153846153847, abs=1e-12)


def test_seen_twenty_centimetres_off_uses_a_gaussian_whose_variance_shrinks_with_points() -> None:
    # n = 100: sigma^2 = 1 / 100 + 0.01 = 0.02; d = 0.2: kernel exp(-0.5 * 0.04 / 0.02) = exp(-1)
    assert centroid_sigma_m(100, CFG) == pytest.approx(math.sqrt(0.02))
    l1, l0 = likelihood_seen(C0 + [0.2, 0.0, 0.0], C0, 100, CFG)
    assert l1 == pytest.approx(0.8 * math.exp(-1.0))
    upd = update_seen(0.5, C0 + [0.2, 0.0, 0.0], C0, 100, CFG)
    assert upd.posterior == pytest.approx(0.7463882857379717, abs=1e-12)
    # fewer points -> wider Gaussian -> the same offset is more plausible
    few = update_seen(0.5, C0 + [0.2, 0.0, 0.0], C0, 10, CFG)
    assert few.posterior > upd.posterior
    assert centroid_sigma_m(10, CFG) == pytest.approx(math.sqrt(0.1 + 0.01))
    # a 1.4 m table: + (0.25 * 1.4)^2, so a 0.3 m offset of a partial view still counts as seen
    assert centroid_sigma_m(100, CFG, 1.4) == pytest.approx(math.sqrt(0.02 + 0.35 ** 2))
    assert update_seen(0.5, C0 + [0.3, 0.0, 0.0], C0, 100, CFG, 1.4).posterior > 0.7


def test_missed_where_expected_lowers_the_belief_by_hand() -> None:
    assert likelihood_missed(CFG) == pytest.approx((0.2, 0.9))
    upd = update_missed(0.5, CFG)
    assert upd.posterior == pytest.approx(0.1 / 0.55, abs=1e-12)  # 0.181818


def test_belief_rises_with_repeated_observations_and_falls_with_misses_within_limits() -> None:
    b, rising = 0.5, []
    for _ in range(10):
        b = update_seen(b, C0 + 0.02, C0, 60, CFG).posterior
        rising.append(b)
    assert all(x < y for x, y in zip(rising, rising[1:]) if y < CFG.belief_max)
    assert rising[-1] == pytest.approx(CFG.belief_max)  # clamped, never 1
    falling = []
    for _ in range(10):
        b = update_missed(b, CFG).posterior
        falling.append(b)
    assert all(x > y for x, y in zip(falling, falling[1:]) if y > CFG.belief_min)
    assert falling[-1] == pytest.approx(CFG.belief_min)  # clamped, never 0
    assert all(0.0 < x < 1.0 for x in rising + falling)


def test_seen_far_from_the_mapped_centroid_lowers_the_belief() -> None:
    # kernel below p_false / p_detect = 0.125 when d > sigma * sqrt(2 ln 8) = 0.141 * 2.04 = 0.29 m (n = 100)
    assert update_seen(0.5, C0 + [0.35, 0.0, 0.0], C0, 100, CFG).posterior < 0.5
    assert update_seen(0.5, C0 + [0.25, 0.0, 0.0], C0, 100, CFG).posterior > 0.5


def test_zero_likelihoods_keep_the_prior_and_clamp() -> None:
    assert bayes_update(0.7, 0.0, 0.0, CFG).posterior == pytest.approx(0.7)
    assert bayes_update(0.7, 1.0, 0.0, CFG).posterior == pytest.approx(CFG.belief_max)
    assert bayes_update(0.7, 0.0, 1.0, CFG).posterior == pytest.approx(CFG.belief_min)


def test_config_from_yaml_section_and_bad_values_name_the_field() -> None:
    cfg = object_map_config({"ltda_threshold_m": 0.4, "n_keyframes_unseen": 3, "belief_threshold": 0.7})
    assert (cfg.ltda_threshold_m, cfg.n_keyframes_unseen, cfg.belief_threshold) == (0.4, 3, 0.7)
    with pytest.raises(ConfigError, match="unknown key.*ltda"):
        object_map_config({"ltda": 0.4}, "cfg.yaml: objects")
    with pytest.raises(ConfigError, match="p_detect .* must exceed p_false"):
        ObjectMapConfig(p_detect=0.1, p_false=0.2)
    with pytest.raises(ConfigError, match="belief_min / belief_max"):
        ObjectMapConfig(belief_min=0.0)
    with pytest.raises(ConfigError, match="belief_threshold"):
        ObjectMapConfig(belief_threshold=0.995)
