"""The simulator's steps as ROS messages, published live by ``scan_sim`` or written into a bag.

:class:`StepMessages` builds the messages of one simulator step (a changed map on ``map`` and a
reinitialization request on ``operator/reinitialize_global_localization`` first, then odometry, as
``odom`` and as ``odom -> base`` on ``/tf``, before the scan it belongs to) and the static ones (``base -> laser``
on ``/tf_static``, the scenario's laser mount); :func:`record` runs a whole scenario as fast as
possible into an MCAP bag, its clock starting at ``record_epoch`` (2025, not 1970). Without tf2_msgs (:data:`.tf.TFMessage` None) there is no ``/tf``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..core.grid_map import GridMap
from ..core.sim.config import REINITIALIZE_TOPIC
from ..core.sim.settings import ScanSimSettings, build_scenario
from ..core.sim.simulator import SimulationStep, Simulator
from . import conversions
from .bag import BagWriter, bag_bytes
from .tf import TFMessage, tf_message, transform_to_msg

__all__ = ["StepMessages", "make_simulator", "record"]


class StepMessages:
    """Builds the ROS messages of a simulator step (shared by live mode and recording)."""

    def __init__(self, simulator: Simulator, settings: ScanSimSettings, epoch: float = 0.0,
                 time_scale: float = 1.0) -> None:
        self.simulator = simulator
        self.settings = settings
        self.epoch = epoch
        # Live at speed s, stamps advance with the wall clock (time_scale 1/s): the robot moves s
        # times faster, and every stamp stays consistent with the receiving nodes' clocks.
        self.time_scale = float(time_scale)
        laser = simulator.scenario.laser
        self._scan_fields = {
            "angle_min": laser.angle_min,
            "angle_increment": laser.angle_increment,
            "range_min": laser.range_min,
            "range_max": laser.range_max,
            "scan_time": laser.period,
        }

    def stamp(self, step_time: float) -> float:
        return self.epoch + step_time * self.time_scale

    def map_message(self, grid_map: GridMap | None = None, seconds: float | None = None) -> Any:
        """``grid_map`` (default: the map sensed now) as an OccupancyGrid stamped ``seconds`` (default: the epoch)."""
        grid = self.simulator.grid_map if grid_map is None else grid_map
        msg = conversions.grid_map_to_msg(grid, self.epoch if seconds is None else seconds)
        msg.header.frame_id = self.settings.map_frame
        return msg

    def reinitialize_message(self, seconds: float) -> Any:
        """The record of a reinitialization request: a std_msgs/Header stamped at the request, in the map frame."""
        from std_msgs.msg import Header

        return Header(stamp=conversions.seconds_to_stamp(seconds), frame_id=self.settings.map_frame)

    def static_messages(self) -> list[tuple[str, Any]]:
        """``(topic, message)`` published once: ``base -> laser`` (the scenario's laser mount) on ``tf_static``."""
        if TFMessage is None:
            return []
        s = self.settings
        laser = self.simulator.scenario.laser
        mount = np.asarray(laser.mount, dtype=np.float64)
        return [("tf_static", tf_message([transform_to_msg(self.epoch, s.base_frame, s.laser_frame, mount,
                                                           upside_down=laser.upside_down)]))]

    def step_messages(self, step: SimulationStep) -> list[tuple[str, Any]]:
        """``(topic, message)`` of a step in publication order (odometry before the scan it belongs to)."""
        seconds = self.stamp(step.time)
        s = self.settings
        events: list[tuple[str, Any]] = []
        if step.new_map is not None:
            events.append(("map", self.map_message(step.new_map, seconds)))
        if step.reinitialize:
            events.append((REINITIALIZE_TOPIC, self.reinitialize_message(seconds)))
        out = [
            *events,
            ("odom", conversions.odometry_to_msg(seconds, step.odom_pose, frame_id=s.odom_frame,
                                                 child_frame_id=s.base_frame, velocity=step.odom_velocity)),
            *([("tf", tf_message([transform_to_msg(seconds, s.odom_frame, s.base_frame, step.odom_pose)]))]
              if TFMessage is not None else []),
            ("ground_truth", conversions.odometry_to_msg(seconds, step.true_pose, frame_id=s.map_frame,
                                                         child_frame_id=s.base_frame, velocity=step.true_velocity)),
            ("scan", conversions.scan_to_msg(seconds, s.laser_frame, ranges=step.ranges, **self._scan_fields)),
        ]
        if step.image is not None:
            out.append(("camera/image_raw", conversions.image_to_msg(seconds, s.camera_frame, step.image)))
        return out


def make_simulator(settings: ScanSimSettings) -> Simulator:
    """The simulator the settings describe (scenario with overrides, or the cmd_vel world)."""
    from ..registry import resolve_scenario_path

    scenario = build_scenario(settings, resolve_scenario_path(settings.scenario))
    return Simulator(scenario, seed=None if settings.seed < 0 else settings.seed)


def record(bag_dir: str | Path, simulator: Simulator, settings: ScanSimSettings,
           *, log: Callable[[str], None] = print,
           stop_requested: Callable[[], str | None] = lambda: None) -> dict[str, int]:
    """Run the simulator's scenario as fast as possible into a new MCAP bag; returns messages per topic.

    ``stop_requested`` is asked after each step; a reason (e.g. ``"SIGINT"``) ends the recording
    there with a complete bag (footer, metadata.yaml) of the steps written so far.
    """
    scenario = simulator.scenario
    if (reason := stop_requested()) is not None:
        log(f"scan_sim: stopped by {reason} before recording began; nothing written")
        return {}
    # A realistic clock (settings.record_epoch, whole seconds), not 1970: log times are exact nanoseconds.
    epoch_ns = int(settings.record_epoch) * 1_000_000_000
    builder = StepMessages(simulator, settings, epoch=float(settings.record_epoch))
    counts: dict[str, int] = {}
    started = time.perf_counter()
    simulated = 0.0
    with BagWriter(bag_dir, compress=True) as writer:
        writer.write("/map", builder.map_message(), epoch_ns)
        counts["/map"] = 1
        for topic, msg in builder.static_messages():
            writer.write("/" + topic, msg, epoch_ns)
            counts["/" + topic] = 1
        for step in simulator.run():
            stamp_ns = epoch_ns + int(round(step.time * 1e9))
            for topic, msg in builder.step_messages(step):
                writer.write("/" + topic, msg, stamp_ns)
                counts["/" + topic] = counts.get("/" + topic, 0) + 1
            simulated = step.time
            if (reason := stop_requested()) is not None:
                break
    elapsed = time.perf_counter() - started
    size = bag_bytes(bag_dir)
    written = ", ".join(f"{topic} {count}" for topic, count in counts.items()) + f"; {size / 1e6:.2f} MB"
    if reason is not None:
        log(f"scan_sim: stopped early by {reason} at {simulated:.1f} s of {scenario.end_time:.1f} s simulated; "
            f"wrote {sum(counts.values())} messages into {str(bag_dir)!r}, a complete bag, in {elapsed:.1f} s: "
            + written)
    else:
        log(f"scan_sim: recorded {scenario.name!r} ({scenario.end_time:.1f} s simulated, "
            f"{len(scenario.kidnappings)} kidnappings, {len(scenario.map_changes)} map changes, "
            f"{len(scenario.reinitializations)} reinitializations) into {str(bag_dir)!r} in {elapsed:.1f} s: " + written)
    return counts
