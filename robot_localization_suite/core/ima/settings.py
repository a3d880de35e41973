"""Every parameter of ``ima_topo_localizer`` (thesis 003), with the thesis' value (section 5.2) where it gives one.

Place recognition (:class:`ImaSettings`, the thesis' ``TopoMap`` parameters of 4.1.1) is nested in the
tracker's settings (:class:`ImaTrackerSettings`, Code 3.1); both share one ROS namespace. Notes: docs/ima.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SettingsError
from ..settings import Settings, nested, setting

__all__ = ["ImaSettings", "ImaTrackerSettings", "NCC_BACKENDS", "ODOMETRY_RESETS", "POSE_ESTIMATES"]

NCC_BACKENDS = ("gemm", "opencv")
ODOMETRY_RESETS = ("winner", "place", "zoom")
POSE_ESTIMATES = ("node", "fused")


@dataclass(frozen=True)
class ImaSettings(Settings):
    """IMA place recognition (thesis 2.2-2.4, 4.1.1)."""

    width: int = setting(72, "working image width (thesis 5.2: 72)", unit="px", low=8, high=2048,
                         ros_name="scale_width", read_only=True)
    height: int = setting(58, "working image height (thesis 5.2: 58)", unit="px", low=4, high=2048,
                          ros_name="scale_height", read_only=True)
    slots: int = setting(8, "IMA slots Ns, at most half the width (thesis 5.2: 8)", low=1, high=1024, read_only=True)
    clahe: bool = setting(True, "CLAHE filtering of images and panoramas (thesis 2.2.2)", read_only=True)
    clahe_clip_limit: float = setting(2.0, "CLAHE contrast limit (OpenCV's usual 2.0)", low=0.0, low_open=True,
                                      high=100.0, read_only=True)
    clahe_tiles: int = setting(4, "CLAHE tiles across the working image", low=1, high=16, read_only=True)
    zoom: float = setting(1.1, "digital zoom rho_in (thesis 5.2: 1.1); 1.0 turns the zoom off", low=1.0, high=2.0,
                          read_only=True)
    ncc_backend: str = setting("gemm", "NCC computation: gemm (batched) or opencv (cv2.matchTemplate)",
                               choices=NCC_BACKENDS)
    cylindrical: bool = setting(True, "warp images to equal angle per column before matching (ours)", read_only=True)

    def validate(self) -> None:
        if self.slots > self.width // 2:
            raise SettingsError(f"ImaSettings.slots must be at most width/2 = {self.width // 2}, got {self.slots!r}")

    @property
    def slot_width(self) -> int:
        return self.width // self.slots

    @property
    def used_columns(self) -> tuple[int, int]:
        """First column and count of the image columns the slots cover."""
        used = self.slot_width * self.slots
        return (self.width - used) // 2, used


@dataclass(frozen=True)
class ImaTrackerSettings(Settings):
    """Multi-hypothesis topological tracking (thesis Code 3.1, section 5.2), and the topological map to load."""

    topomap: str = setting("topomaps/lab/topomap.yaml", "topological map YAML written by build_topomap; "
                           "relative: the working directory, then the package's config/", read_only=True)
    ima: ImaSettings = nested(ImaSettings)
    match_threshold: float = setting(0.5, "eps_M: least IMA match of a destination (thesis 5.2: 0.5)",
                                     low=0.0, high=1.0, high_open=True)
    heading_threshold: float = setting(0.6, "eps_phi >= eps_M: least match to correct the heading (thesis 5.2: 0.6)",
                                       low=0.0, high=1.0)
    min_translation: float = setting(0.3, "translation that triggers an update (thesis 5.2: 0.3)", unit="m",
                                     low=0.0, high=100.0, high_open=True, ros_name="update_min_d")
    min_rotation: float = setting(math.radians(10.0), "rotation that triggers an update (thesis 5.2: 10 deg)",
                                  unit="rad", low=0.0, high=math.pi, ros_name="update_min_a")
    min_sigma_l: float = setting(0.01, "floor of the position tolerance dl_max (ours)", unit="m",
                                 low=0.0, low_open=True, high=10.0, high_open=True)
    min_sigma_phi: float = setting(math.radians(1.0), "floor of the heading tolerance dphi_max (ours)", unit="rad",
                                   low=0.0, low_open=True, high=math.pi, high_open=True)
    heading_sigma: float = setting(math.radians(10.0), "heading standard deviation reported after a correction "
                                   "(thesis 5.1.4: 10 deg)", unit="rad", low=0.0, low_open=True, high=math.pi)
    ambiguity_ratio: float = setting(1.2, "LOCALIZED only when the winner's activity is at least this many times "
                                     "that of the best hypothesis at another place; else AMBIGUOUS (ours)",
                                     low=1.0, high=1000.0)
    odometry_reset: str = setting("zoom", "where the odometry guess d0 is measured from: every winner (Code 3.1), "
                                  "a new place, or also a match without zoom (ours)", choices=ODOMETRY_RESETS)
    pose_estimate: str = setting("fused", "the published position: the winner's node (thesis), or the odometry "
                                 "and the recognised places fused by a Kalman filter, each place a measurement "
                                 "with half the node spacing as standard deviation (ours)", choices=POSE_ESTIMATES)
    odometry_drift: float = setting(0.05, "standard deviation of the odometry's position error per metre "
                                    "travelled, for pose_estimate 'fused' (ours)", unit="m/m", low=0.0, high=1.0)
    localized_min_places: int = setting(3, "LOCALIZED only once this many different places were recognised "
                                        "since the position last restarted (a place far from the fused position, "
                                        "or the start; an initial pose counts as enough) (ours)", low=1, high=100)

    def validate(self) -> None:
        if self.heading_threshold < self.match_threshold:
            raise SettingsError(
                f"ImaTrackerSettings.heading_threshold (eps_phi) must be >= match_threshold (eps_M) "
                f"{self.match_threshold!r}, got {self.heading_threshold!r}"
            )
