"""Every parameter of ``ial_localizer`` (Guyonneau et al., Advanced Robotics 2014), with the paper's value.

Why each default departs from the paper, and what soundness needs from the map: docs/ial.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SettingsError
from ..settings import Settings, setting

__all__ = ["IALSettings"]


@dataclass(frozen=True)
class IALSettings(Settings):
    """Settings of :class:`~.localizer.IntervalLocalizer` (paper sections 4.1 and 5.2 give the sensor values)."""

    range_error: float = setting(0.05, "eps_y: bound of a range reading's error (paper 4.1: 0.05, URG-30LX)",
                                 unit="m", low=0.0, high=10.0)
    max_outliers: int = setting(5, "n_o: readings allowed to break range_error (paper 5.2: 5 of 36)",
                                low=0, high=100_000)
    max_outliers_retry: int = setting(0, "when no box is left, the scan is tried again on the same boxes with this "
                                      "many outliers allowed before restarting from the whole map; 0: no retry, "
                                      "as the paper (ours)", low=0, high=100_000)
    max_beams: int = setting(36, "valid readings used per scan, evenly spaced (paper 5.2: 36)", low=1, high=100_000)
    min_box_width_xy: float = setting(0.05, "xi for x and y: bisect while a box is wider (ours)", unit="m",
                                      low=0.0, low_open=True, high=100.0)
    min_box_width_theta: float = setting(math.radians(1.0), "xi for the heading: bisect while wider (ours)",
                                         unit="rad", low=0.0, low_open=True, high=2.0 * math.pi, high_open=True)
    map_margin: float = setting(0.0, "a beam may end this far from an occupied cell: 0 for simulated maps, about a "
                                "cell for SLAM maps", unit="m", low=0.0, high=10.0, read_only=True)
    free_space_samples: int = setting(9, "points before each beam's end that must not be inside certain obstacles; "
                                      "0: off (ours)", low=0, high=64)
    unknown_is_obstacle: bool = setting(True, "a beam may end in an unknown cell (sound on any map); false: a beam "
                                        "ending in unknown space, away from every occupied cell, is one of the "
                                        "max_outliers (an assumption; docs/ial.md) (ours)", read_only=True)
    laser_in_free_cells: bool = setting(True, "the laser stands in a cell the map marks free; false: in any cell not "
                                        "marked occupied (ours)", read_only=True)
    laser_cell_constraint: bool = setting(True, "contract [x] x [y] to the cells the laser may stand in "
                                          "(laser_in_free_cells); false: no such constraint, any cell, occupied ones "
                                          "too (paper) (ours)", read_only=True)
    odom_relative_translation: float = setting(0.1, "odometry bound: translation error per step, relative part "
                                               "(paper 5.2: 0.1)", low=0.0, high=0.99)
    odom_absolute_translation: float = setting(0.01, "odometry bound: translation error per step, absolute part",
                                               unit="m", low=0.0, high=10.0)
    odom_relative_rotation: float = setting(0.1, "odometry bound: rotation error per step, relative part",
                                            low=0.0, high=0.99)
    odom_absolute_rotation: float = setting(math.radians(1.0), "odometry bound: rotation error per step, absolute "
                                            "part", unit="rad", low=0.0, high=3.14)
    odom_rotation_per_translation: float = setting(0.0, "odometry bound: rotation error per step per metre of "
                                                   "translation (the alpha2 term of Thrun's model; ours)",
                                                   unit="rad/m", low=0.0, high=10.0)
    odom_translation_per_rotation: float = setting(0.0, "odometry bound: translation error per step per radian of "
                                                   "rotation (the alpha4 term of Thrun's model; ours)",
                                                   unit="m/rad", low=0.0, high=10.0)
    contraction_passes: int = setting(3, "forward-backward passes per box at most", low=1, high=100)
    min_contraction_gain: float = setting(0.05, "stop the passes when no width shrank by more than this fraction",
                                          low=0.0, high=0.99)
    max_boxes: int = setting(20_000, "bisection stops past this many boxes in one scan (coarser, still sound)",
                             low=1, high=10_000_000)
    max_contractions: int = setting(2_000_000, "bisection stops past this many contractions in one scan",
                                    low=1, high=1_000_000_000)
    merge_width_xy: float = setting(0.5, "boxes are merged into hulls at most this wide before prediction "
                                    "(paper 5.2's tracking box)", unit="m", low=0.0, low_open=True, high=100.0)
    merge_width_theta: float = setting(math.radians(10.0), "heading width of those hulls (paper 5.2: 10 deg)",
                                       unit="rad", low=0.0, low_open=True, high=math.pi, high_open=True)
    localized_width_xy: float = setting(0.5, "LOCALIZED when the hull is at most this wide", unit="m",
                                        low=0.0, low_open=True, high=1e3)
    localized_width_theta: float = setting(math.radians(20.0), "LOCALIZED needs the hull heading width at most this",
                                           unit="rad", low=0.0, low_open=True, high=6.3)
    settle_updates: int = setting(5, "after the list empties (proof that the bounds were broken: people, a kidnapping), "
                                  "the new set must last this many updates before LOCALIZED; 0: at once (ours)",
                                  low=0, high=1_000_000)
    localized_needs_explained_scan: bool = setting(
        True, "LOCALIZED needs the map to explain, at the hull's centre, the share of the scan the bounds assume: "
        "at least 1 - max_outliers / max_beams of its end points within two cells of a mapped obstacle; the boxes "
        "hold the truth only while that assumption holds (ours; false: the hull's width alone)")
    initial_pose_sigmas: float = setting(3.0, "initialpose box half-width in standard deviations",
                                         low=0.0, low_open=True, high=100.0)
    initial_min_half_width_xy: float = setting(0.05, "initialpose box half-width at least", unit="m",
                                               low=0.0, low_open=True, high=100.0)
    initial_min_half_width_theta: float = setting(math.radians(3.0), "initialpose box heading half-width at least",
                                                  unit="rad", low=0.0, low_open=True, high=3.15)
    update_min_d: float = setting(0.0, "translation before an update; 0: every scan, as the paper", unit="m",
                                  low=0.0, high=1e3)
    update_min_a: float = setting(0.0, "rotation before an update; 0: every scan", unit="rad", low=0.0, high=7.0)

    def validate(self) -> None:
        if self.max_outliers >= self.max_beams:
            raise SettingsError(
                f"IALSettings.max_outliers ({self.max_outliers!r}) must be below max_beams ({self.max_beams!r})"
            )
        if self.max_outliers_retry and not self.max_outliers < self.max_outliers_retry < self.max_beams:
            raise SettingsError(
                f"IALSettings.max_outliers_retry ({self.max_outliers_retry!r}) must be 0 or between max_outliers "
                f"({self.max_outliers!r}) and max_beams ({self.max_beams!r})"
            )
        coupling = (self.odom_relative_translation + 2.0 * self.odom_translation_per_rotation
                    * self.odom_rotation_per_translation / (1.0 - self.odom_relative_rotation))
        if coupling >= 1.0:
            raise SettingsError(
                "IALSettings odometry bounds cannot be inverted: odom_relative_translation + 2 "
                "odom_translation_per_rotation odom_rotation_per_translation / (1 - odom_relative_rotation) "
                f"= {coupling!r} must be below 1"
            )
