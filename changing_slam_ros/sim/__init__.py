"""Scenario simulator for dynamic and changing scenes with full ground truth.

`changing-slam simulate SCENARIO --out DIR [--seed N] [--frames N] [--fps F] [--width W --height H]
[--mcap FILE] [--shadows]`, `--list` for the scenarios, `--contact-sheet PNG` for one frame of each.

Rendering is MuJoCo's, offscreen through OSMesa on the CPU (Debian `libosmesa6`, listed in
`tools/apt-packages.txt`; set `MUJOCO_GL=egl` on a GPU host). Modules, one concept each:

- `textures`: photos bundled with scikit-image (walls, floor, posters, people, objects) and their licences.
- `actors`: people and COCO-class objects built from textured boxes and cylinders; COCO 0-based ids.
- `track`: a ground-truth 6-DoF pose over time (interpolated, with jumps and absences).
- `motions`: walking, sitting, carrying by hand, out-of-view moves.
- `camera_path`: hand-held TUM-like motions and the PUC-USP-like robot loop.
- `room`: the furnished room; `scene`: MJCF generation; `renderer`: colour, depth and instance ids.
- `scenarios`: the registry; `sequence`: the render loop; `writer`: the output folder;
  `oracle`: boxes from instance masks; `bag`: the folder as an mcap; `contact_sheet`.
- `sensor_model`: Kinect- / RealSense-like depth noise, holes, blur and exposure (`--sensor`).
- `random_dynamic` (with `random_room`, `random_movers`): one randomised dynamic scene per seed.

Conventions: world z up, origin at the floor centre of the room; camera poses are the optical frame
(x right, y down, z forward) in the world, TUM format; depth is metres along the optical axis (PNG x
5000); intrinsics are exact, fx = fy = (H / 2) / tan(fovy / 2), cx = (W - 1) / 2, cy = (H - 1) / 2
(525 / 319.5 / 239.5 at 640x480, the ROS default for TUM); instance id i + 1 is `objects.json`'s
object i, 0 the room. The same scenario, seed and options give byte-identical output files.
"""
