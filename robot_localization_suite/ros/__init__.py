"""ros of robot_localization_suite."""
