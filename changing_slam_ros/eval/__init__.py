"""Trajectory evaluation as a library: ATE / RPE, alignment, reports. Plotting lives in `eval.plots`.

    from changing_slam_ros.eval import ate, rpe, evaluate, DeltaUnit
    result = ate(gt, est, max_diff_s=0.02, sim3=False)   # -> AteResult, result.stats.rmse in metres

Nothing imported here loads matplotlib.
"""

from changing_slam_ros.eval.alignment import Alignment, align_trajectories, umeyama
from changing_slam_ros.eval.association import DEFAULT_MAX_DIFF_S, Association, associate
from changing_slam_ros.eval.ate import AteResult, ate
from changing_slam_ros.eval.report import evaluate, evaluate_files
from changing_slam_ros.eval.rpe import DeltaUnit, RpeResult, rpe
from changing_slam_ros.eval.statistics import ErrorStatistics

__all__ = [
    "DEFAULT_MAX_DIFF_S",
    "Alignment",
    "AteResult",
    "Association",
    "DeltaUnit",
    "ErrorStatistics",
    "RpeResult",
    "align_trajectories",
    "associate",
    "ate",
    "evaluate",
    "evaluate_files",
    "rpe",
    "umeyama",
]
