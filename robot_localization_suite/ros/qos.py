"""QoS profiles as nav2 and the ROS 2 demos use them."""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

__all__ = ["SENSOR_QOS", "MAP_QOS", "RELIABLE_QOS", "POSE_QOS", "TF_QOS", "TF_STATIC_QOS"]

# Best effort, small depth: a slow localizer drops old scans instead of queueing them.
SENSOR_QOS: QoSProfile = qos_profile_sensor_data

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
