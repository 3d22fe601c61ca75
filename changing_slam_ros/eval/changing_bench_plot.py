"""Plot of a changing-room benchmark: per seed, recall and precision, the wrong objects, and the ATE ratio."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from changing_slam_ros.eval.changing_bench import ATE_RATIO_TARGET, PRECISION_TARGET, SeedResult
from changing_slam_ros.io.atomic import atomic_write_bytes


def plot_changing_bench(results: Sequence[SeedResult], path: Path, title: str = "") -> None:
    """Three panels over the seeds: recall / precision (target line), stale / picture / other spurious counts
    (stacked), ATE / control ATE (target line). Failed seeds are left blank."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.arange(len(results))
    labels = [str(r.seed) for r in results]
    nan = float("nan")
    recall = [r.score.recall if r.score else nan for r in results]
    precision = [r.score.precision if r.score else nan for r in results]
    stale = np.array([len(r.score.stale) if r.score else 0 for r in results])
    pict = np.array([len(r.score.spurious_pictures) if r.score else 0 for r in results])
    other = np.array([len(r.score.spurious_other) if r.score else 0 for r in results])
    fig, axes = plt.subplots(3, 1, figsize=(max(6.0, 0.35 * len(results) + 2), 8), sharex=True)
    axes[0].bar(x - 0.2, recall, 0.4, label="recall")
    axes[0].bar(x + 0.2, precision, 0.4, label="precision")
    axes[0].axhline(PRECISION_TARGET, color="k", lw=0.8, ls="--")
    axes[0].set_ylim(0, 1.05)
    axes[0].legend(loc="lower right", fontsize=8)
    axes[1].bar(x, stale, label="stale")
    axes[1].bar(x, pict, bottom=stale, label="picture as object")
    axes[1].bar(x, other, bottom=stale + pict, label="other spurious")
    axes[1].set_ylabel("active objects")
    axes[1].legend(loc="upper right", fontsize=8)
    axes[2].bar(x, [r.ate_ratio for r in results], color="grey")
    axes[2].axhline(ATE_RATIO_TARGET, color="k", lw=0.8, ls="--")
    axes[2].set_ylabel("ATE / control ATE")
    axes[2].set_xticks(x, labels, rotation=90, fontsize=7)
    axes[2].set_xlabel("seed")
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
