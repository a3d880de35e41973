"""``rls_demo --foxglove``: a WebSocket client sees the run's channels advertised and receives their messages."""

from __future__ import annotations

import asyncio
import json
import queue
import re
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path

from websockets.asyncio import client as websockets_client

# The Foxglove WebSocket protocol as foxglove-sdk 0.30 speaks it; binary messages: op 1, subscription id, log time.
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_HEADER = struct.Struct("<BIQ")


def _lines(stream, sink: queue.Queue) -> None:  # noqa: ANN001
    for line in stream:
        sink.put(line)
    sink.put(None)


async def _watch(address: str, wanted: list[str]) -> tuple[dict[str, dict], dict[str, bytes]]:
    """The advertised channels by topic, and the first message received on each of ``wanted``."""
    channels: dict[str, dict] = {}
    received: dict[str, bytes] = {}
    async with websockets_client.connect(address, subprotocols=[SUBPROTOCOL], max_size=None) as ws:
        by_subscription: dict[int, str] = {}
        while len(received) < len(wanted):
            frame = await asyncio.wait_for(ws.recv(), 60)
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "advertise":
                    fresh = [c for c in message["channels"] if c["topic"] not in channels]
                    channels.update({c["topic"]: c for c in message["channels"]})
                    subscribe = [c for c in fresh if c["topic"] in wanted]
                    for channel in subscribe:
                        by_subscription[len(by_subscription) + 1] = channel["topic"]
                    if subscribe:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": sub, "channelId": channels[topic]["id"]} for sub, topic in by_subscription.items()
                            if topic in {c["topic"] for c in subscribe}]}))
                continue
            op, subscription, _log_time = MESSAGE_HEADER.unpack_from(frame)
            if op == 1 and subscription in by_subscription:
                received.setdefault(by_subscription[subscription], bytes(frame[MESSAGE_HEADER.size:]))
    return channels, received


def test_the_live_server_advertises_the_run_and_streams_its_messages(tmp_path: Path) -> None:
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message

    from robot_localization_suite.ros.recording import error_topic, run_topics

    process = subprocess.Popen(
        [sys.executable, "-m", "robot_localization_suite.launch.demo", "--localizers", "mcl_baseline",
         "--speed", "2", "--duration", "90", "--out", str(tmp_path), "--foxglove", "--foxglove-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(process.stdout, lines), daemon=True).start()
    seen = []
    try:
        address = None
        while address is None:
            line = lines.get(timeout=60)
            assert line is not None, "".join(seen)
            seen.append(line)
            match = re.search(r"Foxglove: open connection (ws://127\.0\.0\.1:\d+)", line)
            address = match.group(1) if match else None
        wanted = ["/ground_truth", "/scan", "/mcl_baseline/pose"]
        channels, received = asyncio.run(_watch(address, wanted))
        expected = {topic.name: topic.type_name for topic in run_topics(["mcl_baseline"], camera=False)}
        expected[error_topic("mcl_baseline")] = "geometry_msgs/msg/PointStamped"
        for topic, type_name in expected.items():
            assert topic in channels, sorted(channels)
            assert (channels[topic]["encoding"], channels[topic]["schemaEncoding"]) == ("cdr", "ros2msg")
            assert channels[topic]["schemaName"] == type_name and channels[topic]["schema"]
        assert set(received) == set(wanted)
        truth = deserialize_message(received["/ground_truth"], Odometry)
        assert truth.header.frame_id == "map" and truth.header.stamp.sec > 1_600_000_000  # a live stamp, not 1970
    finally:
        process.send_signal(signal.SIGINT)
        try:
            code = process.wait(timeout=60)
        finally:
            if process.poll() is None:
                process.kill()
    assert code == 0
