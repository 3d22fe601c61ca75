"""Top view (x-y) PNG of a semantic map over the camera trajectory. matplotlib is imported lazily (Agg).

Each object is its box's x-y rectangle, coloured by class, solid when active (belief >= threshold) and
dashed otherwise, labelled "<class> #<id> <belief>"; its centroid is a dot. Optional ground-truth boxes
(min (3,), max (3,) with a name) are drawn in grey for comparison.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.semantic_map import SemanticMap
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.atomic import atomic_write_bytes

F64 = npt.NDArray[np.float64]


def _class_colour(class_id: int) -> tuple[float, float, float]:
    import colorsys

    hue = (class_id * 0.618033988749895) % 1.0
    return colorsys.hsv_to_rgb(hue, 0.75, 0.85)


def plot_semantic_map(path: str | os.PathLike[str], smap: SemanticMap, trajectory_xyz: F64 | None = None,
                      ground_truth: Sequence[tuple[str, F64, F64]] = (), title: str = "semantic map (top view)",
                      dpi: int = 110) -> None:
    """Write the top view to `path` (PNG, atomic). trajectory_xyz (N, 3) camera positions in the map frame."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    if not smap.objects and trajectory_xyz is None and not ground_truth:
        raise EvalError(f"{path}: nothing to plot (no objects, no trajectory)")
    fig = Figure(figsize=(7.0, 6.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for name, lo, hi in ground_truth:
        ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, ec="0.6", lw=1.0, ls=":"))
        ax.text(lo[0], lo[1], name, fontsize=6, color="0.5", va="top")
    if trajectory_xyz is not None and len(trajectory_xyz):
        t = np.asarray(trajectory_xyz, float)
        ax.plot(t[:, 0], t[:, 1], "-", color="0.3", lw=0.8, label="camera")
        ax.plot(t[:1, 0], t[:1, 1], "o", color="0.3", ms=4)
    for o in smap.objects:
        colour = _class_colour(o.class_id)
        lo, hi = o.box_min_w, o.box_max_w
        ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=o.active, alpha=0.35 if o.active
                               else 1.0, fc=colour, ec=colour, lw=1.5, ls="-" if o.active else "--"))
        ax.plot([o.centroid_w[0]], [o.centroid_w[1]], ".", color=colour)
        ax.annotate(f"{o.class_name} #{o.id} {o.belief:.2f}", (o.centroid_w[0], hi[1]), fontsize=7, ha="center",
                    va="bottom", color="black")
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{title}: {sum(o.active for o in smap.objects)} active of {len(smap.objects)} objects")
    ax.grid(True, lw=0.3)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write_bytes(path, buf.getvalue())
