"""carmen_to_bag: a slice of the real Intel log converted and read back, and bad logs."""

from __future__ import annotations

import gzip
import itertools
from pathlib import Path

import numpy as np
import pytest
from carmen_world import NO_RETURN, corridor_poses, corridor_ranges, robotlaser_line, write_log

from robot_localization_suite.core.grid_map import load_map_yaml
from robot_localization_suite.core.motion import ODOMETRY_NOISE_KEY, odometry_delta, read_odometry_noise
from robot_localization_suite.ros import conversions
from robot_localization_suite.ros.bag import bag_custom_data, bag_topics, read_bag
from robot_localization_suite.tools import carmen_cv, carmen_log, carmen_to_bag
from robot_localization_suite.tools.carmen_to_bag import CarmenLogError, ConversionSettings, convert_log

INTEL_LOG = Path(__file__).resolve().parents[2] / "shared" / "data" / "carmen" / "intel-corrected.log.gz"
SLICE_LINES = 1200  # ~50 scans of the Intel log: enough for a map, fast to convert


def log_slice(lines: int) -> list[str]:
    if not INTEL_LOG.is_file():
        pytest.skip(f"the Intel log is not at {INTEL_LOG}")
    with gzip.open(INTEL_LOG, "rt") as stream:
        return list(itertools.islice(stream, lines))


def flaser_poses(lines: list[str]) -> np.ndarray:
    poses = []
    for line in lines:
        tokens = line.split()
        if tokens and tokens[0] == "FLASER":
            count = int(tokens[1])
            poses.append([float(v) for v in tokens[2 + count : 5 + count]])
    return np.array(poses)


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """The first lines of the Intel log, gzipped, converted once for all tests here."""
    lines = log_slice(SLICE_LINES)
    work = tmp_path_factory.mktemp("carmen")
    log_path = work / "intel_slice.log.gz"
    with gzip.open(log_path, "wt") as stream:
        stream.writelines(lines)
    report = convert_log(log_path, work / "intel_slice", map_out=work / "intel_slice.yaml", settings=ConversionSettings(seed=3))
    return {"lines": lines, "bag": work / "intel_slice", "yaml": work / "intel_slice.yaml", "report": report,
            "log": log_path, "work": work}


def test_converted_scans_have_the_log_beam_count_fov_and_pose_count(converted):
    expected = flaser_poses(converted["lines"])
    assert len(expected) > 30
    assert bag_topics(converted["bag"]) == {
        "/map": "nav_msgs/msg/OccupancyGrid",
        "/odom": "nav_msgs/msg/Odometry",
        "/ground_truth": "nav_msgs/msg/Odometry",
        "/scan": "sensor_msgs/msg/LaserScan",
    }
    scans = [conversions.scan_from_msg(m.msg) for m in read_bag(converted["bag"], ["/scan"])]
    truth = [conversions.odometry_from_msg(m.msg) for m in read_bag(converted["bag"], ["/ground_truth"])]
    assert len(scans) == len(truth) == len(expected)
    for scan in scans:
        assert scan.beam_count == 180  # the Intel log's FLASER lines carry 180 readings
        assert scan.angles[0] == pytest.approx(-np.pi / 2)  # CARMEN: first beam at -90 degrees, 1 degree apart
        assert scan.field_of_view == pytest.approx(np.pi)
    # Ground truth is the corrected pose of each FLASER line, stamped like its scan.
    assert np.array([p for _, p in truth]) == pytest.approx(expected, abs=1e-6)
    assert [s for s, _ in truth] == pytest.approx([s.stamp for s in scans])
    assert np.all(np.diff([s.stamp for s in scans]) > 0)


def test_no_returns_become_inf_with_range_max_at_the_threshold(converted):
    raw = np.concatenate([np.array(line.split()[2:182], dtype=float) for line in converted["lines"]
                          if line.startswith("FLASER")])
    msgs = [m.msg for m in read_bag(converted["bag"], ["/scan"])]
    ranges = np.concatenate([np.asarray(m.ranges) for m in msgs])
    threshold = raw.max() - ConversionSettings().no_return_tolerance
    assert msgs[0].range_max == pytest.approx(threshold, abs=1e-4)
    assert np.array_equal(np.isinf(ranges), raw >= threshold)
    assert np.isinf(ranges).any()  # the slice does hold no-returns (81.83 m readings)
    hits = ~np.isinf(ranges)
    assert ranges[hits] == pytest.approx(raw[hits], abs=1e-5)


