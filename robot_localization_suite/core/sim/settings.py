"""Every parameter of ``scan_sim``: the scenario, live-mode pacing, cmd_vel driving, overrides and frames.

Laser and odometry overrides are negative (or empty) to keep the scenario's own value.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ScenarioError
from ..grid_map import load_map_yaml
from ..settings import Settings, setting
from .config import MAX_BEAMS, MAX_RATE_HZ, ODOMETRY_MODELS, RANGE_NOISE_MODELS, LaserConfig, OdometryConfig
from .scenario import Scenario
from .scenario_yaml import load_scenario

__all__ = ["ScanSimSettings", "LASER_OVERRIDES", "ODOMETRY_OVERRIDES", "build_scenario"]

_KEEP = "negative (or empty): keep the scenario's value"

# ScanSimSettings field -> LaserConfig / OdometryConfig field it overrides.
LASER_OVERRIDES = {
    "beams": "beams",
    "fov_deg": "fov_deg",
    "range_min": "range_min",
    "range_max": "range_max",
    "rate_hz": "rate_hz",
    "range_noise_model": "range_noise_model",
    "range_noise_std": "range_noise_std",
    "range_noise_bound": "range_noise_bound",
    "outlier_prob": "outlier_prob",
    "dropout_prob": "dropout_prob",
}
ODOMETRY_OVERRIDES = {
    "odom_model": "model",
    "odom_alpha1": "alpha1",
    "odom_alpha2": "alpha2",
    "odom_alpha3": "alpha3",
    "odom_alpha4": "alpha4",
}


@dataclass(frozen=True)
class ScanSimSettings(Settings):
    """Settings of the ``scan_sim`` node (live and ``--record``)."""

    scenario: str = setting("", "scenario YAML (a path, or a name in config/scenarios); empty: drive by cmd_vel")
    map_yaml: str = setting("", "nav2 map_server YAML of the world without a scenario (cmd_vel mode)")
    seed: int = setting(-1, "noise seed; -1: the scenario's seed", low=-1, high=2_147_483_647)
    speed: float = setting(1.0, "real-time factor of live mode (2.0 runs twice as fast)", low=0.01, high=100.0)
    exit_at_end: bool = setting(True, "live mode: exit (code 0) when the scenario ends; false: keep publishing")
    start_x: float = setting(0.0, "cmd_vel mode: start x", unit="m", low=-1e6, high=1e6)
    start_y: float = setting(0.0, "cmd_vel mode: start y", unit="m", low=-1e6, high=1e6)
    start_yaw: float = setting(0.0, "cmd_vel mode: start heading (wrapped to [-pi, pi))", unit="rad",
                               low=-6.2832, high=6.2832)
    robot_radius: float = setting(0.2, "cmd_vel mode: robot radius kept from obstacles", unit="m", low=0.0, high=2.0)
    max_linear: float = setting(1.0, "cmd_vel mode: |linear.x| limit", unit="m/s", low=0.0, high=10.0)
    max_angular: float = setting(2.0, "cmd_vel mode: |angular.z| limit", unit="rad/s", low=0.0, high=20.0)
    cmd_vel_timeout: float = setting(0.5, "cmd_vel mode: stop after this long without a command", unit="s",
                                     low=0.0, high=60.0)
    beams: int = setting(-1, f"laser beams; {_KEEP}", low=-1, high=MAX_BEAMS)
    fov_deg: float = setting(-1.0, f"laser field of view, 90..360; {_KEEP}", unit="deg", low=-1.0, high=360.0)
    range_min: float = setting(-1.0, f"laser minimum range; {_KEEP}", unit="m", low=-1.0, high=1000.0)
    range_max: float = setting(-1.0, f"laser maximum range; {_KEEP}", unit="m", low=-1.0, high=1000.0)
    rate_hz: float = setting(-1.0, f"scans (and steps) per second; {_KEEP}", unit="Hz", low=-1.0, high=MAX_RATE_HZ)
    range_noise_model: str = setting("", f"gaussian or uniform; {_KEEP}", choices=("", *RANGE_NOISE_MODELS))
    range_noise_std: float = setting(-1.0, f"Gaussian range noise std; {_KEEP}", unit="m", low=-1.0, high=10.0)
    range_noise_bound: float = setting(-1.0, f"uniform range noise bound; {_KEEP}", unit="m", low=-1.0, high=10.0)
    outlier_prob: float = setting(-1.0, f"probability of a random reading per beam; {_KEEP}", low=-1.0, high=1.0)
    dropout_prob: float = setting(-1.0, f"probability of a no-return per beam; {_KEEP}", low=-1.0, high=1.0)
    odom_model: str = setting("", f"odometry noise: alphas or bounded; {_KEEP}", choices=("", *ODOMETRY_MODELS))
    odom_alpha1: float = setting(-1.0, f"odometry rotation noise from rotation; {_KEEP}", low=-1.0, high=10.0)
    odom_alpha2: float = setting(-1.0, f"odometry rotation noise from translation; {_KEEP}", low=-1.0, high=10.0)
    odom_alpha3: float = setting(-1.0, f"odometry translation noise from translation; {_KEEP}", low=-1.0, high=10.0)
    odom_alpha4: float = setting(-1.0, f"odometry translation noise from rotation; {_KEEP}", low=-1.0, high=10.0)
    map_frame: str = setting("map", "frame of the map and of ground_truth")
    odom_frame: str = setting("odom", "frame of odom")
    base_frame: str = setting("base_link", "child frame of odom and ground_truth")
    laser_frame: str = setting("laser", "frame of scan")
    camera_frame: str = setting("camera", "frame of camera/image_raw")
    record_epoch: int = setting(1_735_689_600, "--record: the simulated clock's t = 0 in seconds since 1970 "
                                "(live mode uses the node's clock); default 2025-01-01 00:00 UTC",
                                unit="s", low=0, high=4_000_000_000)

    def overrides(self, names: dict[str, str]) -> dict[str, Any]:
        """The scenario fields these settings override (the non-negative, non-empty ones)."""
        out: dict[str, Any] = {}
        for name, target in names.items():
            value = getattr(self, name)
            if (isinstance(value, str) and value) or (not isinstance(value, str) and value >= 0):
                out[target] = value
        return out


def build_scenario(settings: ScanSimSettings, scenario_path: Path | None) -> Scenario:
    """The scenario at ``scenario_path`` with the settings' laser and odometry overrides, or a cmd_vel world.

    Raises:
        ScenarioError, MapError: naming the bad value.
    """
    laser_changes = settings.overrides(LASER_OVERRIDES)
    odom_changes = settings.overrides(ODOMETRY_OVERRIDES)
    if scenario_path is not None:
        scenario = load_scenario(scenario_path)
        if not laser_changes and not odom_changes:
            return scenario
        return dataclasses.replace(
            scenario,
            laser=dataclasses.replace(scenario.laser, **laser_changes),
            odometry=dataclasses.replace(scenario.odometry, **odom_changes),
        )
    if not settings.map_yaml:
        raise ScenarioError("set either 'scenario' or 'map_yaml' (cmd_vel mode)")
    return Scenario(
        grid_map=load_map_yaml(settings.map_yaml, exact_resolution=True),
        start=(settings.start_x, settings.start_y, settings.start_yaw),
        laser=LaserConfig(**laser_changes),
        odometry=OdometryConfig(**odom_changes),
        robot_radius=settings.robot_radius,
        name="cmd_vel",
    )
