"""robot_localization_suite: five published localization methods and a simulator, side by side."""

__version__ = "0.1.0"
