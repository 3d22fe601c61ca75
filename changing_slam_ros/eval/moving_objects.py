"""Exported moving-object trajectories against the simulator's ground truth (`objects.json`).

An exported object's poses E_k are in the SLAM world; `camera_alignment` gives the SE(3) S that maps the
SLAM world onto the ground-truth world (from the camera trajectory the object BA used: the online one).
The object frame differs from the simulator's by a constant rigid Y (our origin is the centre of the
segmented points, the simulator's is on the object's base), estimated as the chordal mean of
G_k^-1 S E_k; the error of pose k is |position of S E_k - position of G_k Y|, i.e. the ATE of the
object's own (segmented) centre.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.movers.object_tracking import MovingObjectTrack
from changing_slam_ros.core.geometry.se3 import make_pose, quat_to_rot
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import EvalError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
SAME_FRAME_NS = 5_000_000  # stamps closer than 5 ms are the same frame


@dataclass(frozen=True)
class ObjectTruth:
    """One simulated object: `stamps_ns` (F,), `T_world_obj` (F, 4, 4) NaN while absent, its mask id."""

    name: str
    class_id: int
    mask_id: int
    stamps_ns: I64
    T_world_obj: F64

    def moving_frames(self, min_step_m: float = 1e-4) -> npt.NDArray[np.bool_]:
        """(F,) True where the object moved between the previous and the next frame."""
        pos = self.T_world_obj[:, :3, 3]
        step = np.zeros(len(pos))
        step[1:-1] = np.linalg.norm(pos[2:] - pos[:-2], axis=1)
        return np.asarray(np.nan_to_num(step) > min_step_m)


def read_sim_movers(sim_dir: Path, class_id: int | None = -1) -> list[ObjectTruth]:
    """The moving objects of a simulated folder's `objects.json` (of `class_id`; None: every class)."""
    path = Path(sim_dir) / "objects.json"
    try:
        doc = json.loads(path.read_text())
        stamps = np.array(doc["stamps_ns"], dtype=np.int64)
        out = []
        for o in doc["objects"]:
            if not o["moving"] or (class_id is not None and o["class_id"] != class_id):
                continue
            poses = np.full((len(stamps), 4, 4), np.nan)
            for k, row in enumerate(o["poses"]):
                if row is not None:
                    poses[k] = make_pose(quat_to_rot(np.array(row[3:7], dtype=np.float64)), np.array(row[:3], dtype=np.float64))
            out.append(ObjectTruth(str(o["name"]), int(o["class_id"]), int(o["id"]), stamps, poses))
    except (OSError, ValueError, KeyError, TypeError, IndexError) as err:
        raise EvalError(f"{path}: cannot read the simulated objects ({err})") from err
    return out


def camera_alignment(gt: Trajectory, est: Trajectory) -> tuple[F64, float]:
    """SE(3) S (4, 4) mapping the estimate's world onto the ground truth's, and the camera ATE RMSE (m).

    S is the chordal mean of G_k E_k^-1 over the associated camera poses (orientations included), not the
    ATE's position-only alignment: a nearly still camera leaves the latter's rotation ill-determined, and
    a rotation error of S moves an object a metre away by centimetres.
    """
    from changing_slam_ros.eval.ate import ate

    res = ate(gt, est)
    G, E = res.association.gt.poses(), res.association.est.poses()
    S = _chordal_mean(np.einsum("nab,nbc->nac", G, np.linalg.inv(E)))
    return S, float(np.sqrt(np.mean(res.errors_m**2)))


def _chordal_mean(poses: F64) -> F64:
    u, _, vt = np.linalg.svd(poses[:, :3, :3].mean(axis=0))
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return make_pose(rot, poses[:, :3, 3].mean(axis=0))


def object_errors_m(track: MovingObjectTrack, S: F64, truth: ObjectTruth) -> F64:
    """Position errors (n,) metres of the track's poses at the frames where the truth exists (module doc)."""
    idx = np.clip(np.searchsorted(truth.stamps_ns, track.stamps_ns), 0, len(truth.stamps_ns) - 1)
    lower = np.clip(idx - 1, 0, len(truth.stamps_ns) - 1)
    idx = np.where(np.abs(truth.stamps_ns[lower] - track.stamps_ns) < np.abs(truth.stamps_ns[idx] - track.stamps_ns), lower, idx)
    near = np.abs(truth.stamps_ns[idx] - track.stamps_ns) < SAME_FRAME_NS
    G = truth.T_world_obj[idx[near]]
    E = np.einsum("ab,nbc->nac", S, track.T_world_obj[near])
    ok = np.all(np.isfinite(G.reshape(len(G), -1)), axis=1)
    G, E = G[ok], E[ok]
    if not len(G):
        return np.zeros(0)
    Y = _chordal_mean(np.einsum("nab,nbc->nac", np.linalg.inv(G), E))
    return np.asarray(np.linalg.norm(E[:, :3, 3] - (G @ Y)[:, :3, 3], axis=1))
