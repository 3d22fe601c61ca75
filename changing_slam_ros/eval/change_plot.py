"""Top-down plan PNG of a change report, with keyframe thumbnails. matplotlib is imported lazily (Agg).

Left: the plan, seen along the map's up direction. Earlier places are hollow circles, later places filled dots,
each in its class's colour; a move is an arrow from the old place to the new one with its distance; a removed
object is a red cross at its old place, an added one a green plus, a replacement a hollow circle joined to the
new object's dot; unchanged objects are small grey dots. Right: one row per change (at most `max_rows`): the
last keyframe that saw the object before (thumbnail of the earlier map) and the keyframe that shows the change
after (the first sighting at the new place, or the last expected miss of a removed object), when kept.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.change_report import Change, ChangeKind, ChangeReport
from changing_slam_ros.core.objects.object_evidence import ObjectEvidence
from changing_slam_ros.errors import EvalError
from changing_slam_ros.io.atomic import atomic_write_bytes

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
Thumbs = Mapping[int, U8]
KIND_COLOUR = {ChangeKind.MOVED: "tab:orange", ChangeKind.REMOVED: "tab:red", ChangeKind.ADDED: "tab:green",
               ChangeKind.REPLACED: "tab:purple"}


def plan_axes(up_w: F64 | None) -> tuple[F64, F64]:
    """Two unit axes (3,) spanning the plane perpendicular to `up_w` (None: the first camera's up, -y of the
    optical frame); the first is the world axis least aligned with up, made perpendicular to it."""
    up = np.array([0.0, -1.0, 0.0]) if up_w is None else np.asarray(up_w, float) / np.linalg.norm(up_w)
    seed = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = seed - (seed @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2


def _xy(e: ObjectEvidence, axes: tuple[F64, F64]) -> tuple[float, float]:
    c = np.asarray(e.centroid_w, float)
    return float(c @ axes[0]), float(c @ axes[1])


def _colour(class_id: int) -> tuple[float, float, float]:
    import colorsys

    return colorsys.hsv_to_rgb((class_id * 0.618033988749895) % 1.0, 0.75, 0.85)


def evidence_frames(change: Change) -> tuple[int | None, int | None]:
    """(keyframe of the earlier map that last saw the object, keyframe of the later map that shows the change)."""
    before = change.before.seen_keyframes[-1] if change.before is not None and change.before.seen_keyframes else None
    after = None
    if change.after is not None and change.after.seen_keyframes:
        after = change.after.seen_keyframes[0]
    elif change.before_later is not None:
        missed = [k for k, _, r in change.before_later.belief_history if r == "missed"]
        after = missed[-1] if missed else None
    return before, after


def plot_change_report(path: str | os.PathLike[str], report: ChangeReport, up_w: F64 | None = None,
                       before_thumbs: Thumbs | None = None, after_thumbs: Thumbs | None = None,
                       title: str = "what changed (top view)", max_rows: int = 6, dpi: int = 110) -> None:
    """Write the plan and the thumbnails to `path` (PNG, atomic)."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not report.changes and not report.unchanged:
        raise EvalError(f"{path}: nothing to plot (no objects in either map)")
    rows = list(report.changes[:max_rows])
    fig = Figure(figsize=(11.0, 6.0))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(max(len(rows), 1), 3, width_ratios=(3.2, 1.0, 1.0))
    ax = fig.add_subplot(grid[:, 0])
    axes = plan_axes(up_w)
    for b, a in report.unchanged:
        x, y = _xy(a, axes)
        ax.plot([x], [y], "o", color="0.6", ms=4)
        ax.annotate(f"{a.class_name} #{a.id}", (x, y), fontsize=6, color="0.45", xytext=(3, 3), textcoords="offset points")
    for c in report.changes:
        colour = KIND_COLOUR[c.kind]
        if c.before is not None:
            x0, y0 = _xy(c.before, axes)
            marker = "x" if c.kind == ChangeKind.REMOVED else "o"
            ax.plot([x0], [y0], marker, mfc="none", mec=_colour(c.before.class_id), ms=9, mew=2)
            ax.annotate(f"{c.kind.value}: {c.before.class_name} #{c.before.id}", (x0, y0), fontsize=7, color=colour,
                        xytext=(4, -10), textcoords="offset points")
        if c.after is not None:
            x1, y1 = _xy(c.after, axes)
            ax.plot([x1], [y1], "P" if c.kind == ChangeKind.ADDED else "o", color=_colour(c.after.class_id), ms=8)
            if c.before is None or c.kind == ChangeKind.REPLACED:
                ax.annotate(f"{c.kind.value}: {c.after.class_name} #{c.after.id}", (x1, y1), fontsize=7,
                            color=colour, xytext=(4, 4), textcoords="offset points")
        if c.before is not None and c.after is not None:
            ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.5})
            ax.text((x0 + x1) / 2, (y0 + y1) / 2, f"{c.distance_m:.2f} m", fontsize=7, color=colour)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.margins(0.15)
    ax.set_xlabel("m")
    ax.set_ylabel("m")
    ax.set_title(title + "; hollow: before, filled: after", fontsize=9)
    for i, c in enumerate(rows):
        kb, ka = evidence_frames(c)
        for j, (thumbs, kf, when) in enumerate(((before_thumbs, kb, "before"), (after_thumbs, ka, "after"))):
            tax = fig.add_subplot(grid[i, 1 + j])
            tax.set_xticks([])
            tax.set_yticks([])
            img = None if thumbs is None or kf is None else thumbs.get(kf)
            if img is not None:
                tax.imshow(img)
            else:
                tax.text(0.5, 0.5, "no image", ha="center", va="center", fontsize=7, color="0.5")
            ref = c.before if c.before is not None else c.after
            assert ref is not None
            tax.set_title(f"{c.kind.value} {ref.class_name}: {when}" + ("" if kf is None else f" kf {kf}"), fontsize=6)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write_bytes(path, buf.getvalue())
