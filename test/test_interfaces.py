"""interfaces/: tf2_msgs and nav2_msgs built by ``make`` from definitions identical to ROS 2 Jazzy's.

The type hash is what DDS peers compare: equal hashes mean a real ROS 2 system's ``/tf``
subscribers (RViz, nav2, tf2_ros) accept our ``TFMessage`` and we accept theirs.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

ROOT = Path(__file__).resolve().parent.parent
# The type hash of tf2_msgs/msg/TFMessage in ROS 2 Jazzy (rosbags' ROS2_JAZZY store holds the same).
JAZZY_TF_MESSAGE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


def _published_type_hash(msg_type: type, topic: str) -> str:
    """The type hash rmw announces for a publisher of ``msg_type``."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("type_hash_probe", context=context)
        node.create_publisher(msg_type, topic, 1)
        (info,) = node.get_publishers_info_by_topic(topic)
        return str(info.topic_type_hash)
    finally:
        rclpy.shutdown(context=context)


def test_tf_message_has_the_jazzy_type_hash() -> None:
    from tf2_msgs.msg import TFMessage

    assert get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage") == JAZZY_TF_MESSAGE_HASH
    assert _published_type_hash(TFMessage, "/tf_hash_probe") == JAZZY_TF_MESSAGE_HASH


@pytest.mark.parametrize("name", ["Particle", "ParticleCloud"])
def test_nav2_messages_hash_as_their_definitions_say(name: str) -> None:
    """The built types hash as rosbags hashes the same definitions (nav2's text, kept in interfaces/)."""
    import nav2_msgs.msg

    store = get_typestore(Stores.ROS2_JAZZY)
    for message in ("Particle", "ParticleCloud"):
        text = (ROOT / "interfaces" / "nav2_msgs" / "msg" / f"{message}.msg").read_text()
        store.register(get_types_from_msg(text, f"nav2_msgs/msg/{message}"))
    expected = store.hash_rihs01(f"nav2_msgs/msg/{name}")
    assert _published_type_hash(getattr(nav2_msgs.msg, name), f"/{name.lower()}_hash_probe") == expected


def test_set_initial_pose_service_is_built() -> None:
    from nav2_msgs.srv import SetInitialPose

    request = SetInitialPose.Request()
    assert request.pose.header.frame_id == "" and len(request.pose.pose.covariance) == 36
