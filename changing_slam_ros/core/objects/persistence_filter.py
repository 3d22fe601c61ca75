"""Persistence filter (Changing-SLAM §4.6, eqs. 14-17): a binary Bayes filter per MapObject.

M_O = 1: the object is still where it was mapped; M_O = 0: it is not. The prior p(M_O) is the last
belief (0.5 at creation); each observation Y (seen, or missed) updates it with eqs. 14-17
(`bayes_update`), then clamps it to [belief_min, belief_max] so that no single update makes the object
certain forever.

The paper samples p(Y | M_O) "from a Gaussian with mean the current estimated centroid and a covariance
inversely proportional to the number of MapPoints" and says nothing about M_O = 0. Our model
(`likelihood_seen`, `likelihood_missed`) makes both sides probabilities of the same event, so that the
ratio is meaningful: seen close to the mapped centroid raises the belief, seen far off or missed lowers it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.map_object import ObjectMapConfig

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class BeliefUpdate:
    """One filter step: prior, the two likelihoods, the posterior (after clamping)."""

    prior: float
    likelihood_present: float  # p(Y | M_O = 1)
    likelihood_absent: float  # p(Y | M_O = 0)
    posterior: float


def centroid_sigma_m(n_points: int, config: ObjectMapConfig, largest_side_m: float = 0.0) -> float:
    """Standard deviation (metres, per axis) of the mapped centroid of an object with `n_points` points
    and largest box side `largest_side_m`."""
    n = max(1, int(n_points))
    size_term = config.sigma_size_fraction * max(0.0, float(largest_side_m))
    return math.sqrt(config.sigma_point_m ** 2 / n + config.sigma_floor_m ** 2 + size_term ** 2)


def likelihood_seen(observed_centroid_w: F64, mapped_centroid_w: F64, n_points: int,
                    config: ObjectMapConfig, largest_side_m: float = 0.0) -> tuple[float, float]:
    """(p(Y | M_O = 1), p(Y | M_O = 0)) for a candidate with centroid (3,) seen near the mapped one (3,).

    Y = seen at y (a same-class candidate associated, centroid y):

        p(Y | M_O = 1) = p_detect * exp(-0.5 * |y - mu|^2 / sigma^2),
        sigma^2 = sigma_point^2 / n + sigma_floor^2 + (sigma_size_fraction * L)^2

    the Gaussian kernel, peak 1, centred on the mapped centroid mu; its variance shrinks as 1 / n with the n
    points of the object, down to a floor for the candidate's own centroid noise: a half-seen object's
    centroid is off by a decimetre, or a fraction of its largest box side L, whatever n is (`centroid_sigma_m`).
    p(Y | M_O = 0) = p_false: a same-class candidate shows up at an empty place (a false detection or another
    object). Seen close to mu raises the belief (ratio up to p_detect / p_false); seen far off (within the
    association gate but more than ~sigma * sqrt(2 ln(p_detect / p_false)) away) lowers it.
    """
    sigma = centroid_sigma_m(n_points, config, largest_side_m)
    d2 = float(np.sum((np.asarray(observed_centroid_w, float) - np.asarray(mapped_centroid_w, float)) ** 2))
    return config.p_detect * math.exp(-0.5 * d2 / sigma ** 2), config.p_false


def likelihood_missed(config: ObjectMapConfig) -> tuple[float, float]:
    """(p(Y | M_O = 1), p(Y | M_O = 0)) when the object should have been seen and was not.

    Y = missed (the object should have been visible, `object_visibility.py`, and no candidate matched):
    p(Y | M_O = 1) = 1 - p_detect; p(Y | M_O = 0) = 1 - p_false, so a miss lowers the belief by the ratio
    (1 - p_detect) / (1 - p_false).
    """
    return 1.0 - config.p_detect, 1.0 - config.p_false


def bayes_update(prior: float, likelihood_present: float, likelihood_absent: float,
                 config: ObjectMapConfig) -> BeliefUpdate:
    """Eqs. 14-17 with the prior p(M_O = 1) = `prior`, then clamping to [belief_min, belief_max].

        bel(M_O = 1) = p(Y | M_O = 1) p(M_O = 1)                         (16, before eta)
        bel(M_O = 0) = p(Y | M_O = 0) p(M_O = 0)                         (17, before eta)
        eta = 1 / (bel(M_O = 1) + bel(M_O = 0))                          (15)
        bel(M_O) = eta p(Y | M_O) p(M_O)                                  (14)
    """
    bel1 = likelihood_present * prior  # eq. 16 before normalisation
    bel0 = likelihood_absent * (1.0 - prior)  # eq. 17 before normalisation
    total = bel1 + bel0
    if total <= 0.0:  # both hypotheses impossible: keep the prior rather than divide by zero
        posterior = prior
    else:
        eta = 1.0 / total  # eq. 15
        posterior = eta * bel1  # eq. 14 for M_O = 1
    posterior = min(config.belief_max, max(config.belief_min, posterior))
    return BeliefUpdate(prior, likelihood_present, likelihood_absent, posterior)


def update_seen(prior: float, observed_centroid_w: F64, mapped_centroid_w: F64, n_points: int,
                config: ObjectMapConfig, largest_side_m: float = 0.0) -> BeliefUpdate:
    """The object was observed (a candidate associated) at `observed_centroid_w`."""
    l1, l0 = likelihood_seen(observed_centroid_w, mapped_centroid_w, n_points, config, largest_side_m)
    return bayes_update(prior, l1, l0, config)


def update_missed(prior: float, config: ObjectMapConfig) -> BeliefUpdate:
    """The object should have been visible and no candidate was associated with it."""
    l1, l0 = likelihood_missed(config)
    return bayes_update(prior, l1, l0, config)
