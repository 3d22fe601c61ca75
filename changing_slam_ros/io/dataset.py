"""One entry point for RGB-D input: `open_dataset(path, config)` picks the reader by what `path` is.

- a folder with `metadata.yaml`: ROS 2 bag (sqlite3 or mcap storage) -> `BagRgbdReader`
- a folder with `rgb.txt` or `associations.txt`: TUM layout (TUM, 7-Scenes, exports) -> `TumFolder`
- a `.bag` / `.mcap` / `.db3` file: ROS 1 bag, bare mcap, single sqlite3 file -> `BagRgbdReader`

Every reader satisfies `RgbdSource`: `camera`, `len()`, iteration of `RgbdFrame` in time order,
`groundtruth` (a `Trajectory` or None), a one-line `description` and `camera_mismatch` (the intrinsics the
data ships disagree with the config's camera; `io.camera_check`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from changing_slam_ros.core.geometry.camera import CameraIntrinsics
from changing_slam_ros.core.features.rgbd_frame import RgbdFrame
from changing_slam_ros.core.geometry.trajectory import Trajectory
from changing_slam_ros.errors import DatasetError
from changing_slam_ros.io.camera_check import CameraMismatch
from changing_slam_ros.io.groundtruth import GroundTruth
from changing_slam_ros.io.dataset_config import (
    CameraConfig,
    DatasetConfig,
    DatasetSettings,
    load_dataset_settings,
)

__all__ = [
    "CameraConfig",
    "DatasetConfig",
    "DatasetSettings",
    "RgbdSource",
    "load_dataset_settings",
    "open_dataset",
]

if TYPE_CHECKING:
    from changing_slam_ros.io.bag_reader import SkippedMessage

BAG_SUFFIXES = (".bag", ".mcap", ".db3")


@runtime_checkable
class RgbdSource(Protocol):
    """A sequence of registered RGB-D frames with intrinsics and optional ground truth."""

    camera: CameraIntrinsics
    description: str
    camera_mismatch: CameraMismatch | None

    @property
    def groundtruth(self) -> Trajectory | None: ...

    @property
    def groundtruth_stamped(self) -> GroundTruth | None:
        """The same ground truth with exact integer-nanosecond stamps."""
        ...

    def __len__(self) -> int: ...

    def __iter__(self) -> Iterator[RgbdFrame]: ...


def open_dataset(
    path: str | Path, config: DatasetSettings | str | Path | None = None, strict: bool = True,
    on_skip: Callable[[SkippedMessage], None] | None = None,
) -> RgbdSource:
    """Open a TUM-layout folder or a bag; `config` is loaded settings, a config file/name, or None.

    A bag's malformed messages end the iteration when `strict`, else their frames are skipped and each is passed
    to `on_skip` (`BagRgbdReader`); a TUM folder's unreadable image always ends it."""
    settings = config if isinstance(config, DatasetSettings) else load_dataset_settings(config)
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: no such file or folder (expected a TUM-layout folder or a bag)")
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            return _bag(p, settings, strict, on_skip)
        if (p / "rgb.txt").is_file() or (p / "associations.txt").is_file():
            from changing_slam_ros.io.tum_folder import TumFolder

            return TumFolder(p, settings.dataset, settings.camera, settings.source)
        raise DatasetError(
            f"{p}: neither a ROS 2 bag folder (metadata.yaml) nor a TUM-layout folder (rgb.txt / associations.txt)"
        )
    if p.suffix in BAG_SUFFIXES:
        return _bag(p, settings, strict, on_skip)
    raise DatasetError(f"{p}: unsupported input; expected a folder, a .bag, a .mcap or a .db3 file")


def _bag(p: Path, settings: DatasetSettings, strict: bool,
         on_skip: Callable[[SkippedMessage], None] | None) -> RgbdSource:  # fmt: skip
    from changing_slam_ros.io.bag_reader import BagRgbdReader

    return BagRgbdReader(p, settings.dataset, settings.camera, settings.source, strict, on_skip)
