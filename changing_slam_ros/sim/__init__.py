"""Scenario simulator for dynamic and changing scenes with full ground truth.

`changing-slam simulate SCENARIO --out DIR [--seed N] [--frames N] [--fps F] [--width W --height H]
[--mcap FILE] [--shadows]`, `--list` for the scenarios, `--contact-sheet PNG` for one frame of each.
Rendering is MuJoCo's, offscreen through OSMesa on the CPU (Debian `libosmesa6`, listed in
`tools/apt-packages.txt`; set `MUJOCO_GL=egl` on a GPU host). Modules, one concept each: `textures`,
`actors` (people and COCO-class objects, 0-based ids), `track` (ground-truth 6-DoF poses over time),
`motions`, `camera_path`, `room`, `scene` (MJCF), `renderer`, `scenarios` (the registry), `sequence` (the
render loop), `writer` (the output folder), `oracle` (boxes from instance masks), `bag` (mcap),
`contact_sheet`, `sensor_model` (`--sensor`), `random_dynamic` (with `random_room`, `random_movers`).

Conventions: world z up, origin at the floor centre; camera poses are the optical frame (x right, y down,
z forward) in the world, TUM format; depth is metres along the optical axis; intrinsics are exact
(`renderer.intrinsics_for`); files in `writer`. Same scenario, seed and options: byte-identical files.
"""