def test_map_is_free_along_the_trajectory_and_has_walls(converted):
    grid_map = load_map_yaml(converted["yaml"])
    assert grid_map.resolution == pytest.approx(0.05)
    poses = flaser_poses(converted["lines"])
    assert grid_map.is_free(poses[:, :2]).all()
    assert grid_map.occupied_mask.sum() > 500  # walls from ~50 scans
    assert grid_map.unknown_mask.any()  # never-seen cells stay unknown
    # The bag's /map is the same map.
    msg = next(read_bag(converted["bag"], ["/map"])).msg
    in_bag = conversions.grid_map_from_msg(msg)
    assert np.array_equal(in_bag.occupied_mask, grid_map.occupied_mask)
    assert np.array_equal(in_bag.free_mask, grid_map.free_mask)


def test_scan_endpoints_land_on_occupied_cells(converted):
    grid_map = load_map_yaml(converted["yaml"])
    poses = flaser_poses(converted["lines"])
    scans = [conversions.scan_from_msg(m.msg) for m in read_bag(converted["bag"], ["/scan"])]
    endpoints = np.vstack([scan.hit_endpoints(pose) for scan, pose in zip(scans, poses, strict=True)])
    cells = grid_map.world_to_cell(endpoints)
    occupied = grid_map.occupied_mask[cells[:, 1], cells[:, 0]]
    assert occupied.mean() > 0.8  # the rest were cleared later by beams passing through (people, clutter)


def test_odometry_is_noisy_but_follows_the_corrected_steps(converted):
    truth = np.array([conversions.odometry_from_msg(m.msg)[1] for m in read_bag(converted["bag"], ["/ground_truth"])])
    odom_msgs = [m.msg for m in read_bag(converted["bag"], ["/odom"])]
    odom = np.array([conversions.odometry_from_msg(m)[1] for m in odom_msgs])
    assert odom_msgs[0].header.frame_id == "odom" and odom_msgs[0].child_frame_id == "base_link"
    assert odom[0] == pytest.approx([0.0, 0.0, 0.0])
    true_steps = np.array([odometry_delta(a, b).trans for a, b in itertools.pairwise(truth)])
    odom_steps = np.array([odometry_delta(a, b).trans for a, b in itertools.pairwise(odom)])
    assert np.abs(odom_steps - true_steps).max() < 0.1 * true_steps.max() + 0.02
    assert not np.allclose(odom_steps, true_steps, atol=1e-9)  # noise was added


def test_the_bag_declares_the_odometry_noise_it_was_made_with(converted, tmp_path):
    declared = bag_custom_data(converted["bag"])[ODOMETRY_NOISE_KEY]
    assert read_odometry_noise(declared) == dict(zip(("alpha1", "alpha2", "alpha3", "alpha4"),
                                                     ConversionSettings().alphas, strict=True))
    noisier = ConversionSettings(seed=3, alphas=(0.01, 0.002, 0.03, 0.004))
    convert_log(converted["log"], tmp_path / "noisier", settings=noisier)
    assert read_odometry_noise(bag_custom_data(tmp_path / "noisier")[ODOMETRY_NOISE_KEY]) == {
        "alpha1": 0.01, "alpha2": 0.002, "alpha3": 0.03, "alpha4": 0.004}


def test_same_seed_same_bag(converted, tmp_path):
    convert_log(converted["log"], tmp_path / "again", settings=ConversionSettings(seed=3))
    first = [m.msg.pose.pose.position.x for m in read_bag(converted["bag"], ["/odom"])]
    again = [m.msg.pose.pose.position.x for m in read_bag(tmp_path / "again", ["/odom"])]
    assert first == again


