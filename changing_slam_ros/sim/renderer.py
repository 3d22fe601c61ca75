"""Offscreen rendering of a scene with MuJoCo: colour, metric depth and instance ids for one camera pose.

MuJoCo renders through OpenGL; on a machine without a display we use OSMesa (`MUJOCO_GL=osmesa`, the
Debian package `libosmesa6`), set here before `mujoco` is first imported unless the caller chose
another backend (`egl` on a GPU host).

Two passes per frame: a shaded colour pass, and one segmentation pass from which both the depth buffer
and the per-pixel geom ids are read. Intrinsics follow from MuJoCo's projection: the vertical field of
view `fovy` spans the full image height edge to edge, so fy = fx = (H / 2) / tan(fovy / 2) and the
principal point is the image centre, cx = (W - 1) / 2, cy = (H - 1) / 2, in the convention where pixel
(0, 0) has its centre at (0, 0) (OpenCV, ROS). `test/sim/test_renderer.py` checks this on drawn points.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from types import TracebackType

import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.geometry.se3 import rot_to_quat
from changing_slam_ros.errors import SimError
from changing_slam_ros.sim.scene import (
    CAMERA_BODY, PARK_POSITION_M, SceneSpec, actor_body_name, build_mjcf,
)

os.environ.setdefault("MUJOCO_GL", "osmesa")

F64 = npt.NDArray[np.float64]

# MuJoCo camera frame (x right, y up, looking along -z) from the optical frame (x right, y down, z forward).
T_OPTICAL_MJCAM = np.diag([1.0, -1.0, -1.0, 1.0])


def intrinsics_for(width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
    """Exact pinhole intrinsics of a MuJoCo camera with vertical field of view `fovy_deg`.

    fx = fy = (H / 2) / tan(fovy / 2), cx = (W - 1) / 2, cy = (H - 1) / 2: 525 / 319.5 / 239.5 at 640x480,
    the ROS default for TUM.
    """
    f = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    return CameraIntrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def fovy_for_focal(height: int, fy_px: float) -> float:
    """The vertical field of view (degrees) that gives focal length `fy_px` at image height `height`."""
    return math.degrees(2.0 * math.atan((height / 2.0) / fy_px))


@dataclass
class RenderedFrame:
    """rgb (H, W, 3) uint8; depth_m (H, W) float32 metres along the optical axis (0 = nothing);
    instance_ids (H, W) uint16: 0 for the room, i + 1 for actor i."""

    rgb: npt.NDArray[np.uint8]
    depth_m: npt.NDArray[np.float32]
    instance_ids: npt.NDArray[np.uint16]


class SimRenderer:
    """Owns a compiled MuJoCo model and an offscreen GL context; renders frames for given poses."""

    def __init__(self, spec: SceneSpec) -> None:
        try:
            import mujoco
        except ImportError as err:  # pragma: no cover - mujoco is pinned in requirements.txt
            raise SimError("mujoco is not installed (pip install -r requirements.txt)") from err
        self._mj = mujoco
        self.spec = spec
        mjcf = build_mjcf(spec)
        try:
            self.model = mujoco.MjModel.from_xml_string(mjcf.xml, mjcf.assets)
        except Exception as err:  # noqa: BLE001 - MuJoCo raises ValueError with the compiler message
            raise SimError(f"scene MJCF does not compile: {err}") from err
        self.data = mujoco.MjData(self.model)
        self.camera = intrinsics_for(spec.width, spec.height, spec.fovy_deg)
        self._actor_mocap = []
        for i in range(len(spec.actors)):
            body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, actor_body_name(i))
            self._actor_mocap.append(int(self.model.body_mocapid[body]))
        cam_body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, CAMERA_BODY)
        self._camera_mocap = int(self.model.body_mocapid[cam_body])
        # geom id -> instance id (0 room, i + 1 actor i)
        self._geom_instance = np.zeros(self.model.ngeom, dtype=np.uint16)
        for i in range(len(spec.actors)):
            body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, actor_body_name(i))
            self._geom_instance[self.model.geom_bodyid == body] = i + 1
        try:
            self._gl = mujoco.GLContext(spec.width, spec.height)
            self._gl.make_current()
        except Exception as err:  # noqa: BLE001 - backend-specific errors
            raise SimError(
                f"cannot create an offscreen OpenGL context with MUJOCO_GL={os.environ.get('MUJOCO_GL')} "
                f"({err}); on Debian install libosmesa6 (see tools/apt-packages.txt)"
            ) from err
        self._ctx = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._ctx)
        self._ctx.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(self.model, maxgeom=2000)
        self._option = mujoco.MjvOption()
        self._mjv_camera = mujoco.MjvCamera()
        self._mjv_camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._mjv_camera.fixedcamid = 0
        self._rect = mujoco.MjrRect(0, 0, spec.width, spec.height)
        extent = float(self.model.stat.extent)
        self.znear_m = float(self.model.vis.map.znear) * extent
        self.zfar_m = float(self.model.vis.map.zfar) * extent

    # --- posing ---
    def _set_mocap(self, index: int, T_world_obj: F64 | None) -> None:
        if T_world_obj is None:
            self.data.mocap_pos[index] = PARK_POSITION_M
            self.data.mocap_quat[index] = (1.0, 0.0, 0.0, 0.0)
            return
        q = rot_to_quat(T_world_obj[:3, :3])
        self.data.mocap_pos[index] = T_world_obj[:3, 3]
        self.data.mocap_quat[index] = (q[3], q[0], q[1], q[2])  # MuJoCo quaternions are (w, x, y, z)

    def render(self, T_world_cam: F64, actor_poses: list[F64 | None]) -> RenderedFrame:
        """Render the view of the optical-frame camera pose `T_world_cam` (4, 4) with actors posed
        as `actor_poses` (one (4, 4) or None per actor, None = absent)."""
        mj = self._mj
        if len(actor_poses) != len(self._actor_mocap):
            raise SimError(f"render: {len(actor_poses)} actor poses for {len(self._actor_mocap)} actors")
        for idx, pose in zip(self._actor_mocap, actor_poses):
            self._set_mocap(idx, pose)
        self._set_mocap(self._camera_mocap, T_world_cam @ T_OPTICAL_MJCAM)
        mj.mj_kinematics(self.model, self.data)
        mj.mj_camlight(self.model, self.data)
        self._gl.make_current()
        mj.mjv_updateScene(self.model, self.data, self._option, None, self._mjv_camera,
                           mj.mjtCatBit.mjCAT_ALL, self._scene)
        h, w = self.spec.height, self.spec.width
        # 1. colour pass
        rgb = np.empty((h, w, 3), dtype=np.uint8)
        mj.mjr_render(self._rect, self._scene, self._ctx)
        mj.mjr_readPixels(rgb, None, self._rect, self._ctx)
        # 2. segmentation pass: flat id colours, and its depth buffer
        flags = self._scene.flags
        flags[mj.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mj.mjtRndFlag.mjRND_IDCOLOR] = True
        seg_rgb = np.empty((h, w, 3), dtype=np.uint8)
        zbuf = np.empty((h, w), dtype=np.float32)
        try:
            mj.mjr_render(self._rect, self._scene, self._ctx)
            mj.mjr_readPixels(seg_rgb, zbuf, self._rect, self._ctx)
        finally:
            flags[mj.mjtRndFlag.mjRND_SEGMENT] = False
            flags[mj.mjtRndFlag.mjRND_IDCOLOR] = False
        return RenderedFrame(
            rgb=np.ascontiguousarray(np.flipud(rgb)),
            depth_m=np.ascontiguousarray(np.flipud(self._metric_depth(zbuf))),
            instance_ids=np.ascontiguousarray(np.flipud(self._instances(seg_rgb))),
        )

    def _metric_depth(self, zbuf: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """Reverse-Z depth buffer values in [0, 1] (0 = far) to metres along the optical axis."""
        zf, zn = np.float32(self.zfar_m), np.float32(self.znear_m)
        c = -(zf + zn) / (zf - zn)
        d = -(np.float32(2) * zf * zn) / (zf - zn)
        c = np.float32(-0.5) * c - np.float32(0.5)
        d = np.float32(-0.5) * d
        z = np.asarray(zbuf, dtype=np.float64)
        with np.errstate(divide="ignore"):
            depth = d / (z + c)
        depth[(z <= 0.0) | (depth >= 0.999 * self.zfar_m)] = 0.0  # nothing drawn there
        return depth.astype(np.float32)

    def _instances(self, seg_rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint16]:
        """Decode id colours to instance ids through the scene's segid -> geom table."""
        seg = seg_rgb.astype(np.int64)
        segid = seg[..., 0] + (seg[..., 1] << 8) + (seg[..., 2] << 16)  # segid + 1; 0 = background
        lut = np.zeros(int(segid.max()) + 2, dtype=np.uint16)
        geom_type = int(self._mj.mjtObj.mjOBJ_GEOM)
        for g in range(self._scene.ngeom):
            sg = self._scene.geoms[g]
            if sg.segid >= 0 and sg.objtype == geom_type and sg.segid + 1 < lut.size:
                lut[sg.segid + 1] = self._geom_instance[sg.objid]
        return lut[segid]

    # --- lifetime ---
    def close(self) -> None:
        if getattr(self, "_ctx", None) is not None:
            self._ctx.free()
            self._ctx = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> "SimRenderer":
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __del__(self) -> None:  # best effort; explicit close() is preferred
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
