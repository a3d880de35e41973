"""carmen_to_bag --blocks: cross-validation splits of a hand-made corridor log (tools/carmen_cv.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from carmen_world import BEAMS, NO_RETURN, corridor_poses, corridor_ranges, write_log

from robot_localization_suite.core.grid_map import load_map_yaml
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.tools import carmen_cv, carmen_to_bag
from robot_localization_suite.tools.carmen_cv import CrossValidationError, block_ranges, load_cv_index, split_log
from robot_localization_suite.tools.carmen_to_bag import convert_log
from robot_localization_suite.tools.scan_coverage import bag_scan_coverage

SCANS, BLOCKS = 60, 3  # three blocks of 20 scans, 9 m of corridor each


@pytest.fixture(scope="module")
def corridor_split(tmp_path_factory):
    """A 60-scan corridor log, split in 3 (once for the module), and its whole-log bag."""
    work = tmp_path_factory.mktemp("cv")
    log_path = write_log(work / "corridor-corrected.log", corridor_poses(SCANS))
    split = split_log(log_path, work / "out", BLOCKS, on_warning=None)
    convert_log(log_path, work / "whole", on_warning=None)
    return {"log": log_path, "split": split, "out": work / "out", "whole": work / "whole"}


def test_block_ranges_are_contiguous_equal_counts_first_blocks_longer():
    assert block_ranges(10, 3) == [range(0, 4), range(4, 7), range(7, 10)]
    assert block_ranges(60, 3) == [range(0, 20), range(20, 40), range(40, 60)]
    with pytest.raises(ValueError, match="at least 2 blocks, got 1"):
        block_ranges(10, 1)


def test_split_writes_a_bag_and_a_map_per_block_named_to_pair_and_an_index(corridor_split):
    out = corridor_split["out"]
    names = sorted(p.name for p in out.iterdir())
    assert names == ["corridor_cv.yaml",
                     "corridor_cv1of3", "corridor_cv1of3.png", "corridor_cv1of3.yaml",
                     "corridor_cv2of3", "corridor_cv2of3.png", "corridor_cv2of3.yaml",
                     "corridor_cv3of3", "corridor_cv3of3.png", "corridor_cv3of3.yaml",
                     "corridor_full.png", "corridor_full.yaml"]
    split = load_cv_index(out / "corridor_cv.yaml")
    assert split.name == "corridor" and split.scans == SCANS and split.full_map_yaml == out / "corridor_full.yaml"
    assert [b.scan_range for b in split.blocks] == [(0, 20), (20, 40), (40, 60)]
    assert [b.time_range for b in split.blocks] == [(10.0, 14.75), (15.0, 19.75), (20.0, 24.75)]  # 10 + i / 4 s
    for block in split.blocks:
        assert block.status == "ok" and block.scan_count == 20
        assert block.bag == out / f"corridor_cv{block.block}of3"
        assert block.map_yaml == out / f"corridor_cv{block.block}of3.yaml"
        # The bag's /map is the block's own map, so `rls_bench BAG` alone is honest too.
        messages = list(read_bag(block.bag))
        assert messages[0].topic == "/map"
        in_bag, on_file = conversions.grid_map_from_msg(messages[0].msg), load_map_yaml(block.map_yaml)
        assert np.array_equal(in_bag.occupied_mask, on_file.occupied_mask)
        assert np.array_equal(in_bag.free_mask, on_file.free_mask)
    # Relative paths in the index: the directory can move.
    raw = yaml.safe_load((out / "corridor_cv.yaml").read_text())
    assert raw["blocks"][0]["bag"] == "corridor_cv1of3" and raw["full_map"] == "corridor_full.yaml"


def _contents(message) -> list:
    fields = []
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        if hasattr(value, "get_fields_and_field_types"):
            fields += _contents(value)
        else:
            fields.append(value if isinstance(value, str) else np.asarray(value).tobytes())
    return fields


def test_block_bags_partition_the_whole_log_bag(corridor_split):
    """Same stamps, same odometry stream (seeded once over the whole log), same scans: only /map differs."""
    whole = [(m.topic, m.stamp_ns, _contents(m.msg)) for m in read_bag(corridor_split["whole"]) if m.topic != "/map"]
    blocks = []
    for block in corridor_split["split"].blocks:
        blocks += [(m.topic, m.stamp_ns, _contents(m.msg)) for m in read_bag(block.bag) if m.topic != "/map"]
    assert len(whole) == 3 * SCANS
    assert blocks == whole


def _hit_cells(grid_map, poses: np.ndarray) -> set[tuple[int, int]]:
    """Cells (of ``grid_map``'s lattice) holding a hit end point of the corridor scans at ``poses``."""
    cells = set()
    angles = np.deg2rad(np.arange(BEAMS) - 90.0)
    for pose in poses:
        ranges = corridor_ranges(pose)
        hit = ranges < NO_RETURN
        ends = pose[:2] + ranges[hit, None] * np.stack([np.cos(pose[2] + angles[hit]),
                                                        np.sin(pose[2] + angles[hit])], axis=1)
        cells.update(map(tuple, grid_map.world_to_cell(ends).tolist()))
    return cells


def test_a_block_map_never_holds_a_wall_only_that_block_saw(corridor_split):
    split = corridor_split["split"]
    full = load_map_yaml(split.full_map_yaml)
    poses = corridor_poses(SCANS)
    for block in split.blocks:
        own = np.zeros(SCANS, dtype=bool)
        own[block.scan_range[0] : block.scan_range[1]] = True
        only_here = _hit_cells(full, poses[own]) - _hit_cells(full, poses[~own])
        assert len(only_here) > 20, block.label  # wall cells within 4 m of this block's poses only
        centres = full.cell_to_world(np.array(sorted(only_here)))
        cells_full = full.world_to_cell(centres)
        # The whole-log map has these walls (a few wall cells are also crossed by grazing beams) ...
        assert full.occupied_mask[cells_full[:, 1], cells_full[:, 0]].mean() > 0.9, block.label
        # ... the block's own map, built from the other blocks, has none of them.
        own_map = load_map_yaml(block.map_yaml)
        cells_own = own_map.world_to_cell(centres)
        inside = own_map.in_bounds(cells_own)
        assert not own_map.occupied_mask[cells_own[inside, 1], cells_own[inside, 0]].any(), block.label
    # The end blocks' maps do not even reach the far end of the corridor they alone saw.
    first = load_map_yaml(split.blocks[0].map_yaml)
    assert first.extent[0] > 1.0 and full.extent[0] < 0.0


def test_coverage_is_recorded_per_block_and_matches_the_bag_helper(corridor_split):
    split = corridor_split["split"]
    for block in split.blocks:
        own = bag_scan_coverage(block.bag, load_map_yaml(block.map_yaml))
        same = bag_scan_coverage(block.bag, load_map_yaml(split.full_map_yaml))
        assert own.median == pytest.approx(block.coverage_median, abs=1e-4)
        assert same.median == pytest.approx(block.coverage_median_same_map, abs=1e-4)
        assert same.median == pytest.approx(1.0)  # every end point sits on a wall of the whole-log map
        assert own.at(own.stamps[:3]) == pytest.approx(own.coverage[:3])
    # The end blocks saw walls nobody else saw: their own maps explain less of their scans.
    assert split.blocks[0].coverage_median < 0.95 and split.blocks[2].coverage_median < 0.95


def test_a_block_under_20_scans_is_skipped_and_the_rest_written(tmp_path, capsys):
    log_path = write_log(tmp_path / "short-corrected.log", corridor_poses(59))  # blocks of 20, 20 and 19
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "out"), "--blocks", "3"]) == 0
    err = capsys.readouterr().err
    assert "carmen_to_bag: block 3 of 3 (scans 40-58): 19 scans, fewer than 20: skipped, nothing written" in err
    split = load_cv_index(tmp_path / "out" / "short_cv.yaml")
    assert [b.status for b in split.blocks] == ["ok", "ok", "skipped"]
    assert split.blocks[2].bag is None and not (tmp_path / "out" / "short_cv3of3").exists()
    assert not (tmp_path / "out" / "short_cv3of3.yaml").exists()