def test_malformed_line_is_reported_with_its_line_number_and_skipped(tmp_path, capsys):
    lines = log_slice(200)
    flaser = [i for i, line in enumerate(lines) if line.startswith("FLASER")]
    truncated_index = flaser[1]
    lines[truncated_index] = " ".join(lines[truncated_index].split()[:100]) + "\n"  # cut in the middle of the ranges
    log_path = tmp_path / "broken.log"
    log_path.write_text("".join(lines))
    report = convert_log(log_path, tmp_path / "broken")
    line_number = truncated_index + 1
    assert report.skipped_lines[0][0] == line_number
    assert report.scans == len(flaser) - 1
    assert f"line {line_number}: malformed FLASER line (truncated" in capsys.readouterr().err


def test_non_numeric_field_is_reported(tmp_path):
    lines = log_slice(200)
    index = next(i for i, line in enumerate(lines) if line.startswith("FLASER"))
    tokens = lines[index].split()
    tokens[5] = "1.0x"
    lines[index] = " ".join(tokens) + "\n"
    log_path = tmp_path / "bad_number.log"
    log_path.write_text("".join(lines))
    skipped = []
    log = carmen_to_bag.parse_carmen_log(log_path, on_skip=lambda n, why: skipped.append((n, why)))
    assert skipped == [(index + 1, "malformed FLASER line (field '1.0x' is not a number)")]
    assert len(log.scans) == sum(line.startswith("FLASER") for line in lines) - 1


def test_a_line_whose_beam_count_does_not_match_its_readings_is_skipped(tmp_path):
    # FLASER 180 with 181 readings was read with every field after them shifted: the stamp from odom_theta.
    lines = write_log(tmp_path / "flaser.log", corridor_poses(5)).read_text().splitlines(keepends=True)
    for line_number, count in ((3, "180"), (4, "182")):
        tokens = lines[line_number - 1].split()
        tokens[1] = count
        lines[line_number - 1] = " ".join(tokens) + "\n"
    (tmp_path / "flaser.log").write_text("".join(lines))
    skipped = []
    log = carmen_to_bag.parse_carmen_log(tmp_path / "flaser.log", on_skip=lambda n, why: skipped.append((n, why)))
    assert [s.line_number for s in log.scans] == [2, 5, 6]
    assert skipped == [
        (3, "malformed FLASER line (192 fields, 191 expected for 180 beams (the beam count does not match the "
            "readings))"),
        (4, "malformed FLASER line (192 fields, 193 expected for 182 beams (the beam count does not match the "
            "readings))"),
    ]
    # ROBOTLASER1 likewise: one beam short, the last reading (0, no return) was taken for the remission count.
    poses = corridor_poses(2)
    tokens = robotlaser_line(corridor_ranges(poses[1]), poses[1], 10.25).split()
    tokens[8], tokens[8 + 181] = "180", "0"
    log_path = tmp_path / "robotlaser.log"
    log_path.write_text(robotlaser_line(corridor_ranges(poses[0]), poses[0], 10.0) + " ".join(tokens) + "\n")
    skipped = []
    log = carmen_to_bag.parse_carmen_log(log_path, on_skip=lambda n, why: skipped.append((n, why)))
    assert len(log.scans) == 1
    assert skipped == [(2, "malformed ROBOTLASER1 line (205 fields, 204 expected for 180 beams (the beam count "
                           "does not match the readings))")]


def test_a_non_finite_reading_is_passed_on_and_the_maximum_range_comes_from_the_finite_ones(tmp_path):
    # One inf reading made the whole log "cannot find the maximum range of the log (largest reading inf)".
    poses = corridor_poses(6)
    ranges = [corridor_ranges(pose) for pose in poses]
    ranges[2][10], ranges[3][20], ranges[4][30] = np.inf, np.nan, -np.inf
    log_path = write_log(tmp_path / "inf.log", poses, ranges=ranges)
    report = convert_log(log_path, tmp_path / "inf")
    assert report.max_range == pytest.approx(NO_RETURN - ConversionSettings().no_return_tolerance)
    scans = [np.asarray(m.msg.ranges) for m in read_bag(tmp_path / "inf", ["/scan"])]
    assert scans[2][10] == np.inf and np.isnan(scans[3][20]) and scans[4][30] == -np.inf
    assert np.all(np.isinf(scans[2][ranges[2] == NO_RETURN]))  # the log's own no-returns still are
    poses = corridor_poses(2)
    write_log(log_path, poses, ranges=[np.full(181, np.inf), np.full(181, np.nan)])
    with pytest.raises(CarmenLogError, match=r"maximum range of the log \(no finite reading\)"):
        convert_log(log_path, tmp_path / "none")


