"""`changing-slam run --start-frame N`: a recording's later frames run as a session of their own."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest
from helpers import FR1_XYZ_10, require

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.commands.run import frames_from
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.tum_trajectory import read_tum_trajectory


@dataclass
class _Frame:
    index: int


class _ByIndex:
    """A source that reads frames by index and records which ones were read."""

    def __init__(self, n: int) -> None:
        self.n, self.read = n, []

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[_Frame]:
        return (self.frame(i) for i in range(self.n))

    def frame(self, i: int) -> _Frame:
        self.read.append(i)
        return _Frame(i)


def test_frames_from_reads_by_index_from_the_start_and_numbers_from_zero() -> None:
    source = _ByIndex(6)
    assert [f.index for f in frames_from(source, 4)] == [0, 1]
    assert source.read == [4, 5]  # the first four never read
    assert [f.index for f in frames_from(_ByIndex(3), 0)] == [0, 1, 2]


def test_frames_from_cuts_an_iterated_source_by_the_frames_own_index() -> None:
    """A bag whose frame 2 was skipped as malformed: the cut at 3 still starts at its frame 3, and the gap before
    frame 5 (frame 4 skipped) is kept."""
    bag = [_Frame(i) for i in (0, 1, 3, 5, 6)]
    assert [f.index for f in frames_from(bag, 3)] == [0, 2, 3]


def test_run_from_a_start_frame_tracks_only_the_later_frames(tmp_path) -> None:
    data = require(FR1_XYZ_10)
    out = tmp_path / "late"
    assert cli_main(["run", str(data), "--out", str(out), "--config", "tum_fr1", "--quiet", "--no-plot", "--no-loop",
                     "--start-frame", "6"]) == 0  # fmt: skip
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == metrics["frames_tracked"] == 3  # the folder's 9 associated frames, less 6
    stamps_ns = [p.rgb_stamp_ns for p in open_dataset(data, "tum_fr1").pairs[6:]]  # type: ignore[attr-defined]
    assert np.allclose(read_tum_trajectory(out / "trajectory.txt").stamps_s, np.array(stamps_ns) * 1e-9)


@pytest.mark.parametrize("start,message", [("-1", "expected a frame count >= 0"), ("9", "has 9 frames")])
def test_a_start_frame_outside_the_source_is_refused_in_one_line(tmp_path, capsys, start, message) -> None:
    rc = cli_main(["run", str(require(FR1_XYZ_10)), "--out", str(tmp_path / "o"), "--config", "tum_fr1", "--quiet",
                   "--start-frame", start])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and f"--start-frame {start}: " in err[0] and message in err[0], err
