"""`convert --recover`: a truncated mcap (written here) gives back every message before the cut, byte for byte."""

from __future__ import annotations

from pathlib import Path

import pytest

from changing_slam_ros.cli import main as cli_main
from changing_slam_ros.errors import BagError
from changing_slam_ros.io.bag_messages import BagMessages
from changing_slam_ros.io.dataset import open_dataset
from changing_slam_ros.io.mcap_recover import recover_mcap

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "tum_fr1_xyz_first10.mcap"


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with BagMessages(path) as bag:
        return [(m.topic, m.log_stamp_ns, m.cdr) for m in bag.messages()]


def test_a_truncated_mcap_gives_back_every_message_before_the_cut(tmp_path: Path, capsys) -> None:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(BAG.read_bytes()[: BAG.stat().st_size * 2 // 3])
    assert cli_main(["run", str(cut), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "'changing-slam convert --recover FILE.mcap OUT.mcap'" in capsys.readouterr().err
    out = tmp_path / "recovered.mcap"
    assert cli_main(["convert", "--recover", str(cut), str(out)]) == 0
    said = capsys.readouterr().out
    original, recovered = _messages(BAG), _messages(out)
    assert 0 < len(recovered) < len(original)
    assert recovered == original[: len(recovered)]  # the same messages in order, payloads byte for byte
    assert f"wrote {out}: {len(recovered)} messages on 4 topics recovered" in said and "EndOfFile" in said
    frames = list(open_dataset(out, "tum_fr1"))
    assert 0 < len(frames) < 10
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in list(open_dataset(BAG, "tum_fr1"))[: len(frames)]]


def test_a_complete_mcap_is_copied_whole_and_what_is_no_mcap_is_named(tmp_path: Path) -> None:
    got = recover_mcap(BAG, tmp_path / "copy.mcap")
    assert got.stopped is None and got.messages == len(_messages(BAG)) and got.channels == 4
    assert _messages(tmp_path / "copy.mcap") == _messages(BAG)
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n")
    with pytest.raises(BagError, match=r"notes.mcap: not an mcap file"):
        recover_mcap(text, tmp_path / "x.mcap")
    header_only = tmp_path / "header.mcap"
    header_only.write_bytes(BAG.read_bytes()[:40])
    with pytest.raises(BagError, match=r"header.mcap: no message could be read"):
        recover_mcap(header_only, tmp_path / "y.mcap")
    assert not (tmp_path / "y.mcap").exists()