def test_a_pose_far_off_is_skipped_and_a_map_too_big_to_build_is_refused(tmp_path, capsys):
    # x = 1e9 in one line made the map 20,000,001,555 x 985 cells: "Unable to allocate 71.7 TiB".
    poses = corridor_poses(6)
    far = poses.copy()
    far[3, 0] = 1e9
    log_path = write_log(tmp_path / "far.log", far, ranges=[corridor_ranges(pose) for pose in poses])
    report = convert_log(log_path, tmp_path / "far")
    assert report.scans == 5 and report.skipped_lines == [(5, "pose [1000000000.0, 0.0, 0.0] is farther than "
                                                              "1e+06 m from the origin")]
    assert "line 5: malformed FLASER line (pose [1000000000.0, 0.0, 0.0] is farther than" in capsys.readouterr().err
    # Within 1e6 m a map can still be far too big to allocate: refused naming its size before anything is written.
    spread = np.array([[0.0, 0.0, 0.0], [9e5, 9e5, 0.0]])
    with pytest.raises(ValueError, match=r"^the map would be 18000041 x 18000041 cells \(900002 m x 900002 m at "
                                         r"0.05 m\), more than 400000000$"):
        carmen_to_bag.build_occupancy_map(spread, [np.zeros(0)] * 2, [np.zeros(0)] * 2, 80.0)
    write_log(log_path, spread, ranges=[np.full(181, 1.0)] * 2)
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "spread")]) == 1
    assert capsys.readouterr().err.splitlines()[-1].startswith("carmen_to_bag: error: the map would be 18000041 x ")
    assert not (tmp_path / "spread").exists()


def test_outputs_that_cannot_be_written_are_refused_before_converting(tmp_path, capsys):
    # Each ended in a traceback (FileExistsError, IsADirectoryError), some after the bag had been written.
    log_path = write_log(tmp_path / "ok.log", corridor_poses(6))
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    (tmp_path / "image.pgm").mkdir()
    cases = [
        ([str(tmp_path / "afile" / "bag")], f"OUT_DIR: {str(tmp_path / 'afile' / 'bag')!r} cannot be created: "
                                            f"{str(tmp_path / 'afile')!r} is not a directory"),
        ([str(tmp_path / "afile"), "--blocks", "2"], f"OUT_DIR: {str(tmp_path / 'afile')!r} is not a directory"),
        ([str(tmp_path / "bag"), "--map-out", str(tmp_path / "afile" / "deeper" / "map.yaml")],
         f"--map-out: {str(tmp_path / 'afile' / 'deeper' / 'map.yaml')!r} cannot be created: "
         f"{str(tmp_path / 'afile')!r} is not a directory"),
        ([str(tmp_path / "bag"), "--map-out", str(tmp_path / "adir")], f"--map-out: {str(tmp_path / 'adir')!r} is a "
                                                                       "directory"),
        ([str(tmp_path / "bag"), "--map-out", str(tmp_path / "image.yaml")],
         f"--map-out: {str(tmp_path / 'image.pgm')!r} is a directory"),
    ]
    for args, message in cases:
        with pytest.raises(SystemExit) as exit_info:
            carmen_to_bag.main([str(log_path), *args])
        assert exit_info.value.code == 2
        assert capsys.readouterr().err.splitlines()[-1] == f"carmen_to_bag: error: {message}"
        assert not (tmp_path / "bag").exists()
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "new" / "bag"), "--map-out",
                               str(tmp_path / "new" / "maps" / "map.yaml")]) == 0  # missing parents are made