def test_every_block_too_short_exits_non_zero(tmp_path, capsys):
    log_path = write_log(tmp_path / "tiny.log", corridor_poses(30))
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "out"), "--blocks", "2"]) == 1
    assert capsys.readouterr().err.count("fewer than 20: skipped") == 2


def test_a_map_far_from_the_block_path_is_refused_naming_the_block(tmp_path, capsys):
    # Two corridors 200 m apart: neither block's map (the other corridor) has free space near it.
    poses = np.vstack([corridor_poses(20), corridor_poses(20, y=200.0)])
    ranges = [corridor_ranges(p, y_offset=200.0 if i >= 20 else 0.0) for i, p in enumerate(poses)]
    log_path = write_log(tmp_path / "apart.log", poses, ranges=ranges)
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "out"), "--blocks", "2"]) == 1
    err = capsys.readouterr().err
    assert ("carmen_to_bag: block 1 of 2 (scans 0-19): its map (from the other blocks) has no free cell within 1 m "
            "of any of its 20 true poses: the other blocks never saw where it drives; refused, nothing written") in err
    assert "block 2 of 2 (scans 20-39): its map (from the other blocks) has no free cell within 1 m" in err
    split = load_cv_index(tmp_path / "out" / "apart_cv.yaml")
    assert [b.status for b in split.blocks] == ["refused", "refused"]
    assert not (tmp_path / "out" / "apart_cv1of2").exists()


