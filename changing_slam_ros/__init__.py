"""changing_slam_ros: visual SLAM for dynamic and changing rooms (Changing-SLAM + Dai et al. 2021)."""

__version__ = "0.1.0"
