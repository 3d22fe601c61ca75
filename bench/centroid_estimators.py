"""Offline study of MapObject centroid / box estimators (target: centroids within 10 cm). Prints, never asserts.

The layer's centroid is the mean of an object's points (`MapObject.set_points`), its 3D box the median of the
5 % extremes per axis (`box_extent`). Both lean toward what the points over-represent: parts seen from many
keyframes (each view adds its own samples), the room inside the box's depth band (floor between a chair's legs,
the wall behind it), and, for views cut by the image border, the part they show. This study takes finished
runs (`changing-slam run ... --objects`: object_map.json with every object's points in the map frame, map.npz
with the static map points, trajectory.txt) and recomputes, per object of the semantic map, the centroid and
box with candidate estimators, each a property a robot would want for any object:

    .venv/bin/python bench/centroid_estimators.py --root /tmp/h5/F/root --tag=-objects-trunc \\
        --scenarios static one_chair changing shift replacing vanishing [--per-object]

The rows and the method: `main`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]


def fit_planes(points: F64, dist_m: float, min_frac: float, max_planes: int, iters: int,
               rng: np.random.Generator) -> list[tuple[F64, float]]:
    """Sequential RANSAC: up to `max_planes` planes (unit normal n (3,), offset d with n.x + d = 0), each
    holding at least `min_frac` of `points` within `dist_m`, refined by least squares on its inliers."""
    planes: list[tuple[F64, float]] = []
    rest = np.asarray(points, float)
    need = max(3, int(min_frac * len(rest)))
    for _ in range(max_planes):
        if len(rest) < need:
            break
        best: Mask | None = None
        for _ in range(iters):
            a, b, c = rest[rng.choice(len(rest), 3, replace=False)]
            n = np.cross(b - a, c - a)
            norm = np.linalg.norm(n)
            if norm < 1e-9:
                continue
            n /= norm
            inl = np.abs((rest - a) @ n) < dist_m
            if best is None or inl.sum() > best.sum():
                best = inl
        if best is None or best.sum() < need:
            break
        for _ in range(2):  # least-squares refit, then re-select inliers
            q = rest[best]
            mu = q.mean(axis=0)
            n = np.linalg.svd(q - mu, full_matrices=False)[2][-1]
            best = np.abs((rest - mu) @ n) < dist_m
        planes.append((n, float(-n @ mu)))
        rest = rest[~best]
    return planes


def off_planes(pts: F64, planes: list[tuple[F64, float]], dist_m: float) -> Mask:
    keep = np.ones(len(pts), bool)
    for n, d in planes:
        keep &= np.abs(pts @ n + d) >= dist_m
    return keep


def largest_cluster(pts: F64, radius_m: float) -> Mask:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(pts) < 2:
        return np.ones(len(pts), bool)
    pairs = cKDTree(pts).query_pairs(radius_m, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts)))
    _, lab = connected_components(g, directed=False)
    return lab == np.bincount(lab).argmax()


def voxel_means(pts: F64, voxel_m: float) -> F64:
    keys = np.floor(pts / voxel_m).astype(np.int64)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    sums = np.zeros((inv.max() + 1, 3))
    np.add.at(sums, inv, pts)
    return sums / np.bincount(inv)[:, None]


def trimmed_mean(pts: F64, keep_frac: float = 0.8) -> F64:
    med = np.median(pts, axis=0)
    d = np.linalg.norm(pts - med, axis=1)
    return pts[d <= np.quantile(d, keep_frac)].mean(axis=0)


@dataclasses.dataclass(frozen=True)
class Params:
    voxel_m: float
    plane_dist_m: float
    cluster_radius_m: float
    own_dist_m: float


def centroid_of(name: str, kept: F64, p: Params) -> F64:
    """The aggregate (last step of `name`) of the kept points (N, 3)."""
    agg = name.split("+")[-1]
    if agg == "vox":
        return voxel_means(kept, p.voxel_m).mean(axis=0)
    if agg == "med":
        return np.median(kept, axis=0)
    if agg == "trim":
        return trimmed_mean(kept)
    return kept.mean(axis=0)


ESTIMATORS = ["core", "mean", "vox", "med", "trim", "plane", "clu", "own", "plane+vox", "own+vox", "own+plane",
              "own+plane+vox", "clu+vox", "plane+clu+vox", "plane+med", "plane+trim"]


def study(root: Path, scenario: str, tag: str, names: list[str], p: Params, plane_args: dict[str, Any],
          per_object: bool) -> dict[str, dict[str, Any]]:
    from changing_slam_ros.commands.objects_options import trajectory_alignment
    from changing_slam_ros.core.objects.map_object import ObjectMapConfig
    from changing_slam_ros.core.objects.semantic_map import build_semantic_map
    from changing_slam_ros.eval.object_metrics import evaluate_objects, load_ground_truth_objects
    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.semantic_map_file import read_object_map
    from changing_slam_ros.io.tum_trajectory import read_tum_trajectory

    from changing_slam_ros.core.objects.object_point_weights import fit_structure_planes as fit_core, reweight_objects

    def fit_structure_planes_core(points: F64, c: Any) -> Any:
        return fit_core(points, c.structure_plane_dist_m, c.structure_plane_min_fraction, c.structure_max_planes,
                        c.structure_plane_iterations, c.structure_plane_max_points)

    reweight_objects_core = reweight_objects
    run = root / "runs" / f"{scenario}{tag}"
    gt_traj = open_dataset(root / scenario, "sim").groundtruth
    T = trajectory_alignment(gt_traj, read_tum_trajectory(run / "trajectory.txt"))
    assert T is not None
    truth = load_ground_truth_objects(root / scenario / "objects.json")
    surf = {k: np.asarray(v) for k, v in json.loads((root / "runs" / f"{scenario}.surface_centroids.json").read_text()).items()}
    z = np.load(run / "map.npz")
    mid = int(z["current_map_id"])
    static = (z[f"m{mid}_pt_object_id"] < 0) & ~z[f"m{mid}_pt_bad"]
    R, t = T[:3, :3], T[:3, 3]
    # everything in the ground-truth frame (boxes are axis-aligned there)
    planes = fit_planes(z[f"m{mid}_pt_positions"][static] @ R.T + t, rng=np.random.default_rng(0), **plane_args)
    objs = [dataclasses.replace(o, point_ids=o.point_ids.copy(), points_w=o.points_w @ R.T + t)
            for o in read_object_map(run / "object_map.json")]
    vols = {o.id: float(np.prod(o.box_size_m)) for o in objs}
    cfg = ObjectMapConfig()
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        if name == "core":  # what the layer computes (core/objects/object_point_weights.py, objects config defaults)
            cp = fit_structure_planes_core(z[f"m{mid}_pt_positions"][static] @ R.T + t, cfg)
            reweight_objects_core(objs, cp, cfg)
        for o in objs:
            if not o.n_points or name == "core":
                continue
            smaller = [q.points_w for q in objs if q.id != o.id and q.n_points and vols[q.id] < vols[o.id]]
            kept = _kept(name, o.points_w, planes, p, np.vstack(smaller) if smaller else None)
            o.centroid_w = centroid_of(name, kept, p)
            o.box_center_w, o.box_size_m = _box(name, kept, p)
        ev = evaluate_objects(build_semantic_map(objs, cfg).objects, truth, surface_centroids=surf)
        cut_only = {o.id for o in objs if o.n_observations == 0}
        errs = {m.gt_name + ("*" if m.estimate_id in cut_only else ""): 100 * m.surface_centroid_error_m
                for m in ev.matches if math.isfinite(m.surface_centroid_error_m)}
        out[name] = {"errs": errs, "iou": ev.mean_iou, "missed": list(ev.missed), "n_planes": len(planes),
                     "vol": {m.gt_name: 100 * m.centroid_error_m for m in ev.matches},
                     "ious": {m.gt_name: m.iou for m in ev.matches}}
    return out


def _kept(name: str, pts: F64, planes: list[tuple[F64, float]], p: Params, smaller: F64 | None = None) -> F64:
    from scipy.spatial import cKDTree

    kept = pts
    for s in name.split("+"):
        if s == "own" and smaller is not None and len(smaller):
            m = cKDTree(smaller).query(kept, distance_upper_bound=p.own_dist_m)[0] > p.own_dist_m
            kept = kept[m] if m.sum() >= 5 else kept
        elif s == "plane":
            m = off_planes(kept, planes, p.plane_dist_m)
            kept = kept[m] if m.sum() >= 5 else kept
        elif s == "clu":
            kept = kept[largest_cluster(kept, p.cluster_radius_m)]
    return kept


def _box(name: str, kept: F64, p: Params) -> tuple[F64, F64]:
    from changing_slam_ros.core.objects.map_object import box_extent

    return box_extent(voxel_means(kept, p.voxel_m) if name.split("+")[-1] == "vox" else kept)


def main() -> int:
    """Parse the options, measure, print the table.

    - `mean`: the current estimator (reproduces bench/changing_scenes.py's visible-surface column);
    - `vox`: voxel-weighted mean: points binned in `--voxel` cubes, each occupied voxel counts once (its points'
      mean), so a part seen from many keyframes does not outweigh the rest of the surface;
    - `plane`: points within `--plane-dist` of one of the room's large planes (floor, walls, table top) are
      structure, not object. The planes are fitted by RANSAC + least squares to the run's *static* map points (map
      points with no object, not culled), never to the object's own points; a plane must hold `--plane-min-frac`
      of them;
    - `clu`: the largest connected cluster of the object's points (points closer than `--cluster-radius` linked);
    - `med`: per-axis median; `trim`: mean of the points within the 80th percentile of distance to the median;
    - `own`: points within `--own-dist` of the points of another object with a smaller box are that object's (the
      teddy bear on a chair);
    - combinations (`plane+vox` etc., filters first, then the aggregate);
    - `core`: what the object layer now computes (core/objects/object_point_weights.py with the `objects:` defaults; the
      same rule as `own+plane+vox`, its box over the kept points rather than over the voxel means).

    Each object is then compared with its visible-surface centroid (bench/changing_scenes.py's cache
    ROOT/runs/SCENARIO.surface_centroids.json) after the same object-placing alignment the bench uses
    (`trajectory_alignment`), matched to ground truth the same way (semantic map at belief >= 0.5, same class
    within 0.3 m of the box centre, recomputed per estimator). Box IoU: the robust box of the kept points (for
    `vox`, of the voxel means).
    """
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, required=True, help="folder with the rendered scenarios and runs/")
    ap.add_argument("--tag", default="-objects-trunc", help="run folder suffix: ROOT/runs/SCENARIO+TAG")
    ap.add_argument("--scenarios", nargs="+", default=["static", "one_chair", "changing", "shift", "replacing", "vanishing"])
    ap.add_argument("--estimators", nargs="+", default=ESTIMATORS)
    ap.add_argument("--voxel", type=float, default=0.025)
    ap.add_argument("--plane-dist", type=float, default=0.02)
    ap.add_argument("--plane-min-frac", type=float, default=0.05)
    ap.add_argument("--max-planes", type=int, default=6)
    ap.add_argument("--cluster-radius", type=float, default=0.06)
    ap.add_argument("--own-dist", type=float, default=0.03)
    ap.add_argument("--per-object", action="store_true", help="also print every object's error per estimator")
    args = ap.parse_args()
    p = Params(args.voxel, args.plane_dist, args.cluster_radius, args.own_dist)
    plane_args = {"dist_m": args.plane_dist, "min_frac": args.plane_min_frac, "max_planes": args.max_planes, "iters": 300}
    results = {s: study(args.root, s, args.tag, args.estimators, p, plane_args, args.per_object) for s in args.scenarios}
    print(f"visible-surface centroid error cm, mean / max (objects over 10 cm), mean box IoU; voxel {args.voxel} m, "
          f"plane dist {args.plane_dist} m, cluster radius {args.cluster_radius} m; planes found: "
          + ", ".join(f"{s} {r[args.estimators[0]]['n_planes']}" for s, r in results.items()))
    print("(* an object known only from views cut by the image border, MapObject.n_observations 0)")
    print("| estimator | " + " | ".join(args.scenarios) + " | all: max / over 10 cm | max without * |")
    print("|---|" + "---|" * (len(args.scenarios) + 2))
    for name in args.estimators:
        cells, allerr, nover = [], [], 0
        for s in args.scenarios:
            r = results[s][name]
            e = list(r["errs"].values())
            allerr += e
            over = [f"{k} {v:.1f}" for k, v in r["errs"].items() if v > 10.0]
            nover += len(over)
            cells.append(f"{np.mean(e):.1f} / {max(e):.1f} ({', '.join(over) or '-'}) {r['iou']:.2f}"
                         + (f" missed {','.join(r['missed'])}" if r["missed"] else ""))
        whole = [v for s in args.scenarios for k, v in results[s][name]["errs"].items() if not k.endswith("*")]
        print(f"| {name} | " + " | ".join(cells) + f" | {max(allerr):.1f} / {nover} | {max(whole):.1f} |")
    print("\ncentroid error to the ground-truth box centre (volume centre) cm, mean / max, per scenario")
    print("| estimator | " + " | ".join(args.scenarios) + " |")
    print("|---|" + "---|" * len(args.scenarios))
    for name in args.estimators:
        vols = [list(results[s][name]["vol"].values()) for s in args.scenarios]
        print(f"| {name} | " + " | ".join(f"{np.mean(v):.1f} / {max(v):.1f}" for v in vols) + " |")
    if args.per_object:
        for s in args.scenarios:
            objs = sorted({k for r in results[s].values() for k in r["errs"]})
            print(f"\n{s}: | estimator | " + " | ".join(objs) + " |")
            for name in args.estimators:
                r = results[s][name]["errs"]
                print(f"| {name} | " + " | ".join(f"{r[k]:.1f}" if k in r else "-" for k in objs) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