def test_log_without_flaser_lines_is_an_error(tmp_path):
    log_path = tmp_path / "odom_only.log"
    log_path.write_text("# a CARMEN log\nODOM 0 0 0 0 0 0 0.1 host 0.1\nODOM 0.1 0 0 0 0 0 0.2 host 0.2\n")
    with pytest.raises(CarmenLogError, match="no usable FLASER or ROBOTLASER1 line"):
        convert_log(log_path, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "out")]) == 1


def _as_robotlaser(line: str) -> str:
    """A FLASER line of the Intel log written as the ROBOTLASER1 line CARMEN's laser-new logs it as."""
    tokens = line.split()
    count = int(tokens[1])
    ranges = [float(v) for v in tokens[2 : 2 + count]]
    pose = [float(v) for v in tokens[2 + count : 5 + count]]
    return robotlaser_line(ranges, pose, float(tokens[8 + count]), remissions=[1.0] * 3)


def test_a_robotlaser1_log_converts_to_the_same_bag_and_map_as_its_flaser_lines(converted, tmp_path):
    # Some CARMEN logs hold the front laser only as ROBOTLASER1 lines (geometry stated, remissions, two poses).
    lines = [_as_robotlaser(line) if line.startswith("FLASER") else line for line in converted["lines"]]
    log_path = tmp_path / "robotlaser.log"
    log_path.write_text("".join(lines))
    log = carmen_to_bag.parse_carmen_log(log_path)
    assert log.message == "ROBOTLASER1" and len(log.scans) == len(flaser_poses(converted["lines"]))
    report = convert_log(log_path, tmp_path / "robotlaser", map_out=tmp_path / "robotlaser.yaml",
                         settings=ConversionSettings(seed=3))
    assert report.stamp_source == "ROBOTLASER1 ipc_timestamp"
    for topic in ("/scan", "/ground_truth", "/odom"):
        ours = [m.msg for m in read_bag(tmp_path / "robotlaser", [topic])]
        theirs = [m.msg for m in read_bag(converted["bag"], [topic])]
        assert len(ours) == len(theirs)
        if topic == "/scan":
            for a, b in zip(ours, theirs, strict=True):
                assert a.angle_min == pytest.approx(b.angle_min) and a.angle_increment == pytest.approx(b.angle_increment)
                assert np.array_equal(np.asarray(a.ranges), np.asarray(b.ranges))
        else:
            assert np.array([conversions.odometry_from_msg(m)[1] for m in ours]) == pytest.approx(
                np.array([conversions.odometry_from_msg(m)[1] for m in theirs]), abs=1e-4)  # poses written to 6 digits
    assert np.array_equal(load_map_yaml(tmp_path / "robotlaser.yaml").occupied_mask,
                          load_map_yaml(converted["yaml"]).occupied_mask)


def test_a_robotlaser1_line_gives_its_own_beam_geometry_to_the_scan(tmp_path):
    # A 270-degree scanner at 0.5 degree (541 beams): FLASER's guess from the count would say 180 degrees.
    poses = corridor_poses(12)
    start, step = -0.75 * np.pi, np.pi / 360
    lines = [robotlaser_line(np.full(541, 1.0 + 0.01 * i), pose, 10.0 + 0.25 * i, start_angle=start,
                             fov=1.5 * np.pi, resolution=step) for i, pose in enumerate(poses)]
    # A line that states no resolution spreads its field of view over the gaps; one with neither is skipped.
    lines.append(robotlaser_line(np.full(541, 1.2), poses[-1] + [0.45, 0, 0], 13.0, start_angle=start,
                                 fov=1.5 * np.pi, resolution=0.0))
    lines.append(robotlaser_line(np.full(541, 1.2), poses[-1] + [0.9, 0, 0], 13.25, resolution=0.0, fov=0.0))
    log_path = tmp_path / "wide.log"
    log_path.write_text("".join(lines))
    skipped = []
    log = carmen_to_bag.parse_carmen_log(log_path, on_skip=lambda n, why: skipped.append((n, why)))
    assert skipped == [(14, "malformed ROBOTLASER1 line (angular resolution 0.0 and field of view 0.0 give no "
                            "beam spacing)")]
    assert np.array([carmen_log.scan_geometry(s) for s in log.scans]) == pytest.approx(np.tile([start, step], (13, 1)))
    convert_log(log_path, tmp_path / "wide")
    msg = next(read_bag(tmp_path / "wide", ["/scan"])).msg
    assert len(msg.ranges) == 541 and msg.angle_min == pytest.approx(start)
    assert msg.angle_max == pytest.approx(0.75 * np.pi, abs=1e-6)


