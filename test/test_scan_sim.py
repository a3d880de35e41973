"""scan_sim: every topic over real DDS to another process, cmd_vel robustness, recorded bags.

The node runs as a subprocess (``python -m robot_localization_suite.nodes.scan_sim``)
with the loopback DDS environment conftest.py set; the test subscribes with
its own rclpy context.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml

from robot_localization_suite.core.grid_map import GridMap, load_map_yaml
from robot_localization_suite.core.se2 import quaternion_to_yaw
from robot_localization_suite.core.sim.scenario_yaml import load_scenario
from robot_localization_suite.core.sim.settings import ScanSimSettings, build_scenario
from robot_localization_suite.core.sim.simulator import Simulator
from robot_localization_suite.nodes import scan_sim
from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.ros.context_node import ContextNode

ROOT = Path(__file__).resolve().parent.parent
KIDNAP_BAGS = ("office_kidnap", "floor_kidnap", "corridor_kidnap")


def write_world(folder: Path, *, duration: float = 8.0, camera: bool = True) -> Path:
    """A 6 m x 4 m room with a pillar, and a scenario driving in it; returns the scenario path."""
    data = np.zeros((80, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[30:40, 80:90] = 100  # pillar at x 4.0..4.5, y 1.5..2.0
    GridMap(data, 0.05, (0.0, 0.0)).save(folder / "room.yaml")
    scenario = {
        "map": "room.yaml",
        "seed": 3,
        "duration": duration,
        "start": [1.0, 1.0, 0.0],
        "motion": {"segments": [{"v": 0.3, "w": 0.1, "duration": 4.0}, {"v": 0.0, "w": 0.5, "duration": 4.0}]},
        "kidnappings": [{"time": 2.0, "pose": [2.0, 3.0, -1.0]}],
        "people": [{"radius": 0.25, "speed": 0.5, "waypoints": [[1.0, 0.5], [5.0, 0.5]]}],  # clear of the robot's path
        "laser": {"beams": 120, "fov_deg": 270.0, "range_max": 8.0, "rate_hz": 10.0},
    }
    if camera:
        scenario["camera"] = {"hfov_deg": 60.0, "width": 32, "height": 24, "rate_hz": 5.0}
    path = folder / "room_scenario.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path


def start_scan_sim(*ros_args: str) -> subprocess.Popen:
    env = dict(os.environ)  # conftest.py: loopback DDS and this run's ROS_DOMAIN_ID
    env["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"
    env["PYTHONUNBUFFERED"] = "1"
    return subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.nodes.scan_sim", "--ros-args", *ros_args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def stop(process: subprocess.Popen) -> str:
    if process.poll() is None:
        process.terminate()
    try:
        output, _ = process.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        output, _ = process.communicate()
    return output


class Probe(ContextNode):
    """A subscriber node in its own rclpy context."""

    def __init__(self) -> None:
        super().__init__("scan_sim_probe")
        self.received: dict[str, list] = {}

    def subscribe(self, msg_type: type, topic: str, qos) -> None:
        self.node.create_subscription(msg_type, topic, lambda msg: self.received.setdefault(topic, []).append(msg), qos)



@pytest.fixture
def probe():
    p = Probe()
    yield p
    p.close()


def test_live_scan_sim_publishes_every_topic_and_exits_at_the_end(tmp_path: Path, probe: Probe) -> None:
    from nav_msgs.msg import OccupancyGrid, Odometry
    from sensor_msgs.msg import Image, LaserScan

    from robot_localization_suite.ros.qos import MAP_QOS, SENSOR_QOS

    scenario_path = write_world(tmp_path)
    process = start_scan_sim("-p", f"scenario:={scenario_path}")
    try:
        probe.subscribe(OccupancyGrid, "map", MAP_QOS)
        for msg_type, topic in (
            (LaserScan, "scan"),
            (Odometry, "odom"),
            (Odometry, "ground_truth"),
            (Image, "camera/image_raw"),
        ):
            probe.subscribe(msg_type, topic, SENSOR_QOS)
        topics = ("map", "scan", "odom", "ground_truth", "camera/image_raw")
        needed = {"map": 1, "scan": 5, "odom": 5, "ground_truth": 5, "camera/image_raw": 2}
        ok = probe.spin_until(lambda: all(len(probe.received.get(t, [])) >= needed[t] for t in topics), timeout=40.0)
        assert ok, f"received only { ({t: len(v) for t, v in probe.received.items()}) }; node output:\n{stop(process)}"
        # The scenario lasts 8 s simulated at real time: then the node exits by itself with code 0.
        output, _ = process.communicate(timeout=30)
        assert process.returncode == 0, output
    finally:
        output = stop(process) if process.returncode is None else output
    assert "ended at 8.0 s simulated, exiting" in output
    assert "kidnapped at t = 2.0 s" in output

    grid = probe.received["map"][0]
    assert (grid.info.width, grid.info.height, grid.info.resolution) == (120, 80, pytest.approx(0.05))
    assert grid.header.frame_id == "map"
    scan = probe.received["scan"][-1]
    assert scan.header.frame_id == "laser" and len(scan.ranges) == 120
    assert scan.angle_min == pytest.approx(-math.radians(135.0))
    assert scan.angle_increment == pytest.approx(math.radians(270.0) / 119)
    assert scan.range_max == pytest.approx(8.0)
    ranges = np.asarray(scan.ranges)
    assert np.isfinite(ranges).mean() > 0.9 and np.all(ranges[np.isfinite(ranges)] < 8.0)
    odom = probe.received["odom"][-1]
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "base_link")
    truth = probe.received["ground_truth"]
    assert (truth[-1].header.frame_id, truth[-1].child_frame_id) == ("map", "base_link")
    # Same stamps on ground truth and scans; ground truth stays on the free floor of the room.
    scan_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in probe.received["scan"]}
    truth_stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in truth}
    assert scan_stamps & truth_stamps
    xs = [m.pose.pose.position.x for m in truth]
    assert all(0.3 < x < 5.7 for x in xs)
    image = probe.received["camera/image_raw"][-1]
    assert (image.width, image.height, image.encoding, image.header.frame_id) == (32, 24, "mono8", "camera")
    assert len(image.data) == 32 * 24


def test_bad_cmd_vel_is_clamped_and_logged_never_fatal(tmp_path: Path, probe: Probe) -> None:
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry

    from robot_localization_suite.ros.qos import SENSOR_QOS

    write_world(tmp_path)
    process = start_scan_sim(
        "-p", f"map_yaml:={tmp_path / 'room.yaml'}",
        "-p", "start_x:=2.0", "-p", "start_y:=2.0",
        "-p", "max_linear:=0.5", "-p", "max_angular:=1.0",
        "-p", "beams:=60",
    )  # fmt: skip
    try:
        probe.subscribe(Odometry, "ground_truth", SENSOR_QOS)
        publisher = probe.node.create_publisher(Twist, "cmd_vel", 10)
        assert probe.spin_until(lambda: len(probe.received.get("ground_truth", [])) >= 3, timeout=40.0), stop(process)
        assert probe.spin_until(lambda: publisher.get_subscription_count() > 0, timeout=20.0)

        def drive(linear: float, angular: float, seconds: float = 1.0) -> list[tuple[float, float]]:
            """Send the command repeatedly; the true velocities ground_truth reports meanwhile."""
            message = Twist()
            message.linear.x, message.angular.z = linear, angular
            probe.received["ground_truth"] = []
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                publisher.publish(message)
                probe.spin_until(lambda: False, timeout=0.1)
            return [(m.twist.twist.linear.x, m.twist.twist.angular.z) for m in probe.received["ground_truth"]]

        speeds = drive(1e9, -math.inf)
        assert (0.5, -1.0) in speeds, speeds  # clamped to max_linear, max_angular
        assert all(abs(v) <= 0.5 and abs(w) <= 1.0 for v, w in speeds)
        speeds = drive(math.nan, 0.3)
        assert (0.0, 0.3) in speeds, speeds  # NaN stops the robot
        assert all(math.isfinite(v) and math.isfinite(w) for v, w in speeds)
        assert process.poll() is None, stop(process)
    finally:
        output = stop(process)
    assert "bad cmd_vel" in output
    assert "linear.x is NaN" in output and "angular.z -inf clamped to +-1.0" in output
    assert "Traceback" not in output


def test_sanitize_command() -> None:
    assert scan_sim.sanitize_command(0.2, -0.1, 1.0, 2.0) == (0.2, -0.1, [], [])
    v, w, not_a_number, clamped = scan_sim.sanitize_command(math.nan, 1e9, 1.0, 2.0)
    assert (v, w) == (0.0, 2.0)
    assert not_a_number == ["linear.x is NaN (stopping)"] and clamped == ["angular.z 1000000000.0 clamped to +-2.0"]
    v, w, _, clamped = scan_sim.sanitize_command(-math.inf, -3.0, 1.0, 2.0)
    assert (v, w) == (-1.0, -2.0) and len(clamped) == 2


# -- record mode ---------------------------------------------------------------------------------
def test_record_writes_a_bag_that_reads_back_message_for_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import rclpy

    def no_init(*args, **kwargs):
        raise AssertionError("recording must not start rclpy (no DDS participant)")

    monkeypatch.setattr(rclpy, "init", no_init)

    scenario_path = write_world(tmp_path, duration=3.0)
    bag = tmp_path / "bag"
    argv = ["scan_sim", "--record", str(bag), "--ros-args", "-p", f"scenario:={scenario_path}", "-p", "seed:=5"]
    assert scan_sim.main(argv) == 0
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))

    messages = list(read_bag(bag))
    expected_steps = list(Simulator(load_scenario(scenario_path), seed=5).run())
    per_step = ["/odom", "/tf", "/ground_truth", "/scan"]
    expected_topics = ["/map", "/tf_static"]
    for step in expected_steps:
        expected_topics += per_step + (["/camera/image_raw"] if step.image is not None else [])
    assert [m.topic for m in messages] == expected_topics
    assert len(expected_steps) == 31 and expected_topics.count("/camera/image_raw") == 16

    grid = messages[0].msg
    assert np.array_equal(
        np.asarray(grid.data, dtype=np.int8).reshape(80, 120), load_scenario(scenario_path).grid_map.data
    )
    (mount,) = messages[1].msg.transforms  # the scenario's laser mount, once
    assert (mount.header.frame_id, mount.child_frame_id) == ("base_link", "laser")
    # The clock starts at record_epoch (2025-01-01), not 1970.
    epoch_ns = ScanSimSettings().record_epoch * 1_000_000_000
    assert epoch_ns == 1_735_689_600 * 1_000_000_000
    assert messages[0].stamp_ns == messages[1].stamp_ns == epoch_ns
    assert (grid.header.stamp.sec, grid.header.stamp.nanosec) == (1_735_689_600, 0)
    stream = iter(messages[2:])
    for step in expected_steps:
        stamp_ns = epoch_ns + int(round(step.time * 1e9))
        odom, odom_tf, truth, scan = next(stream), next(stream), next(stream), next(stream)
        (transform,) = odom_tf.msg.transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("odom", "base_link")
        assert odom_tf.stamp_ns == stamp_ns
        assert transform.transform.translation.x == odom.msg.pose.pose.position.x
        assert transform.transform.rotation.z == odom.msg.pose.pose.orientation.z
        for item, pose in ((odom, step.odom_pose), (truth, step.true_pose)):
            assert item.stamp_ns == stamp_ns
            p = item.msg.pose.pose
            yaw = quaternion_to_yaw(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
            assert np.allclose([p.position.x, p.position.y], pose[:2], atol=1e-12)
            assert math.isclose(math.remainder(yaw - pose[2], 2 * math.pi), 0.0, abs_tol=1e-9)
        assert scan.stamp_ns == stamp_ns
        assert np.array_equal(np.asarray(scan.msg.ranges, dtype=np.float32), step.ranges)
        if step.image is not None:
            image = next(stream)
            assert np.array_equal(np.frombuffer(bytes(image.msg.data), np.uint8).reshape(24, 32), step.image)
    # The kidnapping shows in ground truth only.
    truth = [m.msg.pose.pose.position for m in messages if m.topic == "/ground_truth"]
    assert (truth[20].x, truth[20].y) == pytest.approx((2.0, 3.0))


@contextmanager
def reaped(process: subprocess.Popen) -> Iterator[subprocess.Popen]:
    """The process, killed and reaped on the way out if a test left it running."""
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_running_node_stopped_by_a_signal_exits_0_without_a_traceback(tmp_path: Path, signum: signal.Signals) -> None:
    """Ctrl-C or a launcher's SIGTERM ends a spinning node's loop: exit 0, no traceback, no stack dump."""
    scenario_path = write_world(tmp_path, duration=3600.0, camera=False)
    with reaped(subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.nodes.scan_sim", "--ros-args",
         "-r", "__node:=stopped_sim", "-r", "scan:=/stopped_sim/scan", "-p", f"scenario:={scenario_path}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )) as process:
        assert process.stderr is not None
        started = process.stderr.readline()  # the node's first log line (ROS logs go to stderr): it spins
        assert "simulating" in started, started
        time.sleep(0.5)  # publishing
        process.send_signal(signum)
        _, err = process.communicate(timeout=30)
    assert process.returncode == 0, err
    assert "Traceback" not in err and "Timeout" not in err, err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_record_stopped_by_a_signal_finishes_its_bag_and_exits_0(tmp_path: Path, signum: signal.Signals) -> None:
    """Ctrl-C or a service manager's stop: a complete bag of the steps so far, one line, no traceback."""
    scenario_path = write_world(tmp_path, duration=3600.0, camera=False)  # ~20 s of recording: stopped long before
    bag = tmp_path / "bag"
    with reaped(subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.nodes.scan_sim", "--record", str(bag),
         "--ros-args", "-p", f"scenario:={scenario_path}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )) as process:
        deadline = time.monotonic() + 120
        # Stop it once it has written a few steps (chunks of compressed messages reach the file as it goes).
        while sum(p.stat().st_size for p in bag.glob("*.mcap")) < 20_000:
            assert process.poll() is None and time.monotonic() < deadline, process.communicate()
            time.sleep(0.05)
        process.send_signal(signum)
        out, err = process.communicate(timeout=60)
    assert process.returncode == 0, err
    assert "Traceback" not in err and err == ""
    [line] = out.splitlines()
    assert line.startswith(f"scan_sim: stopped early by {signum.name} at ") and "of 3600.0 s simulated" in line
    written = int(line.split(" wrote ")[1].split()[0])
    reading = read_bag(bag)  # footer, summary and metadata.yaml: no recovery needed
    topics = [m.topic for m in reading]
    assert reading.recovery is None and (bag / "metadata.yaml").is_file()
    assert len(topics) == written > 4 and topics[0] == "/map"
    # /map and /tf_static once, then odom, its /tf, ground truth and the scan of each step
    assert topics.count("/odom") == topics.count("/tf") == topics.count("/ground_truth") == topics.count("/scan") \
        == (written - 2) // 4


def test_record_refuses_bad_input_with_a_clear_message(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_world(tmp_path, camera=False)
    data = yaml.safe_load(path.read_text())
    data["start"] = [0.02, 1.0, 0.0]
    path.write_text(yaml.safe_dump(data))
    assert scan_sim.main(["scan_sim", "--record", str(tmp_path / "b"), "--ros-args", "-p", f"scenario:={path}"]) == 2
    assert "start pose [0.020, 1.000, 0.000] lies in an obstacle" in capsys.readouterr().err
    assert scan_sim.main(["scan_sim", "--record", str(tmp_path / "c"), "--ros-args", "-p", "speed:=fast"]) == 2
    assert "parameter speed must be a number, got 'fast'" in capsys.readouterr().err
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


def test_record_under_a_plain_file_is_refused_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_world(tmp_path, duration=1.0, camera=False)
    (tmp_path / "afile").write_text("")
    for bag in (tmp_path / "afile" / "bag", tmp_path / "afile" / "sub" / "bag"):
        assert scan_sim.main(["scan_sim", "--record", str(bag), "--ros-args", "-p", f"scenario:={path}"]) == 2
        assert f"--record {str(bag)!r}: {str(tmp_path / 'afile')!r} is a file, not a folder" in capsys.readouterr().err


def test_settings_from_args_read_params_files_and_overrides(tmp_path: Path) -> None:
    settings = scan_sim.settings_from_args(
        ["x", "--ros-args", "--params-file", str(ROOT / "config" / "scan_sim.yaml"), "-p", "beams:=90", "-p", "speed:=2"]
    )
    assert settings.beams == 90 and settings.speed == 2.0 and settings.exit_at_end is True
    with pytest.raises(Exception, match="unknown parameter\\(s\\) 'beam'"):
        scan_sim.settings_from_args(["x", "--ros-args", "-p", "beam:=90"])
    with pytest.raises(Exception, match=r"parameter fov_deg must be in \[-1..360\] deg, got 720.0"):
        scan_sim.settings_from_args(["x", "--ros-args", "-p", "fov_deg:=720.0"])
    path = write_world(tmp_path, camera=False)
    settings = ScanSimSettings(scenario=str(path), beams=45, range_noise_model="uniform")
    scenario = build_scenario(settings, path)
    assert scenario.laser.beams == 45 and scenario.laser.range_noise_model == "uniform"
    assert scenario.laser.fov_deg == 270.0  # not overridden: the scenario's


def test_help_lists_parameters_and_record(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        scan_sim.main(["scan_sim", "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "--record DIR" in text and "scenario = ''" in text and "cmd_vel" in text
    assert "fov_deg = -1.0 [deg] [-1..360]: laser field of view" in text


# -- the committed bags -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", KIDNAP_BAGS)
def test_committed_bags_match_their_scenarios(name: str) -> None:
    from rosbags.rosbag2 import Reader

    bag = ROOT / "bags" / name
    size = sum(p.stat().st_size for p in bag.iterdir())
    assert size <= 4_000_000
    scenario = load_scenario(ROOT / "config" / "scenarios" / f"{name}.yaml")
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {
        "/map": 1,
        "/tf_static": 1,
        "/odom": scenario.step_count,
        "/tf": scenario.step_count,
        "/ground_truth": scenario.step_count,
        "/scan": scenario.step_count,
    }
    # recorded from the simulated epoch, not from 1970 (issue 18)
    (first,) = read_bag(bag, ["/map"])
    assert first.stamp_ns == ScanSimSettings().record_epoch * 1_000_000_000
    # The first seconds are exactly what the simulator produces now.
    simulator = Simulator(scenario)
    scans = (m for m in read_bag(bag, ["/scan"]))
    for _ in range(30):
        step = simulator.step()
        assert np.array_equal(np.asarray(next(scans).msg.ranges, dtype=np.float32), step.ranges)


# -- world events: a map change and a reinitialization request ------------------------------------------
def write_world_with_events(folder: Path, *, duration: float = 8.0, change_at: float = 2.0,
                            reinitialize_at: float = 4.0) -> Path:
    """The room of :func:`write_world` whose pillar moves at ``change_at`` (map change), and a reinitialization
    request at ``reinitialize_at`` [s]."""
    path = write_world(folder, duration=duration, camera=False)
    data = np.zeros((80, 120), dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = 100
    data[50:60, 80:90] = 100  # the pillar moved 1 m north: x 4.0..4.5, y 2.5..3.0
    GridMap(data, 0.05, (0.0, 0.0)).save(folder / "room_moved.yaml")
    scenario = yaml.safe_load(path.read_text())
    scenario["kidnappings"] = []  # the kidnap pose (2, 3) would be next to the moved pillar; not needed here
    scenario["map_changes"] = [{"time": change_at, "map": "room_moved.yaml"}]
    scenario["reinitializations"] = [{"time": reinitialize_at}]
    path.write_text(yaml.safe_dump(scenario))
    return path


def test_record_writes_the_new_map_and_the_reinitialization_request_at_their_step(tmp_path: Path) -> None:
    scenario_path = write_world_with_events(tmp_path, duration=5.0)
    bag = tmp_path / "bag"
    assert scan_sim.main(["scan_sim", "--record", str(bag), "--ros-args", "-p", f"scenario:={scenario_path}"]) == 0
    messages = list(read_bag(bag))
    epoch = ScanSimSettings().record_epoch  # whole seconds: the clock's t = 0
    epoch_ns = epoch * 1_000_000_000
    maps = [m for m in messages if m.topic == "/map"]
    assert [m.stamp_ns for m in maps] == [epoch_ns, epoch_ns + 2_000_000_000]
    moved = load_map_yaml(tmp_path / "room_moved.yaml").data
    assert np.array_equal(np.asarray(maps[1].msg.data, dtype=np.int8).reshape(80, 120), moved)
    assert maps[1].msg.header.stamp.sec == epoch + 2 and maps[1].msg.header.frame_id == "map"
    (request,) = [m for m in messages if m.topic == "/operator/reinitialize_global_localization"]
    assert request.stamp_ns == epoch_ns + 4_000_000_000
    assert (request.msg.stamp.sec, request.msg.stamp.nanosec, request.msg.frame_id) == (epoch + 4, 0, "map")
    # Each event comes before the scan of its step, the first scan that sees the changed world.
    topics = [m.topic for m in messages]
    step_20 = [m.topic for m in messages if m.stamp_ns == epoch_ns + 2_000_000_000]
    assert step_20.index("/map") < step_20.index("/scan")
    step_40 = [m.topic for m in messages if m.stamp_ns == epoch_ns + 4_000_000_000]
    assert step_40.index("/operator/reinitialize_global_localization") < step_40.index("/scan")
    assert topics.count("/scan") == 51


def test_live_scan_sim_publishes_the_new_map_and_calls_every_reinitialization_service(
    tmp_path: Path, probe: Probe
) -> None:
    from nav_msgs.msg import OccupancyGrid
    from std_msgs.msg import Header
    from std_srvs.srv import Empty

    from robot_localization_suite.ros.qos import MAP_QOS, RELIABLE_QOS

    calls: list[str] = []

    def served(name: str):
        def handle(request: Empty.Request, response: Empty.Response) -> Empty.Response:
            calls.append(name)
            return response
        return handle

    for name in ("fake_mcl", "fake_pil"):
        probe.node.create_service(Empty, f"{name}/reinitialize_global_localization", served(name))
    probe.subscribe(OccupancyGrid, "map", MAP_QOS)
    probe.subscribe(Header, "operator/reinitialize_global_localization", RELIABLE_QOS)
    # Late events: discovery on a loaded machine may take seconds, and the services must be known by then.
    scenario_path = write_world_with_events(tmp_path, duration=10.0, change_at=6.0, reinitialize_at=8.0)
    moved = load_map_yaml(tmp_path / "room_moved.yaml").data

    def grids() -> list[np.ndarray]:
        return [np.asarray(m.data, dtype=np.int8).reshape(80, 120) for m in probe.received.get("map", [])]

    process = start_scan_sim("-p", f"scenario:={scenario_path}")
    try:
        ok = probe.spin_until(lambda: any(np.array_equal(g, moved) for g in grids()) and len(calls) >= 2,
                              timeout=60.0)
        assert ok, f"maps {len(grids())}, calls {calls}; node output:\n{stop(process)}"
        probe.spin_for(0.5)
    finally:
        output = stop(process)
    assert sorted(calls) == ["fake_mcl", "fake_pil"]  # once each
    # The changed map is the last one; one received before it (depth 1: only if discovery was quick) is the first.
    *before, last = grids()
    assert np.array_equal(last, moved)
    assert all(not np.array_equal(g, moved) for g in before) and len(before) <= 1
    assert len(probe.received["operator/reinitialize_global_localization"]) == 1
    assert "the map changed at t = 6.0 s" in output
    assert "/fake_mcl/reinitialize_global_localization" in output and "/fake_pil/reinitialize_global_localization" in output


def test_a_late_subscriber_gets_the_changed_map(tmp_path: Path, probe: Probe) -> None:
    """/map is transient local with depth 1: a node started after the change gets the new map only."""
    from nav_msgs.msg import OccupancyGrid

    from robot_localization_suite.ros.qos import MAP_QOS

    scenario_path = write_world_with_events(tmp_path, duration=30.0)
    process = start_scan_sim("-p", f"scenario:={scenario_path}")
    try:
        assert process.stdout is not None
        for line in process.stdout:  # ends when the node exits (30 s): bounded
            if "the map changed at t = 2.0 s" in line:
                break
        else:
            raise AssertionError(f"scan_sim never changed the map:\n{stop(process)}")
        time.sleep(0.5)  # the publication itself follows the log line
        probe.subscribe(OccupancyGrid, "map", MAP_QOS)
        ok = probe.spin_until(lambda: len(probe.received.get("map", [])) >= 1, timeout=20.0)
        assert ok, f"no map; node output:\n{stop(process)}"
        probe.spin_for(0.5)
    finally:
        stop(process)
    moved = load_map_yaml(tmp_path / "room_moved.yaml").data
    maps = probe.received["map"]
    assert len(maps) == 1 and np.array_equal(np.asarray(maps[0].data, dtype=np.int8).reshape(80, 120), moved)


def test_the_committed_map_change_bag_matches_its_scenario() -> None:
    """bags/office_mapchange: both events where the scenario puts them, every scan what the simulator makes now."""
    from rosbags.rosbag2 import Reader

    bag = ROOT / "bags" / "office_mapchange"
    assert sum(p.stat().st_size for p in bag.iterdir()) <= 4_000_000
    scenario = load_scenario(ROOT / "config" / "scenarios" / "office_mapchange.yaml")
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    steps = scenario.step_count
    assert counts == {"/map": 2, "/tf_static": 1, "/odom": steps, "/tf": steps, "/ground_truth": steps, "/scan": steps,
                      "/operator/reinitialize_global_localization": 1}
    change, request = scenario.map_changes[0], scenario.reinitializations[0]
    maps = [m for m in read_bag(bag, ["/map"])]
    epoch_ns = ScanSimSettings().record_epoch * 1_000_000_000
    assert [m.stamp_ns - epoch_ns for m in maps] == [0, scenario.event_step(change.time) * 100_000_000]
    assert np.array_equal(np.asarray(maps[1].msg.data, dtype=np.int8).reshape(400, 400), change.grid_map.data)
    (item,) = read_bag(bag, ["/operator/reinitialize_global_localization"])
    assert item.stamp_ns - epoch_ns == scenario.event_step(request.time) * 100_000_000
    simulator = Simulator(scenario)
    for message, step in zip(read_bag(bag, ["/scan"]), simulator.run(), strict=True):
        assert np.array_equal(np.asarray(message.msg.ranges, dtype=np.float32), step.ranges)
