"""A demo run's topics, tapped once and handed to sinks: the run's MCAP recording, the live Foxglove server.

:class:`RunTap` subscribes to the run's topics (:func:`run_topics`) as serialized CDR (rclpy ``raw``
subscriptions: nothing is decoded but ``/odom``, ``/ground_truth`` and ``/tf``) and gives each message
to every sink as ``(topic, type name, CDR bytes, receive time [ns])``. The localizers each publish
``map -> odom`` on ``/tf``: several parents of one frame, which a 3-D view cannot draw, so those
transforms are left out and the tap adds the true ``map -> odom`` (ground truth composed with the
inverse odometry at the same stamp, :func:`.tf.map_to_odom`) instead; each localizer's estimate is on
its own ``/<name>/pose``. :class:`RunRecording` writes the sinks' messages with :class:`.bag.BagWriter`.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geometry_msgs.msg import PointStamped
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from .bag import BagWriter, bag_bytes, message_class
from .conversions import odometry_from_msg, seconds_to_stamp
from .qos import MAP_QOS, POSE_QOS, RELIABLE_QOS, SENSOR_QOS, TF_QOS, TF_STATIC_QOS
from .tf import TFMessage, map_to_odom, tf_message, transform_to_msg

__all__ = ["ERROR_TYPE", "RecordedTopic", "RunRecording", "RunTap", "Sink", "TrueMapToOdom", "error_message",
           "error_topic", "extra_outputs", "run_topics"]

# (topic, type name, CDR bytes, log time [ns])
Sink = Callable[[str, str, bytes, int], None]

# Estimates and candidates kept while the writer is busy (their publishers are reliable).
_DEEP = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
_POSES = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=POSE_QOS.reliability,
                    durability=POSE_QOS.durability)
_EXTRA = re.compile(r"^~/(\w+) \((\w+)/(\w+)")
# Each estimate's error against the ground truth at its stamp, as the demo's monitor scores it:
# point.x the position error [m], point.y the heading error [deg], header.stamp the estimate's.
ERROR_TYPE = "geometry_msgs/msg/PointStamped"


def error_topic(localizer: str) -> str:
    """The topic of a localizer's scored errors in a recording (written by the demo or the benchmark, not a node)."""
    return f"/evaluation/{localizer}/error"


def error_message(stamp: float, position_error_m: float, heading_error_rad: float) -> bytes:
    """One scored estimate as serialized :data:`ERROR_TYPE` (see the comment there)."""
    msg = PointStamped()
    msg.header.stamp = seconds_to_stamp(stamp)
    msg.point.x, msg.point.y = float(position_error_m), math.degrees(float(heading_error_rad))
    return serialize_message(msg)


@dataclass(frozen=True)
class RecordedTopic:
    """A topic of the run: its name, its type (``pkg/msg/Name``) and the QoS that matches its publisher."""

    name: str
    type_name: str
    qos: QoSProfile


def extra_outputs(outputs: Sequence[str]) -> list[tuple[str, str]]:
    """``(suffix, pkg/msg/Name)`` of a plugin's extra outputs as its ``outputs`` describe them (``~/boxes (...)``)."""
    found = []
    for text in outputs:
        match = _EXTRA.match(text)
        if match:
            found.append((match.group(1), f"{match.group(2)}/msg/{match.group(3)}"))
    return found


def run_topics(localizers: Sequence[str], *, camera: bool) -> list[RecordedTopic]:
    """What a demo run records and serves: scan_sim's outputs, then each localizer's pose, candidates, extras."""
    from ..registry import PLUGINS

    topics = [
        RecordedTopic("/map", "nav_msgs/msg/OccupancyGrid", MAP_QOS),
        RecordedTopic("/scan", "sensor_msgs/msg/LaserScan", SENSOR_QOS),
        RecordedTopic("/odom", "nav_msgs/msg/Odometry", RELIABLE_QOS),
        RecordedTopic("/ground_truth", "nav_msgs/msg/Odometry", RELIABLE_QOS),
        RecordedTopic("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", _DEEP),
    ]
    if TFMessage is not None:
        topics += [RecordedTopic("/tf", "tf2_msgs/msg/TFMessage", TF_QOS),
                   RecordedTopic("/tf_static", "tf2_msgs/msg/TFMessage", TF_STATIC_QOS)]
    if camera:
        topics.append(RecordedTopic("/camera/image_raw", "sensor_msgs/msg/Image", SENSOR_QOS))
    for name in localizers:
        topics += [RecordedTopic(f"/{name}/pose", "geometry_msgs/msg/PoseWithCovarianceStamped", _POSES),
                   RecordedTopic(f"/{name}/candidates", "geometry_msgs/msg/PoseArray", _DEEP)]
        plugin = PLUGINS.get(name)
        for suffix, type_name in extra_outputs(plugin.outputs if plugin is not None else ()):
            topics.append(RecordedTopic(f"/{name}/{suffix}", type_name, _DEEP))
    return topics


