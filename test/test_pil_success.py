"""tools/pil_success.py: the paper's section 4 success rate, scored against the poses the scans were cast from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcl_test_world import office_map

from robot_localization_suite.tools.pil_success import SUCCESS_M, format_table, measure, simulated_scans


def test_success_counts_fixes_within_20_cm_of_the_pose_each_scan_was_cast_from(tmp_path: Path) -> None:
    office = office_map()
    rng = np.random.default_rng(3)
    poses = np.repeat(office.sample_free_poses(6, rng), 2, axis=0)
    poses[:, 2] = rng.uniform(-np.pi, np.pi, len(poses))
    scans = simulated_scans(office, poses, beams=360, max_range=10.0, noise=0.01, rng=rng)
    rows = measure(office, "ours", poses, scans, headings=2, cache_dir=str(tmp_path))
    assert [row.search for row in rows] == ["window", "whole map"]
    window = rows[0]
    assert window.position_success.shape == (6,) and window.success_rate >= 5 / 6
    # the same fixes scored against poses 3 x SUCCESS_M away: none is a success
    moved = poses + np.array([3 * SUCCESS_M, 0.0, 0.0])
    far = measure(office, "ours", moved, scans, headings=2, cache_dir=str(tmp_path))
    assert far[1].success_rate == 0.0
    assert "| ours | whole map |" in format_table(rows)
