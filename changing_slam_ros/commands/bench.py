"""`changing-slam bench FAMILY`: benchmarks over seeds of a simulated family.

    changing-slam bench changing --seeds A-B [--root DIR] ...   the changing-room family (`commands/bench_changing.py`)
"""

from __future__ import annotations

import argparse
import importlib

# family -> (module under changing_slam_ros.commands, one-line help)
FAMILIES: dict[str, tuple[str, str]] = {
    "changing": ("bench_changing", "the changing-room family: the semantic map scored over seeds"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="family", required=True, metavar="FAMILY")
    for name, (module, help_text) in FAMILIES.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        importlib.import_module(f"changing_slam_ros.commands.{module}").add_arguments(p)
        p.set_defaults(_bench_module=module)


def main(args: argparse.Namespace) -> int:
    module = importlib.import_module(f"changing_slam_ros.commands.{args._bench_module}")
    return int(module.main(args))
