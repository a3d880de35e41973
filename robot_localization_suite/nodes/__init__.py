"""nodes of robot_localization_suite."""
