"""QoS profiles as nav2 and the ROS 2 demos use them."""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

__all__ = ["SENSOR_QOS", "SENSOR_INPUT_QOS", "MAP_QOS", "RELIABLE_QOS", "POSE_QOS", "TF_QOS", "TF_STATIC_QOS"]

# Sensor publishers (scan_sim) and best-effort outputs: ROS' sensor-data profile (best effort, keep last 5).
SENSOR_QOS: QoSProfile = qos_profile_sensor_data

# What a localizer subscribes its sensor with (scan, camera image): best effort, keep the newest one only.
# A node slower than its sensor then updates with the newest scan and the others are dropped; with the
# sensor-data depth of 5 it worked through up to 5 queued scans, each older by a whole update when it began
# (rls_soak at 10x the scan rate, docs/soak.md).
SENSOR_INPUT_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)

# As nav2 map_server publishes /map: late subscribers still receive the last map.
MAP_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# Estimates, candidates, diagnostics, initial poses.
RELIABLE_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)

# The pose as nav2_amcl publishes amcl_pose: a late subscriber (transient local or not) gets the last one.
POSE_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# /tf and /tf_static as tf2_ros broadcasts and listens to them.
TF_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
TF_STATIC_QOS = QoSProfile(
    depth=100,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
