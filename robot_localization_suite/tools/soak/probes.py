"""The soak's two probes: a DDS monitor of stamps and receive times, and a psutil sampler of each process.

The monitor subscribes to serialized messages (``raw=True``) and reads only the header stamp, so that
its own cost stays small next to the nodes it watches on a loaded machine: every message it takes
begins with a ``std_msgs/Header`` (scan, pose), or with a sequence of stamped transforms (``/tf``).
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Sequence
from typing import Any

from .report import ProcessSeries

__all__ = ["cdr_stamp", "StampMonitor", "ProcessSampler"]

_LITTLE_ENDIAN = (0x01, 0x03)  # CDR_LE, PL_CDR_LE representation identifiers


def cdr_stamp(data: bytes, offset: int = 4) -> float:
    """The ``builtin_interfaces/Time`` at ``offset`` of a CDR-serialized message [s].

    Offset 4 is the header of a message that starts with one (after the 4-byte encapsulation);
    a ``tf2_msgs/TFMessage`` has its first transform's stamp at 8, after the sequence length.
    """
    order = "<" if data[1] in _LITTLE_ENDIAN else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, offset)
    return sec + nanosec * 1e-9


class StampMonitor:
    """Receive time and stamp of every scan, every localizer's pose, and of the ``map -> odom`` each broadcasts.

    Each localizer is started with ``/tf`` remapped to ``/<name>/tf``: it broadcasts ``map -> odom``
    once for every input it handles (estimate or not, as nav2_amcl does), stamped the input's stamp
    plus ``transform_tolerance``, so counting them counts the inputs it processed.

    Lists grow by ``append`` in the executor thread and are read as snapshots by the caller.
    """

    def __init__(self, localizers: Sequence[str]) -> None:
        import rclpy
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import OccupancyGrid
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import LaserScan

        from ...ros.conversions import stamp_to_seconds
        from ...ros.qos import MAP_QOS
        from ...ros.tf import TFMessage

        self.node = rclpy.create_node("rls_soak_monitor")
        self.epoch: float | None = None  # scan_sim's t = 0: the stamp of its map
        self.scans: tuple[list[float], list[float]] = ([], [])  # (receive times, stamps)
        self.poses: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name in localizers}
        self.tf_stamps: dict[str, list[float]] = {name: [] for name in localizers}
        self.has_tf = TFMessage is not None
        # Deep best-effort queues: the monitor must not be the one that drops scans.
        deep = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT)
        reliable = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)

        def on_map(msg: Any) -> None:
            self.epoch = stamp_to_seconds(msg.header.stamp)

        self.node.create_subscription(OccupancyGrid, "/map", on_map, MAP_QOS)
        self.node.create_subscription(LaserScan, "/scan", self._recorder(self.scans), deep, raw=True)
        for name in localizers:
            self.node.create_subscription(PoseWithCovarianceStamped, f"/{name}/pose", self._recorder(self.poses[name]),
                                          reliable, raw=True)
            if TFMessage is not None:
                self.node.create_subscription(TFMessage, f"/{name}/tf", self._tf_recorder(self.tf_stamps[name]),
                                              reliable, raw=True)
        from rclpy.executors import SingleThreadedExecutor

        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._executor.spin, daemon=True, name="soak-monitor")

    @staticmethod
    def _recorder(into: tuple[list[float], list[float]]) -> Any:
        received, stamps = into

        def record(data: bytes) -> None:
            received.append(time.time())
            stamps.append(cdr_stamp(data))

        return record

    @staticmethod
    def _tf_recorder(into: list[float]) -> Any:
        def record(data: bytes) -> None:
            into.append(cdr_stamp(data, 8))

        return record

    def start(self) -> None:
        self._thread.start()

    def save(self, path: Any) -> None:
        """Every receive time and stamp [s], for a closer look: ``scan_*``, ``<name>_pose_*``, ``<name>_tf_stamp``."""
        import numpy as np

        arrays = {"scan_received": self.scans[0], "scan_stamp": self.scans[1], "epoch": [self.epoch or np.nan]}
        for name, (received, stamps) in self.poses.items():
            arrays[f"{name}_pose_received"], arrays[f"{name}_pose_stamp"] = received, stamps
            arrays[f"{name}_tf_stamp"] = self.tf_stamps[name]
        data: dict[str, Any] = {key: np.asarray(value, dtype=np.float64) for key, value in arrays.items()}
        np.savez_compressed(path, **data)

    def stop(self) -> None:
        """Stop receiving; what was received stays readable. :meth:`close` destroys the node."""
        # Stop spinning before the node goes: a spinning thread left at exit aborts the interpreter.
        self._executor.shutdown(timeout_sec=2.0)
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def close(self) -> None:
        """Destroy the node (the middleware's part of the teardown, which can hang: ros/stopping.py)."""
        self.node.destroy_node()


class ProcessSampler:
    """RSS and CPU of named processes, one sample per call.

    A process counts with its children (a node's helpers), except those sampled under their own
    name: the nodes are children of this process, which is sampled alone.
    """

    def __init__(self, pids: dict[str, int]) -> None:
        import psutil

        self._psutil = psutil
        self.series = {name: ProcessSeries(name, pid) for name, pid in pids.items()}
        self._procs = {name: psutil.Process(pid) for name, pid in pids.items()}
        self._tracked = set(pids.values())
        self._last: dict[str, tuple[float, float]] = {}
        for name in pids:
            self._read(name)  # the CPU baseline

    def _read(self, name: str) -> tuple[float, float] | None:
        """(RSS [MB], CPU [% of one core] since the last reading) of the process and its children; None once gone."""
        psutil = self._psutil
        try:
            proc = self._procs[name]
            family = [proc]
            for child in proc.children():
                if child.pid not in self._tracked:
                    family += [child, *child.children(recursive=True)]
            rss = cpu = 0.0
            for member in family:
                with member.oneshot():
                    rss += member.memory_info().rss
                    times = member.cpu_times()
                    cpu += times.user + times.system
        except (psutil.NoSuchProcess, psutil.ZombieProcess, psutil.AccessDenied):
            return None
        now = time.monotonic()
        previous = self._last.get(name)
        self._last[name] = (now, cpu)
        percent = float("nan") if previous is None else 100.0 * (cpu - previous[1]) / max(now - previous[0], 1e-9)
        return rss / 2**20, percent

    def sample(self, t: float) -> None:
        """Append a sample at ``t`` [s since the soak began] to every process still running."""
        for name, series in self.series.items():
            reading = self._read(name)
            if reading is None:
                continue
            series.t.append(t)
            series.rss_mb.append(reading[0])
            series.cpu_percent.append(reading[1])
