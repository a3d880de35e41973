"""A scanner whose beam layout varies a little from scan to scan (an RPLIDAR's beam count, an angle_min a
hair off) is the same scanner: the node prepares for it once, not at every scan (ros/adapter.py
``preparation_due``, each method's ``prepared_for``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_fuzz import OVERRIDES, RANGE_MAX, room

from robot_localization_suite import registry
from robot_localization_suite.core.raycast import RayCaster
from robot_localization_suite.core.settings import parameters
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.adapter import LocalizerAdapter


def adapter_for(name: str, cache: Path, lines: list[tuple[str, str]]) -> LocalizerAdapter:
    plugin = registry.plugin(name)
    overrides = dict(OVERRIDES[name])
    for param in parameters(plugin.settings):
        if param.path[-1] == "cache_dir":
            overrides[param.name] = str(cache)
    localizer = plugin.create(plugin.load_settings(overrides)[1])
    return LocalizerAdapter(localizer, node_name=name, log=lambda level, text: lines.append((level, text)))


def scans(layouts: list[tuple[int, float]], field_of_view: float = 2.0 * math.pi) -> list[object]:
    """Scans along a short straight drive, one per (beam count, angle_min offset), centred on the laser's x axis."""
    grid_map = room()
    caster = RayCaster(grid_map, max_range=RANGE_MAX)
    messages = []
    for k, (beams, offset) in enumerate(layouts):
        pose = np.array([1.0 + 0.05 * k, 1.3, 0.1])
        increment = field_of_view / beams
        angle_min = -0.5 * field_of_view + offset
        ranges = caster.cast(pose, angle_min + increment * np.arange(beams)).astype(np.float64)
        messages.append((0.1 * (k + 1), pose, conversions.scan_to_msg(
            0.1 * (k + 1), "laser", angle_min=angle_min, angle_increment=increment, ranges=ranges,
            range_min=0.05, range_max=RANGE_MAX)))
    return messages


@pytest.mark.parametrize("name", ["ir_initializer", "pil_localizer", "hybrid_localizer"])
@pytest.mark.parametrize("layout", ["beam count", "angle_min"])
def test_a_scanner_whose_layout_varies_a_little_is_prepared_for_once(name: str, layout: str, tmp_path: Path) -> None:
    lines: list[tuple[str, str]] = []
    adapter = adapter_for(name, tmp_path, lines)
    adapter.set_map(room())
    varying = ([(360 + (k % 3) - 1, 0.0) for k in range(12)] if layout == "beam count"
               else [(360, 1e-6 * (k % 2)) for k in range(12)])
    prepared = 0
    for stamp, pose, msg in scans(varying):
        adapter.on_odometry(stamp, pose)
        if adapter.preparation_due(msg):
            adapter.prepare(msg)
            prepared += 1
        adapter.on_scan_msg(msg)
    assert prepared == 1, lines
    assert not any("two scanners" in text for _, text in lines), lines


def test_two_scanners_on_one_topic_are_named_in_a_warning(tmp_path: Path) -> None:
    lines: list[tuple[str, str]] = []
    adapter = adapter_for("pil_localizer", tmp_path, lines)
    adapter.set_map(room())
    for (stamp, pose, full), (_, _, part) in zip(scans([(360, 0.0)] * 3),
                                                 scans([(270, 0.0)] * 3, math.radians(270.0)), strict=True):
        adapter.on_odometry(stamp, pose)
        for msg in (full, part):
            if adapter.preparation_due(msg):
                adapter.prepare(msg)
    assert any(level == "warn" and "two scanners publishing on one topic" in text for level, text in lines), lines
