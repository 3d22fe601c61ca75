"""Uniform draws shared by the randomised scene generators (rooms, movers, furniture, changes).

Each draw is one `rng.uniform` call, so a seed's scene depends only on the order of the draws, never on which
module makes them.
"""

from __future__ import annotations

import numpy as np


def between(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A value drawn uniformly from [lo, hi)."""
    return float(rng.uniform(lo, hi))


def within(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    """A value drawn uniformly from a (lo, hi) range."""
    return float(rng.uniform(lo_hi[0], lo_hi[1]))
