"""PNG figures of evaluation results. matplotlib is imported inside the functions only.

Figures are drawn on a `matplotlib.figure.Figure` with the Agg canvas (no pyplot, no global
state, no display needed) and written atomically.
"""

from __future__ import annotations

import io
import os
from typing import TYPE_CHECKING

from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError
from changing_slam_ros.eval.ate import AteResult
from changing_slam_ros.eval.rpe import RpeResult
from changing_slam_ros.io.atomic import atomic_write_bytes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

_AXES = {"x": 0, "y": 1, "z": 2}


def _plane_axes(plane: str) -> tuple[int, int]:
    if len(plane) != 2 or plane[0] == plane[1] or any(c not in _AXES for c in plane):
        raise EvalError(f"plot plane must be two of x, y, z (e.g. 'xy'), got {plane!r}")
    return _AXES[plane[0]], _AXES[plane[1]]


def _save(fig: Figure, path: str | os.PathLike[str]) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    try:
        atomic_write_bytes(path, buf.getvalue())
    except OSError as err:
        raise EvalError(f"{path}: cannot write plot ({err.strerror or err})") from err


def plot_ate(
    result: AteResult,
    path: str | os.PathLike[str],
    gt_full: Trajectory | None = None,
    plane: str = "xy",
    title: str = "",
) -> None:
    """Write a PNG: aligned estimate and ground truth seen from above, and ATE over time.

    `gt_full` (optional) is the whole ground-truth trajectory, drawn faintly under the
    associated part. `plane` picks the two world axes of the top view.
    """
    from matplotlib.figure import Figure

    a, b = _plane_axes(plane)
    gt = result.association.gt
    est = result.est_aligned
    fig = Figure(figsize=(12, 5), dpi=100)
    ax_top = fig.add_subplot(1, 2, 1)
    if gt_full is not None and len(gt_full):
        ax_top.plot(gt_full.positions[:, a], gt_full.positions[:, b], color="0.8", lw=1,
                    label="ground truth (all)")
    ax_top.plot(gt.positions[:, a], gt.positions[:, b], color="k", lw=1.2, label="ground truth")
    ax_top.plot(est.positions[:, a], est.positions[:, b], color="tab:blue", lw=1.2,
                label="estimate (aligned)")
    ax_top.plot(est.positions[0, a], est.positions[0, b], "o", color="tab:green", label="start")
    ax_top.set_xlabel(f"{plane[0]} [m]")
    ax_top.set_ylabel(f"{plane[1]} [m]")
    ax_top.set_aspect("equal", adjustable="datalim")
    ax_top.grid(True, alpha=0.3)
    ax_top.legend(loc="best", fontsize=8)
    align = "Sim(3)" if result.sim3 else ("SE(3)" if result.aligned else "no")
    ax_top.set_title(f"top view ({align} alignment)")

    ax_err = fig.add_subplot(1, 2, 2)
    t = result.stamps_s - result.stamps_s[0]
    ax_err.plot(t, result.errors_m, color="tab:red", lw=1, label="ATE")
    s = result.stats
    ax_err.axhline(s.rmse, color="k", ls="--", lw=1, label=f"RMSE {s.rmse:.4f} m")
    ax_err.axhline(s.median, color="0.5", ls=":", lw=1, label=f"median {s.median:.4f} m")
    ax_err.set_xlabel("time since first associated pose [s]")
    ax_err.set_ylabel("translation error [m]")
    ax_err.set_ylim(bottom=0)
    ax_err.grid(True, alpha=0.3)
    ax_err.legend(loc="best", fontsize=8)
    ax_err.set_title(f"ATE over time ({s.count} poses)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def plot_rpe(result: RpeResult, path: str | os.PathLike[str], title: str = "") -> None:
    """Write a PNG: RPE translation (m) and rotation (deg) per pair over time."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 6), dpi=100)
    t = result.stamps_s - result.association.gt.stamps_s[0]
    unit = "frame" if result.delta_unit.value == "frames" else "s"
    for row, (errors, stats, label) in enumerate(
        (
            (result.trans_errors_m, result.trans, "translation [m]"),
            (result.rot_errors_deg, result.rot, "rotation [deg]"),
        )
    ):
        ax = fig.add_subplot(2, 1, row + 1)
        ax.plot(t, errors, lw=1, color="tab:red" if row == 0 else "tab:purple")
        ax.axhline(stats.rmse, color="k", ls="--", lw=1, label=f"RMSE {stats.rmse:.4f}")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    ax.set_xlabel("time since first associated pose [s]")
    fig.suptitle(title or f"RPE, delta {result.delta:g} {unit} ({len(result.pairs)} pairs)")
    fig.tight_layout()
    _save(fig, path)

