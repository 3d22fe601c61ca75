"""Where `changing-slam graph` resumes a killed bag player (its last progress line), and `--loop N` as the
player's passes."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from changing_slam_ros.commands.graph_arguments import add_arguments, check_bag_arguments
from changing_slam_ros.commands.graph_source import ResumePoint, inspect_bag, player_params, resume_point
from changing_slam_ros.errors import ConfigError

BAG = str(Path(__file__).resolve().parents[2] / "bags" / "sim_walking_changing.mcap")


def args_of(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args([BAG, "--out", "x", *argv])


def test_a_killed_player_resumes_at_its_last_logged_position_a_little_earlier() -> None:
    log = ("[INFO] bag_player: played 1/675 messages, 0.00/14.93 s of the bag (0 %)\n"
           "[INFO] bag_player: played 120/675 messages, 2.64/14.93 s of the bag (18 %)\n")  # fmt: skip
    assert resume_point(log, ResumePoint()) == ResumePoint(0, pytest.approx(2.63))
    looped = log + "[INFO] bag_player: pass 3: played 60/675 messages, 1.33/14.93 s of the bag (9 %)\n"
    assert resume_point(looped, ResumePoint()) == ResumePoint(2, pytest.approx(1.32))
    # killed before it logged a position: where that player itself had started
    assert resume_point("[INFO] bag_player: waiting for subscribers\n", ResumePoint(2, 1.32)) == ResumePoint(2, 1.32)


def test_loop_n_plays_n_passes_and_one_pass_is_no_loop() -> None:
    info = inspect_bag(BAG)
    assert "loop" not in player_params(args_of(), BAG, info, detection=True)
    params = player_params(args_of("--loop", "4"), BAG, info, detection=True)
    assert (params["loop"], params["loop_passes"], params["min_subscribers"]) == (True, 4, 2)
    with pytest.raises(ConfigError, match="--loop 0: expected the number of passes"):
        check_bag_arguments(args_of("--loop", "0"))