def test_a_map_without_free_cells_is_refused_and_the_other_block_goes_on(tmp_path, capsys):
    # Block 2's scans are all no-returns: they clear nothing, so block 1's map has no free cell.
    poses = corridor_poses(40)
    ranges = [corridor_ranges(p) if i < 20 else np.full(BEAMS, NO_RETURN) for i, p in enumerate(poses)]
    log_path = write_log(tmp_path / "blind.log", poses, ranges=ranges)
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "out"), "--blocks", "2"]) == 0
    assert ("block 1 of 2 (scans 0-19): its map (from the other blocks) has no free cell; refused"
            in capsys.readouterr().err)
    split = load_cv_index(tmp_path / "out" / "blind_cv.yaml")
    assert [b.status for b in split.blocks] == ["refused", "ok"]
    assert split.blocks[0].reason == "its map (from the other blocks) has no free cell"


def test_check_block_map_raises_the_specific_error(corridor_split):
    full = load_map_yaml(corridor_split["split"].full_map_yaml)
    assert carmen_cv.check_block_map(full, corridor_poses(5), "block 9 of 9") == 1.0
    with pytest.raises(CrossValidationError, match=r"^block 9 of 9: .* no free cell within 1 m of any of its 5"):
        carmen_cv.check_block_map(full, corridor_poses(5, y=50.0), "block 9 of 9")


def test_existing_outputs_are_kept_unless_overwrite(corridor_split, tmp_path):
    out = tmp_path / "again"
    split_log(corridor_split["log"], out, BLOCKS, on_warning=None)
    with pytest.raises(carmen_to_bag.CarmenLogError, match="corridor_cv.yaml' exists .use --overwrite"):
        split_log(corridor_split["log"], out, BLOCKS, on_warning=None)
    again = split_log(corridor_split["log"], out, BLOCKS, on_warning=None, overwrite=True)
    assert len(again.written()) == BLOCKS


def test_blocks_and_map_out_do_not_go_together(tmp_path, capsys):
    with pytest.raises(SystemExit):
        carmen_to_bag.main(["x.log", str(tmp_path / "out"), "--blocks", "2", "--map-out", "m.yaml"])
    assert "--map-out does not go with --blocks" in capsys.readouterr().err


def test_default_name_drops_the_log_suffixes():
    assert carmen_cv.default_name(Path("a/intel-corrected.log.gz")) == "intel"
    assert carmen_cv.default_name("freiburg-101-corrected.log") == "freiburg-101"
