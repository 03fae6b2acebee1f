"""The thin ROS 2 shell: the rclpy node and the bag player; the only place that imports rclpy and
ROS message packages. May import every layer but cli."""