def test_a_malformed_robotlaser1_line_is_named_and_a_log_with_both_kinds_is_read_from_its_flaser_lines(tmp_path):
    poses = corridor_poses(3)
    good = robotlaser_line(corridor_ranges(poses[0]), poses[0], 10.0)
    tokens = good.split()
    truncated = " ".join(tokens[:-10]) + "\n"  # cut inside the poses
    bad_remissions = " ".join(tokens[:190] + ["x"] + tokens[191:]) + "\n"  # 9 + 181 fields before the count
    log_path = tmp_path / "bad.log"
    log_path.write_text(good + truncated + bad_remissions)
    skipped = []
    log = carmen_to_bag.parse_carmen_log(log_path, on_skip=lambda n, why: skipped.append((n, why)))
    assert len(log.scans) == 1
    assert skipped[0][0] == 2 and skipped[0][1].startswith("malformed ROBOTLASER1 line (truncated")
    assert skipped[1] == (3, "malformed ROBOTLASER1 line (remission count 'x' is not an integer)")
    both = write_log(tmp_path / "both.log", poses)
    with both.open("a") as stream:
        stream.write(good)
    assert carmen_to_bag.parse_carmen_log(both).message == "FLASER"
    assert len(carmen_to_bag.parse_carmen_log(both).scans) == 3


def test_missing_log_is_an_error(tmp_path):
    with pytest.raises(CarmenLogError, match="does not exist"):
        carmen_to_bag.parse_carmen_log(tmp_path / "nope.log.gz")


def test_beam_geometry_follows_carmen():
    assert carmen_to_bag.beam_geometry(180) == pytest.approx((-np.pi / 2, np.pi / 180))
    assert carmen_to_bag.beam_geometry(181) == pytest.approx((-np.pi / 2, np.pi / 180))
    assert carmen_to_bag.beam_geometry(361) == pytest.approx((-np.pi / 2, np.pi / 360))
    assert carmen_to_bag.beam_geometry(91) == pytest.approx((-np.pi / 2, np.pi / 90))


def test_stamps_are_made_increasing_or_synthesised():
    fixed = carmen_to_bag.assign_stamps(np.array([1.0, 2.0, 1.5, 3.0]), period=1.0)
    assert np.all(np.diff(fixed) > 0) and fixed[0] == 1.0 and fixed[3] == 3.0
    assert carmen_to_bag.assign_stamps(np.zeros(4), period=0.5).tolist() == [0.5, 1.0, 1.5, 2.0]


def test_settings_refuse_bad_values():
    with pytest.raises(ValueError, match="resolution must be positive"):
        ConversionSettings(resolution=0.0)
    with pytest.raises(ValueError, match="alpha1..alpha4"):
        ConversionSettings(alphas=(0.1, -1.0, 0.1, 0.1))


# -- timestamps: every problem said out loud -------------------------------------------------------
def stamp_choice(tmp_path, period: float = 0.5, **stamps) -> carmen_log.StampChoice:
    """The stamps and warnings of a 40-scan corridor log with the given stamp columns."""
    log_path = write_log(tmp_path / "stamps.log", corridor_poses(40), **stamps)
    return carmen_log.choose_stamps(carmen_log.parse_carmen_log(log_path).scans, period)


def good_stamps(count: int = 40) -> np.ndarray:
    return 100.0 + 0.2 * np.arange(count)


