"""The seed benchmark's figure: ATE per seed of the plain engine and the full pipeline, and of both on each
seed's control. matplotlib is imported inside the function only (see `plots`)."""

from __future__ import annotations

import os
from typing import Any

from changing_slam_ros.eval.plots import _save


def plot_seed_bench(doc: dict[str, Any], path: str | os.PathLike[str]) -> None:
    """Bars of ATE RMSE (cm, log scale) per seed from a `run_seed_bench` result, written to `path` (PNG)."""
    from matplotlib.figure import Figure

    rows = doc["per_seed"]
    seeds = [r["seed"] for r in rows]
    fig = Figure(figsize=(max(6.0, 0.35 * len(seeds) + 2.0), 4.0), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    kinds = [("plain", "plain engine", "#bbbbbb"), ("full", "full pipeline", "#1f77b4"),
             ("control_plain", "control, plain", "#dddddd"), ("control_full", "control, full", "#9ecae1")]
    kinds = [k for k in kinds if any(k[0] in r["runs"] for r in rows)]
    width = 0.8 / len(kinds)
    for i, (kind, label, colour) in enumerate(kinds):
        xs, ys = [], []
        for j, r in enumerate(rows):
            ate = r["runs"].get(kind, {}).get("ate_rmse_m")
            if ate is not None:
                xs.append(j + (i - (len(kinds) - 1) / 2) * width)
                ys.append(max(100 * ate, 1e-3))
        ax.bar(xs, ys, width=width, color=colour, label=label, edgecolor="none")
    ax.set_yscale("log")
    ax.axhline(1.0, color="#2ca02c", lw=0.8, ls="--", label="1 cm")
    ax.set_xticks(range(len(seeds)))
    ax.set_xticklabels([str(s) for s in seeds], rotation=90 if len(seeds) > 15 else 0, fontsize=7)
    ax.set_xlabel("seed")
    ax.set_ylabel("ATE RMSE (cm)")
    ax.set_title(f"{doc['scenario']}: ATE per seed", fontsize=10)
    ax.legend(fontsize=7, ncol=len(kinds) + 1, loc="upper left")
    fig.tight_layout()
    _save(fig, path)
