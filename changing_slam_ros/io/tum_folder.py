"""Reader of TUM-layout folders (TUM RGB-D, 7-Scenes as shipped here, simulator exports).

Layout: `rgb.txt` and `depth.txt` (`timestamp filename` per line, `#` comments), optional
`associations.txt` (`t_rgb rgb/x.png t_depth depth/y.png`, used as given when present), optional
`groundtruth.txt` (`timestamp tx ty tz qx qy qz qw`, camera-to-world) and optional `camera_info.yaml`
(ROS camera-calibration YAML, preferred over the config's camera). 7-Scenes' `camera-intrinsics.txt` is read to
check the config's camera against it; `camera_mismatch` says when either disagrees with the config.

Colour and depth are paired exactly as TUM's `associate.py` does: every pair with
|t_rgb - (t_depth + offset)| < max_difference is a candidate, candidates are taken in order of
increasing difference when neither stamp is used yet, and the result is sorted by colour stamp.
Stamps are integer nanoseconds parsed from the decimal text, so no float rounding enters pairing.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.errors import DatasetError, SlamError, read_utf8
from changing_slam_ros.io.camera_check import CameraMismatch, check_cameras, read_intrinsics_txt
from changing_slam_ros.io.camera_info import read_camera_info_yaml
from changing_slam_ros.io.dataset_config import CameraConfig, DatasetConfig
from changing_slam_ros.io.groundtruth import GroundTruth, GroundTruthAccess


def parse_stamp_ns(text: str) -> int:
    """Decimal seconds text -> integer nanoseconds, exactly ('1305031102.175304' -> 1305031102175304000).

    Digits beyond nanoseconds are rounded half up. ValueError on anything but [-]digits[.digits].
    """
    s = text.strip()
    sign = 1
    if s.startswith("-"):
        sign, s = -1, s[1:]
    whole, _, frac = s.partition(".")
    if not (whole or frac) or not (whole.isdigit() or whole == "") or not (frac.isdigit() or frac == ""):
        raise ValueError(f"not a decimal timestamp: {text!r}")
    ns = int(whole or "0") * 1_000_000_000 + int((frac + "000000000")[:9])
    if len(frac) > 9 and frac[9] >= "5":
        ns += 1
    return sign * ns


def format_stamp(stamp_ns: int) -> str:
    """Integer nanoseconds -> decimal seconds text with 6 decimals when exact to microseconds (TUM style)."""
    sec, ns = divmod(stamp_ns, 1_000_000_000)
    return f"{sec}.{ns // 1000:06d}" if ns % 1000 == 0 else f"{sec}.{ns:09d}"


@dataclass(frozen=True)
class StampedFile:
    stamp_ns: int
    relpath: str


def read_file_list(path: Path) -> list[StampedFile]:
    """`timestamp filename` lines of rgb.txt / depth.txt (extra columns ignored, as associate.py does)."""
    out: list[StampedFile] = []
    for lineno, parts in _data_lines(path):
        if len(parts) < 2:
            raise DatasetError(f"{path}:{lineno}: expected 'timestamp filename', got {len(parts)} column(s)")
        out.append(StampedFile(_stamp(parts[0], path, lineno), parts[1]))
    return out


def _data_lines(path: Path) -> Iterator[tuple[int, list[str]]]:
    text = read_utf8(path, DatasetError)
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            yield lineno, s.replace(",", " ").replace("\t", " ").split()


def _stamp(text: str, path: Path, lineno: int) -> int:
    try:
        return parse_stamp_ns(text)
    except ValueError:
        raise DatasetError(f"{path}:{lineno}: timestamp {text!r} is not a decimal number of seconds") from None


def associate(
    first_ns: list[int], second_ns: list[int], offset_ns: int = 0, max_difference_ns: int = 20_000_000
) -> list[tuple[int, int]]:
    """TUM associate.py on integer stamps: (first, second) index pairs sorted by first stamp.

    Candidates |first - (second + offset)| < max_difference, taken greedily by increasing difference
    (ties broken by first stamp then second stamp, as Python's tuple sort does in associate.py).
    """
    a = np.asarray(first_ns, dtype=np.int64)
    b_shift = np.asarray(second_ns, dtype=np.int64) + np.int64(offset_ns)
    order_b = np.argsort(b_shift, kind="stable")
    b_sorted = b_shift[order_b]
    candidates: list[tuple[int, int, int, int, int]] = []
    for i, t in enumerate(a.tolist()):
        lo = int(np.searchsorted(b_sorted, t - max_difference_ns, side="right"))
        hi = int(np.searchsorted(b_sorted, t + max_difference_ns, side="left"))
        for k in range(lo, hi):
            j = int(order_b[k])
            diff = abs(t - int(b_shift[j]))
            if diff < max_difference_ns:
                candidates.append((diff, t, int(second_ns[j]), i, j))
    candidates.sort()
    used_a: set[int] = set()
    used_b: set[int] = set()
    used_stamp_a: set[int] = set()
    used_stamp_b: set[int] = set()
    pairs: list[tuple[int, int]] = []
    for _diff, ta, tb, i, j in candidates:
        # associate.py keys dictionaries by stamp: a repeated stamp can match only once
        if i in used_a or j in used_b or ta in used_stamp_a or tb in used_stamp_b:
            continue
        used_a.add(i)
        used_b.add(j)
        used_stamp_a.add(ta)
        used_stamp_b.add(tb)
        pairs.append((i, j))
    pairs.sort(key=lambda p: (first_ns[p[0]], second_ns[p[1]]))
    return pairs


def read_groundtruth(path: Path) -> GroundTruth:
    """groundtruth.txt -> GroundTruth sorted by stamp, quaternions normalised; DatasetError on bad lines."""
    stamps: list[int] = []
    rows: list[list[float]] = []
    for lineno, parts in _data_lines(path):
        if len(parts) != 8:
            raise DatasetError(f"{path}:{lineno}: expected 8 columns 'timestamp tx ty tz qx qy qz qw', got {len(parts)}")
        stamps.append(_stamp(parts[0], path, lineno))
        try:
            rows.append([float(v) for v in parts[1:]])
        except ValueError:
            raise DatasetError(f"{path}:{lineno}: pose values must be numbers") from None
    if not rows:
        raise DatasetError(f"{path}: no poses (expected lines 'timestamp tx ty tz qx qy qz qw')")
    a = np.asarray(rows, dtype=np.float64)
    norms = np.linalg.norm(a[:, 3:7], axis=1)
    if not np.isfinite(a).all() or (norms < 1e-9).any():
        bad = int(np.argmax(~np.isfinite(a).all(axis=1) | (norms < 1e-9)))
        raise DatasetError(f"{path}: pose {bad + 1} has a non-finite value or a zero quaternion")
    order = np.argsort(np.asarray(stamps, dtype=np.int64), kind="stable")
    return GroundTruth(
        np.asarray(stamps, dtype=np.int64)[order], a[order, :3], (a[:, 3:7] / norms[:, None])[order]
    )


@dataclass(frozen=True)
class FramePair:
    rgb_stamp_ns: int
    rgb_path: Path
    depth_stamp_ns: int
    depth_path: Path


class TumFolder(GroundTruthAccess):
    """RgbdSource over a TUM-layout folder; images are loaded lazily, one frame at a time."""

    def __init__(self, root: str | Path, config: DatasetConfig, camera: CameraConfig | None = None,
                 config_name: str = "the config") -> None:  # fmt: skip
        self.root = Path(root)
        self.config = config
        self.config_name = config_name
        self.camera_mismatch: CameraMismatch | None = None
        if not self.root.is_dir():
            raise DatasetError(f"{self.root}: not a folder (expected a TUM-layout dataset)")
        self.pairs = self._read_pairs()
        gt_path = self.root / "groundtruth.txt"
        self._gt = read_groundtruth(gt_path) if gt_path.is_file() else None
        self.camera = self._read_camera(camera)
        self.description = (
            f"TUM folder {self.root} ({len(self.pairs)} frames, depth scale {config.depth_scale:g}/m, "
            f"{'ground truth' if self._gt else 'no ground truth'})"
        )

    # -- RgbdSource ----------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[RgbdFrame]:
        for i in range(len(self.pairs)):
            yield self.frame(i)

    def frame(self, index: int) -> RgbdFrame:
        pair = self.pairs[index]
        rgb = self._read_rgb(pair.rgb_path)
        depth = self._read_depth(pair.depth_path)
        if rgb.shape[:2] != depth.shape:
            raise DatasetError(
                f"{pair.rgb_path} is {rgb.shape[1]}x{rgb.shape[0]} but {pair.depth_path} is "
                f"{depth.shape[1]}x{depth.shape[0]}; colour and depth must have the same size"
            )
        if (rgb.shape[1], rgb.shape[0]) != (self.camera.width, self.camera.height):
            raise DatasetError(
                f"{pair.rgb_path} is {rgb.shape[1]}x{rgb.shape[0]} but the camera is "
                f"{self.camera.width}x{self.camera.height} ({self._camera_source})"
            )
        T = None
        if self._gt is not None:
            T = self._gt.nearest_pose(pair.rgb_stamp_ns, round(self.config.gt_max_time_diff_s * 1e9))
        return RgbdFrame(pair.rgb_stamp_ns, rgb, depth, self.camera, T, index)

    # -- internals -----------------------------------------------------------------------------
    def _read_pairs(self) -> list[FramePair]:
        assoc = self.root / "associations.txt"
        if assoc.is_file():
            pairs = []
            for lineno, parts in _data_lines(assoc):
                if len(parts) < 4:
                    raise DatasetError(
                        f"{assoc}:{lineno}: expected 't_rgb rgb/x.png t_depth depth/y.png', got {len(parts)} column(s)"
                    )
                pairs.append(
                    FramePair(
                        _stamp(parts[0], assoc, lineno), self.root / parts[1],
                        _stamp(parts[2], assoc, lineno), self.root / parts[3],
                    )  # fmt: skip
                )
            source = assoc
        else:
            rgb_txt, depth_txt = self.root / "rgb.txt", self.root / "depth.txt"
            for needed in (rgb_txt, depth_txt):
                if not needed.is_file():
                    raise DatasetError(
                        f"{self.root}: missing {needed.name} (a TUM-layout folder needs rgb.txt and "
                        "depth.txt, or associations.txt)"
                    )
            rgb, depth = read_file_list(rgb_txt), read_file_list(depth_txt)
            matches = associate(
                [f.stamp_ns for f in rgb], [f.stamp_ns for f in depth],
                round(self.config.offset_s * 1e9), round(self.config.max_time_diff_s * 1e9),
            )  # fmt: skip
            pairs = [
                FramePair(rgb[i].stamp_ns, self.root / rgb[i].relpath, depth[j].stamp_ns, self.root / depth[j].relpath)
                for i, j in matches
            ]
            source = rgb_txt
            if not pairs and rgb and depth:
                raise DatasetError(
                    f"{self.root}: no colour frame has a depth frame within {self.config.max_time_diff_s} s "
                    f"(offset {self.config.offset_s} s); check dataset.max_time_diff_s / offset_s"
                )
        if not pairs:
            raise DatasetError(f"{source}: lists no frames")
        missing = [p for pair in pairs for p in (pair.rgb_path, pair.depth_path) if not p.is_file()]
        if missing:
            raise DatasetError(
                f"{missing[0]}: image file missing ({len(missing)} of the {2 * len(pairs)} files "
                f"listed in {source.name} are missing)"
            )
        pairs.sort(key=lambda p: p.rgb_stamp_ns)
        return pairs

    def _read_camera(self, camera: CameraConfig | None) -> CameraIntrinsics:
        yaml_path = self.root / "camera_info.yaml"
        configured = _usable(camera)
        if yaml_path.is_file():
            self._camera_source = str(yaml_path)
            shipped = read_camera_info_yaml(yaml_path)
            self.camera_mismatch = check_cameras(str(yaml_path), shipped, self.config_name, configured, yaml_path.name)
            return shipped
        txt_path = self.root / "camera-intrinsics.txt"
        if txt_path.is_file() and configured is not None:
            shipped = read_intrinsics_txt(txt_path, configured.width, configured.height)
            self.camera_mismatch = check_cameras(str(txt_path), shipped, self.config_name, configured,
                                                 f"the camera of {self.config_name}")  # fmt: skip
        if camera is None:
            raise DatasetError(
                f"{self.root}: no camera_info.yaml beside the data and no camera: section in the config; "
                "pass --config (e.g. tum_fr1, 7scenes)"
            )
        self._camera_source = "config camera section"
        try:
            return camera.intrinsics()
        except SlamError as err:
            raise DatasetError(f"{self.root}: {err}") from err

    @staticmethod
    def _read_rgb(path: Path) -> npt.NDArray[np.uint8]:
        img = _imread(path, cv2.IMREAD_COLOR, "colour image")
        return np.ascontiguousarray(img[:, :, ::-1])

    def _read_depth(self, path: Path) -> npt.NDArray[np.float32]:
        raw = _imread(path, cv2.IMREAD_UNCHANGED, "depth image")
        if raw.ndim != 2 or raw.dtype != np.uint16:
            shape = "x".join(str(s) for s in raw.shape)
            raise DatasetError(f"{path}: depth image is {raw.dtype} {shape}, expected a 16-bit single-channel PNG")
        depth = raw.astype(np.float32) / np.float32(self.config.depth_scale)
        return depth


def _usable(camera: CameraConfig | None) -> CameraIntrinsics | None:
    """The config's camera as intrinsics, None when absent or incomplete (nothing to compare then)."""
    try:
        return None if camera is None else camera.intrinsics()
    except SlamError:
        return None


def _imread(path: Path, flags: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise DatasetError(f"{path}: {what} file missing")
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as err:
        raise DatasetError(f"{path}: cannot read {what} ({err.strerror})") from err
    if _is_truncated(data.tobytes()[:8], data[-64:].tobytes()):
        raise DatasetError(f"{path}: {what} is truncated (no end marker)")
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise DatasetError(f"{path}: {what} cannot be decoded (truncated or not an image)")
    return img


_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _is_truncated(head: bytes, tail: bytes) -> bool:
    """PNG without its IEND chunk or JPEG without its EOI marker (checked before decoding)."""
    if head.startswith(_PNG_MAGIC):
        return not tail.endswith(b"IEND\xaeB`\x82")
    if head.startswith(b"\xff\xd8"):
        return b"\xff\xd9" not in tail
    return False