def test_clean_stamps_are_used_as_they_are_without_a_warning(tmp_path):
    choice = stamp_choice(tmp_path, stamps=good_stamps())
    assert choice.source == "FLASER ipc_timestamp" and choice.warnings == ()
    assert choice.stamps == pytest.approx(good_stamps())


def test_missing_stamps_everywhere_fall_back_to_the_period_and_say_so(tmp_path):
    choice = stamp_choice(tmp_path, stamps=np.zeros(40))
    assert choice.source == "--period"
    assert choice.stamps == pytest.approx(0.5 * np.arange(1, 41))
    assert choice.warnings[0] == "40 of 40 scans have no FLASER ipc_timestamp (0)"
    assert choice.warnings[-1] == "no usable timestamps: assuming one scan every 0.5 s (--period)"


def test_a_few_missing_or_negative_stamps_are_filled_in_between_their_neighbours(tmp_path):
    stamps = good_stamps()
    stamps[[5, 6]] = 0.0
    stamps[20] = -3.0
    choice = stamp_choice(tmp_path, stamps=stamps)
    assert choice.source == "FLASER ipc_timestamp"
    assert choice.stamps == pytest.approx(good_stamps())  # linear in the scan index between 4 and 7, 19 and 21
    assert choice.warnings == (
        "2 of 40 scans have no FLASER ipc_timestamp (0); filled in linearly between the scans around them",
        "1 of 40 scans have a negative FLASER ipc_timestamp; filled in linearly between the scans around them",
    )


def test_stamps_rounded_to_whole_seconds_are_spread_over_their_second(tmp_path):
    choice = stamp_choice(tmp_path, stamps=np.floor(good_stamps()))  # 5 scans a second, fraction lost
    assert choice.source == "FLASER ipc_timestamp"
    assert choice.warnings == ("40 of 40 FLASER ipc_timestamp values are whole seconds (rounded); "
                               "scans sharing a second are spread evenly over it",)
    assert choice.stamps == pytest.approx(good_stamps())  # 100.0, 100.2, ... exactly as before rounding


def test_stamps_that_step_back_are_nudged_and_counted(tmp_path):
    stamps = good_stamps()
    stamps[10] = stamps[9] - 0.3
    choice = stamp_choice(tmp_path, stamps=stamps)
    assert choice.warnings == ("1 of 39 steps of FLASER ipc_timestamp do not increase (largest step back 0.3 s); "
                               "each moved 1 ms after the one before",)
    assert choice.stamps[10] == pytest.approx(stamps[9] + 1e-3)
    assert np.all(np.diff(choice.stamps) > 0)


def test_a_stamp_far_ahead_of_both_neighbours_is_filled_in_and_its_line_named(tmp_path):
    # One stamp of 1e9 s among 100..108 s made it the clock: every later scan was moved to 1e9 s + 1 ms steps.
    stamps = good_stamps()
    stamps[[0, 12]] = [5e8, 1e9]
    choice = stamp_choice(tmp_path, stamps=stamps)
    assert choice.source == "FLASER ipc_timestamp"
    assert choice.stamps == pytest.approx(good_stamps())
    assert choice.warnings == (
        "2 of 40 scans have a FLASER ipc_timestamp more than 100 median steps ahead of the scans on both sides "
        "(line 2: 500000000.0, line 14: 1000000000.0); filled in linearly between the scans around them",)
    paused = good_stamps()
    paused[20:] += 1e4  # a long pause is not an outlier: the scans after it go on from there
    choice = stamp_choice(tmp_path, stamps=paused)
    assert choice.warnings == () and choice.stamps == pytest.approx(paused)


