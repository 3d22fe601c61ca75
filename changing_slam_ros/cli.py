"""`changing-slam` command-line tool: parses, dispatches, prints. The work lives in the libraries.

Each subcommand is a module in `changing_slam_ros.commands` exposing
`add_arguments(parser)` and `main(args) -> int`; modules are imported lazily so that
`changing-slam eval` does not pay for gtsam or onnxruntime.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from changing_slam_ros.errors import SlamError

# name -> (module under changing_slam_ros.commands, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "run": ("run", "run the SLAM pipeline offline over a dataset or bag"),
    "eval": ("eval", "evaluate trajectories (ATE / RPE) against ground truth"),
    "convert": ("convert", "convert a TUM folder or ROS 1 bag to a ROS 2 mcap"),
    "simulate": ("simulate", "render a dynamic / changing scenario with ground truth"),
    "bench": ("bench", "benchmark a scenario family over seeds: ATE, lost frames, CPU, moving keypoints"),
    "graph": ("graph", "run the ROS 2 node graph over a bag without ros2 launch"),
    "changes": ("changes", "what changed between two object maps: moved, removed, added, replaced"),
    "points": ("points", "a saved map's points as a PLY point cloud (CloudCompare, Open3D)"),
}


class _VersionAction(argparse.Action):
    """`--version`: the git commit is looked up only when asked for."""

    def __init__(self, option_strings: Sequence[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> None:  # fmt: skip
        from changing_slam_ros.provenance import version_line

        print(version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="changing-slam",
        description="Visual SLAM for dynamic and changing environments (Changing-SLAM + Dai et al.).",
    )
    parser.add_argument("--version", action=_VersionAction, help="print the package version (and git commit "
                        "in a checkout) and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        # Arguments are added lazily only for the chosen command (see main()).
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # First pass: find the subcommand, then let its module add its own arguments.
    if argv and argv[0] in SUBCOMMANDS:
        module = importlib.import_module(f"changing_slam_ros.commands.{SUBCOMMANDS[argv[0]][0]}")
        sub_parser = argparse.ArgumentParser(
            prog=f"changing-slam {argv[0]}", description=SUBCOMMANDS[argv[0]][1]
        )
        module.add_arguments(sub_parser)
        args = sub_parser.parse_args(argv[1:])
        try:
            return int(module.main(args))
        except SlamError as err:
            print(f"changing-slam {argv[0]}: error: {err}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print(f"changing-slam {argv[0]}: interrupted", file=sys.stderr)
            return 130
    parser.parse_args(argv)  # prints usage / errors for unknown commands
    return 2


if __name__ == "__main__":
    sys.exit(main())
