"""launch of robot_localization_suite."""
