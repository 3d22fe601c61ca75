"""`changing-slam convert SRC OUT.mcap`: a TUM folder or a bag -> a bare ROS 2 mcap.

    changing-slam convert SRC OUT.mcap [--config NAME|FILE] [--compress] [--jpeg-quality Q]
                                       [--depth-encoding 32FC1|16UC1]
    changing-slam convert --recover BROKEN.mcap OUT.mcap

SRC is anything `open_dataset` reads (TUM-layout folder, ROS 1 .bag, ROS 2 bag folder, .mcap).
The output holds colour, depth and CameraInfo per frame and the ground truth as PoseStamped
(see `io.mcap_writer`); it is written to a temporary file and renamed, so a failure leaves an
existing OUT untouched. `--recover` copies every message still readable from a truncated or damaged mcap
(`io.mcap_recover`), all topics as recorded, into a complete OUT.mcap that `run`, `graph` and `bag_player` read.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from changing_slam_ros.errors import BagError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("src", metavar="SRC", help="TUM-layout folder, ROS 1 .bag, ROS 2 bag folder or .mcap")
    parser.add_argument("out", metavar="OUT.mcap", help="output mcap file (ROS 2 profile, CDR)")
    parser.add_argument("--config", metavar="NAME|FILE",
                        help="camera/dataset config (tum_fr1, tum_fr2, tum_fr3, 7scenes, realsense_d435, sim or a YAML path)")  # fmt: skip
    parser.add_argument("--compress", action="store_true",
                        help="JPEG colour and 16-bit PNG depth (millimetres) as CompressedImage on .../compressed")  # fmt: skip
    parser.add_argument("--jpeg-quality", type=int, default=95, metavar="Q", help="JPEG quality with --compress (default 95)")
    parser.add_argument("--recover", action="store_true",
                        help="SRC is a truncated or damaged .mcap: copy every message still readable (all topics, as "
                             "recorded) into OUT.mcap; the other options do not apply")  # fmt: skip
    parser.add_argument("--depth-encoding", choices=("32FC1", "16UC1"), default="32FC1",
                        help="raw depth encoding: 32FC1 metres (lossless, default) or 16UC1 millimetres")  # fmt: skip


def main(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from changing_slam_ros.io.dataset import open_dataset
    from changing_slam_ros.io.mcap_writer import RgbdMcapWriter
    from changing_slam_ros.io.output_dir import check_output_file

    out = Path(args.out)
    if out.suffix != ".mcap":
        raise BagError(f"{out}: output must be an .mcap file")
    if Path(args.src).resolve() == out.resolve():
        raise BagError(f"{out}: output would overwrite the input")
    if not 1 <= args.jpeg_quality <= 100:
        raise BagError(f"--jpeg-quality {args.jpeg_quality}: expected 1..100")
    check_output_file(out, "OUT.mcap")
    if args.recover:
        return _recover(Path(args.src), out)
    src = open_dataset(args.src, args.config)
    print(f"reading {src.description}")
    gt = getattr(src, "groundtruth_stamped", None)
    with RgbdMcapWriter(out, compress=args.compress, jpeg_quality=args.jpeg_quality,
                        depth_encoding=args.depth_encoding) as writer:  # fmt: skip
        if gt is not None:
            writer.add_groundtruth(gt)
        with tqdm(total=len(src), unit="frame", desc="convert", file=sys.stderr, disable=None) as bar:
            for frame in src:
                writer.write_frame(frame)
                bar.update(1)
    size_mb = out.stat().st_size / 1e6
    mode = "compressed (JPEG + PNG)" if args.compress else f"raw (rgb8 + {args.depth_encoding})"
    print(f"wrote {out}: {writer.frames_written} frames, {writer.poses_written} ground-truth poses, "
          f"{mode}, {size_mb:.1f} MB")  # fmt: skip
    return 0


def _recover(src: Path, out: Path) -> int:
    from changing_slam_ros.io.mcap_recover import recover_mcap

    if src.is_dir():
        raise BagError(f"{src}: --recover takes an .mcap file (a ROS 2 bag folder's is inside it)")
    got = recover_mcap(src, out)
    ending = f"; the rest is unreadable (stopped {got.stopped})" if got.stopped else "; the file read to its end"
    print(f"wrote {out}: {got.messages} messages on {got.channels} topics recovered from {src}{ending}")
    return 0
