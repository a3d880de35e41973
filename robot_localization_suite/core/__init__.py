"""Pure localization algorithms: numpy / OpenCV / numba only, never rclpy."""
