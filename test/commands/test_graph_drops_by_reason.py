"""graph_summary.json `drops_by_reason`: the colour frames without a pose split by the counts tracking keeps, the
values adding up to `drops`, and the final line naming the reasons that have a count."""

from __future__ import annotations

from changing_slam_ros.commands.graph_outputs import DROP_REASONS, drops_by_reason, drops_text


def test_every_reason_is_present_and_the_values_add_up_to_the_drops() -> None:
    stats = {"colour_received": 95, "poses_published": 80, "unpaired_colour_dropped": 2, "frames_dropped_stale": 6,
             "frames_rejected": 1, "frames_lost": 3, "frames_skipped_waiting_for_map": 1,
             "colour_waiting_for_depth": 1}  # fmt: skip
    out = drops_by_reason(100, stats)
    assert list(out) == [*DROP_REASONS, "unaccounted"]
    assert out == {"not_received": 5, "unpaired": 2, "waiting_for_depth_at_end": 1, "stale": 6, "malformed": 1,
                   "no_camera_info": 0, "waiting_for_map": 1, "not_tracked": 3, "unaccounted": 1}  # fmt: skip
    assert sum(out.values()) == 100 - 80
    assert drops_text(20, out) == ("20 dropped: 5 not_received, 2 unpaired, 1 waiting_for_depth_at_end, 6 stale, "
                                   "1 malformed, 1 waiting_for_map, 3 not_tracked, 1 unaccounted")  # fmt: skip


def test_a_complete_run_has_every_reason_at_zero() -> None:
    out = drops_by_reason(9, {"colour_received": 9, "poses_published": 9})
    assert set(out.values()) == {0} and drops_text(0, out) == "0 dropped"
