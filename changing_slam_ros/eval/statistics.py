"""Summary statistics of a vector of per-pose errors, defined as evo defines them."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ErrorStatistics:
    """Statistics of N errors e_i (all in one unit: metres or degrees).

    rmse = sqrt(mean(e^2)), std is the population standard deviation (divides by N, like
    `np.std` and evo), sse = sum(e^2). Every error is used: there is no outlier rejection.
    """

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    count: int

    @classmethod
    def of(cls, errors: F64) -> "ErrorStatistics":
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if len(e) == 0:
            raise EvalError("no errors to summarise (0 pose pairs)")
        sq = np.power(e, 2)
        return cls(
            rmse=math.sqrt(float(np.mean(sq))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(sq)),
            count=int(len(e)),
        )

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)
