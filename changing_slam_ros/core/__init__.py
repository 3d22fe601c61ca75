"""ROS-free algorithms. Nothing in this package imports rclpy, file formats or matplotlib."""