class RunTap:
    """Subscribes ``node`` to ``topics`` and hands every message to each of ``sinks`` (see the module docstring)."""

    def __init__(self, node: Any, topics: Sequence[RecordedTopic], sinks: Sequence[Sink]) -> None:
        from nav_msgs.msg import Odometry

        self.sinks = list(sinks)
        self.counts: dict[str, int] = {}
        self._odometry_class = Odometry
        self._true_map_to_odom = TrueMapToOdom()
        self._lock = threading.Lock()
        for topic in topics:
            node.create_subscription(message_class(topic.type_name), topic.name, self._callback(topic), topic.qos,
                                     raw=True)

    def _callback(self, topic: RecordedTopic) -> Callable[[bytes], None]:
        if topic.name == "/tf":
            return lambda data: self._on_tf(topic, data)
        if topic.name in ("/odom", "/ground_truth"):
            return lambda data: self._on_odometry(topic, data)
        return lambda data: self.emit(topic.name, topic.type_name, data)

    def emit(self, topic: str, type_name: str, data: bytes, log_time_ns: int | None = None) -> None:
        """Give one message to every sink (the receive time when ``log_time_ns`` is None)."""
        stamp = time.time_ns() if log_time_ns is None else log_time_ns
        with self._lock:
            self.counts[topic] = self.counts.get(topic, 0) + 1
            for sink in self.sinks:
                sink(topic, type_name, data, stamp)

    def _on_tf(self, topic: RecordedTopic, data: bytes) -> None:
        msg = deserialize_message(data, TFMessage)
        kept = [t for t in msg.transforms if t.child_frame_id.lstrip("/") != self._true_map_to_odom.odom_frame]
        if len(kept) == len(msg.transforms):
            self.emit(topic.name, topic.type_name, data)
        elif kept:
            self.emit(topic.name, topic.type_name, serialize_message(tf_message(kept)))

    def _on_odometry(self, topic: RecordedTopic, data: bytes) -> None:
        self.emit(topic.name, topic.type_name, data)
        if TFMessage is None:
            return
        msg = deserialize_message(data, self._odometry_class)
        transform = self._true_map_to_odom.add(msg, truth=topic.name == "/ground_truth")
        if transform is not None:
            self.emit("/tf", "tf2_msgs/msg/TFMessage", serialize_message(tf_message([transform])))


class TrueMapToOdom:
    """Pairs odometry and ground truth of the same stamp into the true ``map -> odom`` (TransformStamped)."""

    def __init__(self) -> None:
        self.odom_frame = "odom"
        self._odom: dict[int, tuple[str, Any]] = {}  # stamp [ns] -> (odom frame, odom -> base pose)

    def add(self, msg: Any, *, truth: bool) -> Any:
        """An ``nav_msgs/Odometry`` of odometry (``truth`` False) or of ground truth; the transform once both came."""
        seconds, pose = odometry_from_msg(msg)
        key = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if not truth:
            self.odom_frame = msg.header.frame_id.lstrip("/") or self.odom_frame
            self._odom[key] = (self.odom_frame, pose)
            if len(self._odom) > 200:  # odometry whose ground truth never came
                for old in sorted(self._odom)[:100]:
                    del self._odom[old]
            return None
        odom = self._odom.pop(key, None)
        if odom is None:
            return None
        frame, odom_pose = odom
        return transform_to_msg(seconds, msg.header.frame_id, frame, map_to_odom(pose, odom_pose))


class RunRecording:
    """The run's MCAP (a rosbag2 directory, zstd chunks) written as a :data:`Sink`."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._writer = BagWriter(self.path, compress=True)
        self._writer.__enter__()
        self._open = True

    def __call__(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        if self._open:
            self._writer.write_serialized(topic, type_name, data, log_time_ns)

    def close(self) -> int:
        """Finish the file (footer, metadata.yaml); returns its size in bytes."""
        if self._open:
            self._open = False
            self._writer.__exit__(None, None, None)
        return bag_bytes(self.path)
