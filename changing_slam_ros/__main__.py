import sys

from changing_slam_ros.cli import main

sys.exit(main())
