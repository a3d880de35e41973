"""A demo run served live over the Foxglove WebSocket protocol (``foxglove-sdk``), as a :data:`.recording.Sink`.

Every topic is a channel advertised at the start, ``cdr``-encoded with its ``ros2msg`` schema (the
text rosbag2 puts in an MCAP, :func:`.bag.message_definition`), so Foxglove decodes the messages
exactly as it decodes the recording. The server listens on loopback only.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from .bag import message_definition

__all__ = ["LiveServer"]


class LiveServer:
    """Foxglove WebSocket server of ``topics`` (``(name, pkg/msg/Name)`` pairs) on ``host:port`` (0: a free port).

    Raises:
        ImportError: foxglove-sdk is not installed (``pip install -e '.[viz]'``; ``make`` installs it).
    """

    def __init__(self, topics: Iterable[tuple[str, str]], *, host: str = "127.0.0.1", port: int = 8765) -> None:
        import foxglove

        self._foxglove = foxglove
        self.host = host
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name="rls_demo", host=host, port=port, context=self.context)
        self.channels: dict[str, Any] = {}
        for name, type_name in topics:
            self._channel(name, type_name)

    def _channel(self, topic: str, type_name: str) -> Any:
        channel = self.channels.get(topic)
        if channel is None:
            schema = self._foxglove.Schema(name=type_name, encoding="ros2msg",
                                           data=message_definition(type_name).encode())
            channel = self.channels[topic] = self._foxglove.Channel(topic, schema=schema, message_encoding="cdr",
                                                                   context=self.context)
        return channel

    @property
    def address(self) -> str:
        """``ws://host:port``: what Foxglove's "Open connection" takes."""
        return f"ws://{self.host}:{self.server.port}"

    def app_url(self) -> str | None:
        """The Foxglove web app's link that opens this server (None once stopped)."""
        return self.server.app_url()

    def __call__(self, topic: str, type_name: str, data: bytes, log_time_ns: int) -> None:
        self._channel(topic, type_name).log(data, log_time=log_time_ns)

    def close(self) -> None:
        self.server.stop()
