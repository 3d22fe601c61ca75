"""Datasets and files: TUM folders, ROS 1 bags, ROS 2 bags (sqlite3, mcap), trajectories, maps."""