@pytest.mark.parametrize(("stamps", "period", "bad", "first"), [
    (1e11 + 0.25 * np.arange(6), 1.0, 6, "line 2: 100000000000.0 s"),  # past 2038: no int32 seconds
    (1e-6 * np.array([2, 3, 5, 6, 7, 8]), 1.0, 2, "line 2: 2e-06 s"),  # /map would be logged before time 0
    (np.zeros(6), 1e9, 4, "line 4: 3000000000.0 s"),  # --period from the API, which argparse does not guard
])
def test_stamps_a_bag_cannot_hold_are_refused_before_anything_is_written(tmp_path, capsys, stamps, period, bad, first):
    # They ended in an OverflowError half-way through writing, leaving an .mcap without metadata.yaml.
    log_path = write_log(tmp_path / "far.log", corridor_poses(6), stamps=stamps)
    with pytest.raises(CarmenLogError, match=rf"^{bad} of 6 scan stamps \(.*\) lie outside the 4e-06 to 2147483647 s "
                                             rf"a bag holds, the first at {first}$"):
        convert_log(log_path, tmp_path / "far", settings=ConversionSettings(period=period))
    assert not (tmp_path / "far").exists()
    with pytest.raises(CarmenLogError, match="lie outside"):
        carmen_cv.split_log(log_path, tmp_path / "blocks", 2, settings=ConversionSettings(period=period))
    assert not (tmp_path / "blocks").exists()
    capsys.readouterr()
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "far"), "--period", str(period)]) == 1
    assert capsys.readouterr().err.splitlines()[-1].startswith(f"carmen_to_bag: error: {bad} of 6 scan stamps")


@pytest.mark.parametrize(("option", "value"), [("--period", "1e-9"), ("--period", "nan"), ("--period", "3e9"),
                                               ("--resolution", "1e-7"), ("--resolution", "inf"), ("--resolution", "x")])
def test_a_period_or_resolution_out_of_range_is_refused_naming_it(tmp_path, capsys, option, value):
    log_path = write_log(tmp_path / "ok.log", corridor_poses(6))
    with pytest.raises(SystemExit) as exit_info:
        carmen_to_bag.main([str(log_path), str(tmp_path / "out"), option, value])
    assert exit_info.value.code == 2
    assert f"argument {option}: {value!r} is not a number from " in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_unusable_ipc_stamps_fall_back_to_the_logger_timestamp(tmp_path):
    choice = stamp_choice(tmp_path, stamps=np.zeros(40), logger_stamps=good_stamps())
    assert choice.source == "FLASER logger_timestamp"
    assert choice.stamps == pytest.approx(good_stamps())
    assert choice.warnings == ("40 of 40 scans have no FLASER ipc_timestamp (0)",
                               "FLASER ipc_timestamp not usable: using the times of the FLASER logger_timestamp "
                               "instead")


def test_unusable_flaser_stamps_fall_back_to_the_odom_lines(tmp_path):
    choice = stamp_choice(tmp_path, stamps=np.zeros(40), odom_stamps=good_stamps())
    assert choice.source == "ODOM lines"
    assert choice.stamps == pytest.approx(good_stamps())
    assert choice.warnings[1] == "FLASER logger_timestamp: not usable either (40 zero; the same values as the " \
                                 "FLASER ipc_timestamp)"
    assert choice.warnings[2] == ("FLASER ipc_timestamp not usable: using the times of the ODOM lines (the last "
                                  "ODOM line before each scan) instead")


def test_garbage_odom_times_are_refused_too(tmp_path):
    rng = np.random.default_rng(1)
    garbage = rng.choice([0.0, 4.4e-38, -8290.46, 6.979], size=40)  # what the Orebro log's ODOM lines hold
    choice = stamp_choice(tmp_path, stamps=np.zeros(40), odom_stamps=garbage)
    assert choice.source == "--period"
    assert choice.warnings[2].startswith("ODOM lines: not usable either (")


def test_conversion_prints_each_stamp_warning_on_stderr(tmp_path, capsys):
    stamps = good_stamps()
    stamps[3] = 0.0
    stamps[10] = stamps[9] - 0.3
    log_path = write_log(tmp_path / "warned.log", corridor_poses(40), stamps=stamps)
    assert carmen_to_bag.main([str(log_path), str(tmp_path / "warned")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err == [
        "carmen_to_bag: warning: timestamps: 1 of 40 scans have no FLASER ipc_timestamp (0); filled in linearly "
        "between the scans around them",
        "carmen_to_bag: warning: timestamps: 1 of 38 steps of FLASER ipc_timestamp do not increase (largest step "
        "back 0.3 s); each moved 1 ms after the one before",
    ]
