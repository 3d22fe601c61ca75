"""`changing-slam changes MAP_BEFORE MAP_AFTER [--out DIR]`: what changed between two object maps of one room.

    changing-slam changes BEFORE/map.npz AFTER/map.npz [--out DIR] [--map-id N] [--same-place-m 0.3]
        [--replace-radius-m 0.5] [--no-plot]

Each map is a map file (`map.npz`, with keyframe thumbnails), an object-map JSON file (`object_map.json`) or a
semantic-map file (`semantic_map.json`, or what `object_map`'s SaveMap writes: no belief history); both must be in
one frame (the later run started from the earlier map with `--map-in`, or both aligned). Prints one
line per change (moved, removed, added, replaced; `core.objects.change_report`); with --out, DIR receives
`changes.json` (`io.change_report_file`) and `changes.png` (`eval.change_plot`: top view, before / after markers,
keyframe thumbnails). `changing-slam run --map-in` writes the same two files at the end of its run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from changing_slam_ros.core.objects.change_report import ChangeReport, ChangeReportConfig, compare_maps
from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.objects.object_evidence import EvidenceConfig, map_up
from changing_slam_ros.io.change_report_file import read_report_objects, summary_lines, write_change_report

F64 = npt.NDArray[np.float64]
Thumbs = Mapping[int, npt.NDArray[np.uint8]]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("before", metavar="MAP_BEFORE",
                        help="the earlier map: map.npz, object_map.json or a semantic map (JSON / YAML)")
    parser.add_argument("after", metavar="MAP_AFTER", help="the later map, in the same frame")
    parser.add_argument("--out", metavar="DIR", help="write changes.json and changes.png here")
    parser.add_argument("--map-id", type=int, default=None, help="map of the Atlas to compare (default: current)")
    parser.add_argument("--same-place-m", type=float, default=0.3, help="closer centroids are one place (m)")
    parser.add_argument("--replace-radius-m", type=float, default=0.5,
                        help="a gone object and a new one of another class this close were replaced (m)")
    parser.add_argument("--present-belief", type=float, default=0.5,
                        help="objects with at least this belief are in the room (the semantic map's 0.5)")
    parser.add_argument("--no-plot", action="store_true", help="skip changes.png")


def write_change_outputs(out: Path, report: ChangeReport, up_w: F64 | None, before_thumbs: Thumbs,
                         after_thumbs: Thumbs, names: tuple[str, str], plot: bool = True) -> None:
    """`changes.json` and (with `plot`) `changes.png` in `out`; `up_w` (3,) the map's up (None: unknown)."""
    out.mkdir(parents=True, exist_ok=True)
    write_change_report(out / "changes.json", report, *names)
    if plot and (report.changes or report.unchanged):
        from changing_slam_ros.eval.change_plot import plot_change_report

        plot_change_report(out / "changes.png", report, up_w, before_thumbs, after_thumbs)


def main(args: argparse.Namespace) -> int:
    before = read_report_objects(args.before, args.map_id)
    after = read_report_objects(args.after, args.map_id)
    evidence = EvidenceConfig(args.present_belief)
    report = compare_maps(before.evidence(evidence), after.evidence(evidence),
                          ChangeReportConfig(args.same_place_m, args.replace_radius_m))
    for line in summary_lines(report):
        print(line)
    counts = report.counts()
    print(", ".join(f"{v} {k}" for k, v in counts.items()))
    if args.out:
        up = map_up([*before.objects, *after.objects])
        write_change_outputs(Path(args.out), report, up, before.thumbnails, after.thumbnails,
                             (str(args.before), str(args.after)), not args.no_plot)
        print(f"results in {args.out}")
    return 0
