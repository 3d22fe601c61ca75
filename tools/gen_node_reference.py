#!/usr/bin/env python3
"""Write docs/nodes.md from the node classes (`--check`: exit 1 when it is out of date).

The generator is `changing_slam_ros/nodes/node_reference.py`; the hand-written text per node is in
docs/nodes_intro/<node>.md. The package is imported from the checkout this tool lives in.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from changing_slam_ros.nodes.node_reference import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
