"""tools of robot_localization_suite."""
