"""Writing a rendered scenario: a TUM folder plus the simulator's own ground truth.

Layout of `out_dir`:
- `rgb/<stamp>.png`, `depth/<stamp>.png` (uint16, metres x 5000, 0 = no reading), `rgb.txt`, `depth.txt`,
  `associations.txt`, `groundtruth.txt` (camera optical frame in the world, TUM format): a TUM RGB-D folder.
- `camera_info.yaml`: the exact intrinsics (ROS calibration format).
- `masks/<stamp>.png`: uint8 instance ids, 0 = room, i + 1 = object i of `objects.json`.
- `objects.json`: every object's class, box and pose per frame (null while absent), and the changes.
- `detections.json`: oracle detections per frame (see `oracle.py`).
- the scenario's `extra_files` (e.g. `changing_truth.json` of the changing-room family).
`sequence.py` adds `sensor.json` (the sensor model, unless exact) and `scenario.json` (a random family's draws).
Every file is written atomically.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import rot_to_quat
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import SimError
from changing_slam_ros.io.atomic import atomic_write_bytes, atomic_write_text
from changing_slam_ros.io.camera_info import write_camera_info_yaml
from changing_slam_ros.io.tum_folder import format_stamp
from changing_slam_ros.io.tum_trajectory import write_tum_trajectory
from changing_slam_ros.sim.oracle import OracleDetection
from changing_slam_ros.sim.renderer import RenderedFrame
from changing_slam_ros.sim.scenarios import Scenario

F64 = npt.NDArray[np.float64]
DEPTH_SCALE = 5000.0  # TUM: depth PNG value per metre


def _png(image: npt.NDArray[Any], what: str) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise SimError(f"{what}: PNG encoding failed")
    return bytes(buf.tobytes())


def depth_png_u16(depth_m: npt.NDArray[np.float32]) -> npt.NDArray[np.uint16]:
    """Metres (H, W) -> TUM depth image values (H, W) uint16 (x5000, rounded, saturating at 13.1 m)."""
    return np.clip(np.rint(depth_m.astype(np.float64) * DEPTH_SCALE), 0, 65535).astype(np.uint16)


def pose_row(T: F64 | None) -> list[float] | None:
    """(4, 4) -> [tx, ty, tz, qx, qy, qz, qw] rounded to 1e-9, or None."""
    if T is None:
        return None
    q = rot_to_quat(T[:3, :3])
    return [round(float(v), 9) for v in (*T[:3, 3], *q)]


class SequenceWriter:
    """Accumulates frames of one scenario into `out_dir`; `finish()` writes the index and JSON files."""

    def __init__(self, out_dir: Path, scenario: Scenario, camera: CameraIntrinsics, seed: int) -> None:
        self.out_dir = Path(out_dir)
        self.scenario = scenario
        self.camera = camera
        self.seed = seed
        for sub in ("rgb", "depth", "masks"):
            (self.out_dir / sub).mkdir(parents=True, exist_ok=True)
        self.stamps_ns: list[int] = []
        self.T_world_cams: list[F64] = []
        self.object_poses: list[list[list[float] | None]] = [[] for _ in scenario.actors]
        self.detections: list[dict[str, Any]] = []

    def add_frame(self, stamp_ns: int, frame: RenderedFrame, T_world_cam: F64, actor_poses: list[F64 | None],
                  detections: list[OracleDetection]) -> None:
        name = f"{format_stamp(stamp_ns)}.png"
        atomic_write_bytes(self.out_dir / "rgb" / name, _png(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR), name))
        atomic_write_bytes(self.out_dir / "depth" / name, _png(depth_png_u16(frame.depth_m), name))
        atomic_write_bytes(self.out_dir / "masks" / name, _png(frame.instance_ids.astype(np.uint8), name))
        self.stamps_ns.append(stamp_ns)
        self.T_world_cams.append(T_world_cam)
        for i, pose in enumerate(actor_poses):
            self.object_poses[i].append(pose_row(pose))
        self.detections.append({"stamp_ns": stamp_ns, "detections": [d.as_dict() for d in detections]})

    def finish(self, start_stamp_ns: int) -> None:
        out = self.out_dir
        names = [f"{format_stamp(s)}" for s in self.stamps_ns]
        header = f"# simulated scenario {self.scenario.name} seed {self.seed}\n# timestamp filename\n"
        atomic_write_text(out / "rgb.txt", header + "".join(f"{n} rgb/{n}.png\n" for n in names))
        atomic_write_text(out / "depth.txt", header + "".join(f"{n} depth/{n}.png\n" for n in names))
        atomic_write_text(out / "associations.txt", "".join(f"{n} rgb/{n}.png {n} depth/{n}.png\n" for n in names))
        stamps_s = np.array(self.stamps_ns, dtype=np.float64) * 1e-9
        write_tum_trajectory(out / "groundtruth.txt", Trajectory.from_poses(stamps_s, np.array(self.T_world_cams)))
        write_camera_info_yaml(out / "camera_info.yaml", self.camera, camera_name="sim_camera")
        objects = []
        for i, actor in enumerate(self.scenario.actors):
            lo, hi = actor.box_m()
            objects.append({
                "id": i + 1, "name": actor.name, "class_id": actor.class_id, "class_name": actor.class_name,
                "moving": actor.moving, "box_min_m": [round(float(v), 6) for v in lo],
                "box_max_m": [round(float(v), 6) for v in hi], "poses": self.object_poses[i],
            })
        changes = [{
            "t_s": c.t_s, "stamp_ns": start_stamp_ns + int(round(c.t_s * 1e9)), "object": c.actor,
            "object_id": self.scenario.actor_index(c.actor) + 1, "kind": c.kind.value, "other": c.other,
        } for c in self.scenario.changes]
        doc = {
            "format": "changing_slam_ros sim objects v1",
            "scenario": self.scenario.name, "description": self.scenario.description, "seed": self.seed,
            "frame": "world: z up, origin at the floor centre; object frame: z up, origin on the floor, front +x;"
                     " pose = [tx, ty, tz, qx, qy, qz, qw] of T_world_object, null while absent",
            "box_frame": "box_min_m / box_max_m: axis-aligned bounds of the object in its own frame",
            "mask_ids": "masks/*.png hold id (uint8); 0 = room",
            "stamps_ns": self.stamps_ns, "objects": objects, "changes": changes,
        }
        atomic_write_text(out / "objects.json", json.dumps(doc, separators=(",", ":")) + "\n")
        for name, text in self.scenario.extra_files:
            atomic_write_text(out / name, text)
        atomic_write_text(out / "detections.json", json.dumps({
            "format": "changing_slam_ros sim oracle detections v1",
            "box": "box_xyxy = [x_min, y_min, x_max, y_max) pixels, max exclusive",
            "frames": self.detections,
        }, separators=(",", ":")) + "\n")
