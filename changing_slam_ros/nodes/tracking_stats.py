"""The tracking node's counts and latencies: tracking_stats.json, /diagnostics and the periodic log line.

Mixed into `TrackingNode`, whose `__init__` sets the counters these methods read.
"""

from __future__ import annotations

from typing import Any

# A stamp further than this behind its stream's newest is not a resumed player's overlap but a bag played again or
# a clock reset: warned about once per jump (frames are dropped either way).
BACKWARD_JUMP_S = 1.0


class TrackingStats:
    """Methods of `TrackingNode` (see the module docstring)."""

    def stats(self, per_frame: bool = True) -> dict[str, Any]:
        """Counts and latencies for tracking_stats.json and the log. The per-frame figures are `RecentValues`: their
        medians and p90s are of the last `RECENT_CAPACITY` values (32768; every frame of a shorter run), and so is the
        `latency_ms` list (left out with `per_frame` False); `carry_cpu_ms_mean` is of every frame."""
        s = self.pairer.stats
        prov = self.split.provisional if self.split is not None else None
        out = {
            "colour_received": self.colour_in, "pairs": s.pairs, "unpaired_colour_dropped": s.dropped_first,
            "unpaired_depth_dropped": s.dropped_second, "frames_converted": self.frames_in,
            "frames_rejected": self.frames_rejected, "poses_published": self.published_poses,
            "frames_skipped_no_camera_info": self.frames_no_camera, "frames_lost": self.frames_lost,
            "colour_waiting_for_depth": self.pairer.waiting_first,
            "colour_duplicates_dropped": self.duplicates["colour"], "depth_duplicates_dropped": self.duplicates["depth"],
            "frames_without_detections": self.frames_without_detections,
            "detections_skipped_received": self.detections_skipped_in,
            "frames_with_carried_detections": self.frames_with_carried_detections,
            "carry_cpu_ms_mean": self.carry_cpu_ms.mean(),
            "deferred_refinement": None if self.backend is None or self.backend.system.refinement is None
            else dict(vars(self.backend.system.refinement.stats)),  # frames bracketed / optimised again / refined
            "frames_dropped_stale": self.frames_dropped_stale, "frame_policy": self.params["frame_policy"],
            "frames_not_waited_for_late_detections": self.frames_not_waited,
            "latency_ms_median": self.latency_ms.median(), "latency_ms_p90": self.latency_ms.percentile(90),
            "process_ms_median": self.process_ms.median(),
            "process_cpu_ms_median": self.process_cpu_ms.median(),
            "process_cpu_ms_p90": self.process_cpu_ms.percentile(90),
            "detection_delay_ms_median": self.detection_delay_ms.median(),
            "detections_received": self.detections_in,
            "backend": "in_process" if self.split is None else "split",
            "map_updates_applied": self.updates_applied, "map_updates_rejected": self.updates_rejected,
            "keyframes_without_map_update": len(self._kf_sent_s) if self.split is not None else None,
            "map_update_waits_timed_out": self.map_update_waits_timed_out,
            "keyframes_resent": self.keyframes_resent,
            "map_update_latency_ms_median": self.update_latency_ms.median(),
            "loops_closed_split": self.split.n_loops if self.split is not None else None,
            "maps_merged_split": self.split.n_merges if self.split is not None else None,
            "keyframes_moved_by_merges": self.split.n_moved_keyframes if self.split is not None else None,
            "provisional_points_moved_by_merges": self.split.n_moved_provisional if self.split is not None else None,
            "frames_skipped_waiting_for_map": self.split.n_skipped if self.split is not None else None,
            "provisional_points_created": prov.n_created if prov is not None else None,
            "provisional_points_replaced": prov.n_replaced if prov is not None else None,
            "provisional_points_dropped": prov.n_dropped if prov is not None else None,
            "moving_objects_messages": self.movers_out.published if self.movers_out is not None else 0,
            "map_loads": self.loads,
            "load_relocalised_after_s": self._relocalised_after_load_s(),
            "dropped_before_load": self.epochs.dropped,
        }  # fmt: skip
        if per_frame:
            out["latency_ms"] = [round(v, 2) for v in self.latency_ms]
        return out

    def _relocalised_after_load_s(self) -> float | None:
        """After a LoadMap: seconds (frame stamps) from the first frame tracked after it to the frame that
        relocalised in the loaded map; None before a load or while not relocalised."""
        if not self.epochs.epoch_ns or self.split is None:
            return None
        system = self.split.system
        i = system.tracker.loaded_map_relocalised_index
        if i < 0 or not system.records:
            return None
        return (system.records[i].stamp_ns - system.records[0].stamp_ns) * 1e-9

    def diagnostic_values(self) -> dict[str, Any]:
        """Counts and latencies for /diagnostics (no per-frame lists)."""
        s = self.stats(per_frame=False)
        keep = ("colour_received", "frames_converted", "poses_published", "unpaired_colour_dropped",
                "unpaired_depth_dropped", "frames_rejected", "frames_without_detections", "frames_dropped_stale",
                "latency_ms_median",
                "latency_ms_p90", "process_ms_median", "process_cpu_ms_median", "detections_received", "map_updates_applied", "map_update_latency_ms_median")  # fmt: skip
        out = {k: s[k] for k in keep}
        out["dropped"] = self.colour_in - self.published_poses
        out.update(self.frames_out.diagnostic_values())  # tracking state, map -> odom jumps, odometry time-outs
        out.update(self.mode_control.diagnostic_values())  # mapping / localization, objects present
        return out

    def _duplicate(self, stream: str, stamp_ns: int) -> bool:
        """Whether a colour or depth message is not newer than the newest of its stream (then counted, and the
        caller drops it): a bag player restarted mid-run resumes a little before where it stopped, and the pairer
        and the map take each stamp once, in order."""
        newest = self._newest_ns[stream]
        if stamp_ns <= newest:
            self.duplicates[stream] += 1
            back_s = (newest - stamp_ns) * 1e-9
            if back_s > BACKWARD_JUMP_S and not self._warned_backward.get(stream):
                # not a resumed player's overlap: a bag started again, or a clock reset; the map keeps its order
                self._warned_backward[stream] = True
                self.get_logger().warning(
                    f"tracking: {stream} stamps went back {back_s:.1f} s (a bag played again into a running graph?); "
                    "every frame not newer than the newest tracked one is dropped; restart tracking for a new "
                    "sequence, or replay with the player's loop option (it moves the stamps on)")  # fmt: skip
            else:
                self.get_logger().info(f"tracking: {stream} at {stamp_ns * 1e-9:.6f} s received again; dropped",
                                       throttle_duration_sec=5.0)  # fmt: skip
            return True
        self._warned_backward[stream] = False
        self._newest_ns[stream] = stamp_ns
        return False

    def _warn_if_unpaired(self) -> None:
        s = self.pairer.stats
        if s.dropped_first > 10 and s.pairs == 0:
            self._warn_once(
                "unpaired",
                f"tracking: colour and depth do not pair within {self.params['sync_slop_s']} s "
                f"({s.dropped_first} colour frames dropped); check the stamps or raise sync_slop_s",
            )

    def _log_stats(self) -> None:
        """The counts line (every stats_period_s while they change; `changing-slam graph` reads its progress
        from it)."""
        s = self.pairer.stats
        if s.pairs or s.dropped_first or s.dropped_second:
            counts = (f"tracking: {self.colour_in} colour received, {self.frames_in} frames, {s.pairs} colour/depth "
                      f"pairs, unpaired dropped: {s.dropped_first} colour, {s.dropped_second} depth, "
                      f"{self.published_poses} poses")  # fmt: skip
            if counts == getattr(self, "_last_counts_line", ""):
                return
            self._last_counts_line = counts
            lat = f", latency median {self.latency_ms.median():.0f} ms" if self.latency_ms else ""
            self.get_logger().info(counts + lat)


def _warn_if(values: Any) -> str | None:
    """/diagnostics level WARN: tracking lost, or the latency over its target."""
    if values.get("tracking_state") == "LOST":
        return "tracking LOST: no pose until relocalisation"
    lat = values.get("latency_ms_median")
    if lat is not None and lat > 60.0:
        return f"image-to-pose latency median {lat:.0f} ms > 60 ms"
    return None
