"""The tracking node's parameters: name, default and description of each (`nodes/tracking_node.py`).

A table of its own so that the node's module holds what the node does; `declare_parameters` declares them with
their descriptions, and `ros2 param describe /tracking NAME` shows them.
"""

from __future__ import annotations

from typing import Any

TRACKING_PARAMETERS: tuple[tuple[str, Any, str], ...] = (
    ("config", "tum_fr1", "config name or YAML path (camera, dataset, features, tracking, mapping, loop, "
                          "dynamic, objects sections)"),
    ("sync_slop_s", 0.02, "largest colour/depth stamp difference paired (TUM associate.py: 0.02)"),
    ("intrinsics_from", "auto", "'camera_info', 'config', or 'auto' = the config's dataset.bag_intrinsics_from"),
    ("map_frame", "map", "REP-105 map frame"),
    ("odom_frame", "odom", "REP-105 odom frame"),
    ("camera_frame", "camera", "camera optical frame of the published pose"),
    ("base_frame", "", "REP-105 robot base frame (base_link): pose, odometry and TF are for it, with the "
                       "camera's mounting base_frame -> camera_frame from /tf_static (the robot's URDF); "
                       "empty = the camera frame is the base"),
    ("odom_source", "visual", "who publishes odom -> base_frame: 'visual' = this node, from the visual "
                              "estimate (map -> odom identity until a loop or relocalisation moves the map, "
                              "then the correction); 'tf' = the robot (wheel odometry, an EKF), this node "
                              "publishes only map -> odom = T_map_base * inv(T_odom_base at the image stamp)"),
    ("publish_tf", True, "publish map -> odom (and with odom_source visual odom -> base_frame) on /tf"),
    ("tf_timeout_s", 0.1, "odom_source tf: how long a frame waits for odom -> base_frame at its stamp "
                          "(odometry arriving after the image) before map -> odom is left as it was (warns)"),
    ("tf_cache_s", 10.0, "seconds of /tf kept for lookups at image stamps (tf2_ros's buffer when installed, "
                         "else the package's own)"),
    ("path_max_poses", 4000, "~/path holds at most this many poses: beyond, every other one is dropped (the "
                             "newest kept; the whole way stays drawn, evenly spaced, and memory and each path "
                             "message stay bounded on a long run); 0 = every pose"),
    ("pose_sigma_m", 0.01, "odometry covariance: position 1-sigma (m) at pose_sigma_inliers tracking inliers; "
                           "variance scales with pose_sigma_inliers / inliers"),
    ("pose_sigma_rad", 0.01, "odometry covariance: rotation 1-sigma (rad) at pose_sigma_inliers inliers"),
    ("pose_sigma_inliers", 100, "odometry covariance: inlier count at which the sigmas above hold"),
    ("ack_topic", "", "std_msgs/Header per processed frame and per accepted camera_info (bag_player lossless); "
                      "empty = off"),
    ("stats_period_s", 10.0, "seconds between log lines with frame and drop counts"),
    ("compressed", False, "subscribe CompressedImage on <colour>/compressed and <depth>/compressed"),
    ("slam", True, "false: pair, convert and acknowledge frames only (no poses; plumbing tests)"),
    ("in_process_backend", False, "run local mapping, objects and loop closing in this process instead of "
                                  "taking map updates from local_mapping / loop_closing"),
    ("wait_for_map_updates", False, "split backend: acknowledge a keyframe frame only after its map update "
                                    "and loop verdict arrived (lossless graph)"),
    ("map_update_timeout_s", 30.0, "wait_for_map_updates: give up waiting after this long (warns)"),
    ("map_update_resend_s", 5.0, "wait_for_map_updates: after a restarted node took its map snapshot, "
                                 "send the awaited keyframe again every this long until its map update comes "
                                 "(the restarted node may have missed it)"),
    ("keyframe_subscribers", 2, "wait_for_map_updates: frames wait until ~/keyframes has this many subscriptions "
                                "(local_mapping, loop_closing) and both send-back topics a publisher"),
    ("peers_wait_s", 60.0, "wait_for_map_updates: after this long without those matches, track anyway (warns)"),
    ("provisional_points", True, "split backend, real time: a new keyframe's depth keypoints become "
                                 "provisional points here at once, so tracking never waits for "
                                 "local_mapping's points (off with wait_for_map_updates: lossless)"),
    ("diagnostics_period_s", 5.0, "seconds between /diagnostics reports (0 = off)"),
    ("loop_closing", True, "in-process backend: loop closing on (unless the config's loop.enabled is false)"),
    ("dynamic", "config", "dynamic-scene filter: config (the dynamic section's enabled), on, off"),
    ("objects", "config", "object layer (MapObjects, beliefs): config, on, off"),
    ("detections_wait_s", 0.0, "longest wait for a frame's detections once detections are flowing; a frame "
                               "the detector announces it skips (/detection/skipped) or has passed does not wait "
                               "(0: track at once with what is in; real time with a capped detector: ~0.05; "
                               "lossless replay: long)"),
    ("detections_carry_max_age_s", 0.5, "a frame without its own detections uses the newest earlier ones "
                                        "up to this old, boxes grown with their age (0 = never)"),
    ("detections_carry_grow_widths_per_s", 0.5, "carried boxes: each grown per side by this many of its "
                                                "widths (heights) per second of age"),
    ("detections_carry_extrapolate", False, "carried boxes: each first moved on at the velocity of its "
                                           "edges between the two newest detection sets"),
    ("detections_carry_flow", True, "carried boxes: each first moved by the image motion of its foreground between "
                                     "the detections' image and the frame (Median Flow, core.dynamic.box_flow); "
                                     "a box whose motion is not measured is carried as without"),
    ("detections_carry_flow_grow_widths_per_s", 0.25, "detections_carry_flow: a moved box is grown by this "
                                                      "many widths (heights) per second of age instead"),
    ("detections_carry_flow_hull", False, "detections_carry_flow: a moved box is first joined with where it "
                                          "was (the person's path since its image)"),
    ("detections_carry_flow_max_stamp_gap_s", 0.07, "detections_carry_flow: without an image of the "
                                                    "detections' stamp (a frame tracking dropped), the "
                                                    "nearest kept one this close is used"),
    ("detections_carry_class_ids", [0], "carried boxes: only those of these COCO classes (person: a static object's "
                                        "box carried while the camera turns only hides static keypoints)"),
    ("detections_skip_late", False, "do not wait for a frame's detections while the last "
                                    "detections_late_window ones all came later than detections_wait_s "
                                    "(the wait could not succeed; it only added latency)"),
    ("detections_late_window", 5, "detections_skip_late: how many recent detection delays decide"),
    ("frames_held_for_camera_info", 60, "frame_policy all: frames before the first camera_info wait for "
                                        "it, at most this many (then, and in real time, they are skipped)"),
    ("frame_policy", "all", "'all': every paired frame in order (lossless); 'latest' (real time): when "
                            "frames pile up, the newest ready one is tracked and the older ones dropped"),
    ("detections_required", False, "wait for detections from the first frame (a detection node is started)"),
    ("debug_image", True, "publish ~/debug_image (keypoints by class, detection boxes)"),
    ("moving_objects_period_s", 0.5, "seconds between ~/moving_objects (+ markers) messages while the "
                                     "config's dynamic.movers tracks class-agnostic movers (0 = every frame)"),
    ("output_dir", "", "write trajectories, semantic map and stats here on shutdown; empty = none"),
    ("reliable_images", False, "reliable image subscriptions (keep last image_queue_depth) instead of "
                               "sensor-data best effort: large images across processes on Fast DDS arrive only this way"),
    ("image_queue_depth", 2, "reliable_images: frames queued while one is processed (more = fewer drops "
                             "after slow keyframes, more latency)"),
    ("mode", "mapping", "'mapping' (SLAM) or 'localization': the map (map_file) is only read: no keyframes, "
                        "points or objects added or moved, no loops; tracking relocalises when lost; "
                        "~/objects_seen lists the mapped objects present at their place. Also settable at run "
                        "time, and by ~/set_mode (std_srvs/SetBool, true = localization)"),
    ("map_file", "", "multi-session: start from this map file of `changing-slam run` (DIR/map.npz) and "
                     "relocalise in it first; split backend: local_mapping and loop_closing load it too"),
    ("initial_pose_radius_m", 0.5, "/initialpose (PoseWithCovarianceStamped of base_frame in map_frame, RViz / "
                                   "Nav2): relocalisation looks near it and accepts a pose within 3 sigma of its "
                                   "covariance, and at least this far (m)"),
    ("initial_pose_angle_deg", 30.0, "/initialpose: the accepted rotation from it, at least this (deg)"),
)  # fmt: skip
