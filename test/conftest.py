"""Test-wide setup: DDS on loopback and a ROS domain of this run's own."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

# Before anything imports rclpy: every process this run starts inherits these.
from robot_localization_suite.launch.dds import use_loopback  # noqa: E402

_DOMAIN_ID = 1 + os.getpid() % 100
use_loopback(_DOMAIN_ID)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    return _DOMAIN_ID
