"""rosbag2 MCAP bags: write, read, and replay deterministically.

``rosbags`` handles the container (``metadata.yaml`` + ``.mcap``, as
``ros2 bag record -s mcap`` makes it); messages are serialised and deserialised
with rclpy's own CDR type support, so the bag holds exactly what a ROS 2 node
publishes and the replay hands nodes the message classes they subscribe to. A bag rosbags
refuses (cut short, no footer, metadata.yaml missing or stale) is read by ``bag_recovery``:
every complete message, with a warning and :attr:`BagMessages.recovery`.
"""

from __future__ import annotations

import importlib
import logging
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore

from ..core.errors import BagError

if TYPE_CHECKING:
    from .bag_recovery import RecoveredBag, Recovery

__all__ = ["BagMessage", "BagMessages", "BagWriter", "read_bag", "bag_custom_data", "bag_topics", "remapped_topic", "replay", "message_type_name",
           "message_class", "message_definition", "bag_bytes"]

LOG = logging.getLogger(__name__)
_TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
_WARNED: set[tuple[str, str]] = set()


def message_type_name(msg_or_class: Any) -> str:
    """``sensor_msgs/msg/LaserScan`` for a LaserScan instance or class."""
    cls = msg_or_class if isinstance(msg_or_class, type) else type(msg_or_class)
    package = cls.__module__.split(".")[0]
    return f"{package}/msg/{cls.__name__}"


def bag_bytes(path: str | os.PathLike[str]) -> int:
    """The size of a bag directory (its MCAP files and metadata.yaml) [bytes]."""
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())


def message_definition(type_name: str) -> str:
    """The ``ros2msg`` text of ``pkg/msg/Name`` with its dependencies, as rosbag2 puts it in an MCAP schema."""
    text, _ = _TYPESTORE.generate_msgdef(type_name, ros_version=2)
    return text


def message_class(type_name: str) -> type:
    """The rclpy class of ``pkg/msg/Name``; BagError when it is not installed."""
    try:
        package, kind, name = type_name.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise BagError(f"unknown message type {type_name!r} in bag") from exc


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag: its topic, log time [ns] and deserialised rclpy message."""

    topic: str
    stamp_ns: int
    msg: Any


class BagWriter:
    """Write rclpy messages into a new rosbag2 MCAP bag directory.

    Use as a context manager; topics are added on their first message.
    ``compress=True`` zstd-compresses the MCAP chunks (what ``ros2 bag record
    -s mcap --storage-preset-profile zstd_fast`` does; rosbag2 reads it as is):
    simulated bags shrink to less than half.
    """

    def __init__(self, path: str | os.PathLike[str], *, compress: bool = False,
                 custom_data: Mapping[str, str] | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"bag directory {str(self.path)!r} already exists")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():  # the metadata's custom_data, as rosbag2 keeps it
            self._writer.set_custom_data(key, value)
        self._connections: dict[str, Any] = {}
        self.count = 0

    def __enter__(self) -> BagWriter:
        try:
            self._writer.open()
        except WriterError as exc:
            raise BagError(f"cannot open bag {str(self.path)!r} for writing: {exc}") from exc
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._writer.close()

    def write(self, topic: str, msg: Any, stamp_ns: int) -> None:
        self.write_serialized(topic, message_type_name(msg), serialize_message(msg), stamp_ns)

    def write_serialized(self, topic: str, type_name: str, data: bytes, stamp_ns: int) -> None:
        """A message already in CDR (as a raw rclpy subscription receives it) of type ``pkg/msg/Name``."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(topic, type_name, typestore=_TYPESTORE)
        self._writer.write(self._connections[topic], int(stamp_ns), data)
        self.count += 1


def _stale_metadata(reader: Reader, path: Path) -> str | None:
    """Why a bag's metadata.yaml disagrees with its MCAP files (rosbags trusts it for topics), or None."""
    storages = getattr(reader.storage, "storages", None)
    if not path.is_dir() or not storages or reader.compression_mode == "file":
        return None
    listed = {Path(storage.path).name for storage in storages}
    if unlisted := sorted(p.name for p in path.glob("*.mcap") if p.name not in listed):
        return f"metadata.yaml is stale: it does not list {unlisted}"
    in_files = sum(storage.metadata.message_count for storage in storages)
    if in_files != reader.message_count:
        return f"metadata.yaml is stale: it counts {reader.message_count} messages, the MCAP files hold {in_files}"
    return None


def _open(path: Path) -> tuple[Reader | None, RecoveredBag | None]:
    """rosbags' reader for a sound bag (today's path); else what ``bag_recovery`` finds, with a warning."""
    if not path.exists():
        raise BagError(f"bag {str(path)!r} does not exist")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001 - whatever rosbags refuses, the stream reader tries
        reason = str(exc) or type(exc).__name__
    else:
        stale = _stale_metadata(reader, path)
        if stale is None:
            return reader, None
        reader.close()
        reason = stale
    from .bag_recovery import recover  # the mcap stream reader, only for damaged bags

    recovered = recover(path, reason)
    key = (str(path.resolve()), recovered.recovery.summary())
    if key not in _WARNED:  # once per bag and process: the benchmark reads a bag several times
        _WARNED.add(key)
        LOG.warning("bag %r is damaged (%s): %s", str(path), reason, recovered.recovery.summary())
    return None, recovered


class BagMessages(Iterator[BagMessage]):
    """The messages of one reading of a bag, in log-time order.

    ``recovery`` is None for a sound bag, else what was recovered from a damaged one
    (:class:`~robot_localization_suite.ros.bag_recovery.Recovery`).
    """

    def __init__(self, messages: Iterator[BagMessage], recovery: Recovery | None,
                 reader: Reader | None = None, decoder: _Decoder | None = None) -> None:
        self._messages = messages
        self._reader = reader
        self._decoder = decoder
        self.recovery = recovery

    @property
    def skipped(self) -> int:
        """Messages left out so far because their bytes could not be decoded (damaged, the chunk intact)."""
        return self._decoder.skipped if self._decoder is not None else 0

    def __iter__(self) -> BagMessages:
        return self

    def __next__(self) -> BagMessage:
        return next(self._messages)

    def close(self) -> None:
        """Release the bag's files (also done at the end of the messages)."""
        close = getattr(self._messages, "close", None)
        if close is not None:
            close()
        if self._reader is not None and self._reader.is_open:
            self._reader.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - never raise from a finalizer
            pass


def bag_custom_data(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``custom_data`` of a bag's ``metadata.yaml`` (rosbag2 metadata version 6 on); empty when it has
    none or no readable metadata (a damaged bag's is read as it is)."""
    import yaml

    try:
        with open(Path(path) / "metadata.yaml", encoding="utf-8") as stream:
            info = (yaml.safe_load(stream) or {}).get("rosbag2_bagfile_information") or {}
    except (OSError, yaml.YAMLError, AttributeError):
        return {}
    custom = info.get("custom_data") if isinstance(info, dict) else None
    return {str(key): str(value) for key, value in custom.items()} if isinstance(custom, dict) else {}


def remapped_topic(topic: str, remap: Mapping[str, str] | None) -> str | None:
    """The name a bag's ``topic`` goes by under ``remap`` (bag topic -> name, as ``ros2 bag play --remap``);
    None when another topic is remapped onto its name (a node subscribed to that name would not hear it)."""
    if not remap:
        return topic
    if topic in remap:
        return remap[topic]
    return None if topic in remap.values() else topic


def bag_topics(path: str | os.PathLike[str], remap: Mapping[str, str] | None = None) -> dict[str, str]:
    """Topic name (under ``remap``) -> message type name of a bag (of what could be read, for a damaged one)."""
    reader, recovered = _open(Path(path))
    if recovered is not None:
        found = recovered.topics
    else:
        assert reader is not None
        try:
            found = {c.topic: c.msgtype for c in reader.connections}
        finally:
            reader.close()
    return {name: kind for topic, kind in found.items() if (name := remapped_topic(topic, remap)) is not None}


class _Decoder:
    """Deserialises one reading's messages; one whose bytes are damaged (its chunk intact, its CDR not) is
    skipped and counted, and said once per bag and process when the reading ends."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.skipped = 0
        self._first = ""

    def __call__(self, raw: bytes, cls: type, topic: str, stamp_ns: int) -> Any | None:
        try:
            return deserialize_message(raw, cls)
        except (RuntimeError, ValueError, TypeError) as exc:  # rclpy's RMWError is a RuntimeError
            self.skipped += 1
            self._first = self._first or f"{topic} at {stamp_ns * 1e-9:.3f} s: {exc}"
            return None

    def report(self) -> None:
        key = (str(self.path.resolve()), f"undecodable {self.skipped}")
        if self.skipped and key not in _WARNED:
            _WARNED.add(key)
            LOG.warning("bag %r: %d message(s) could not be decoded and were skipped (the first: %s)",
                        str(self.path), self.skipped, self._first)


def _sound_messages(reader: Reader, path: Path, wanted: set[str] | None,
                    remap: Mapping[str, str] | None, decode: _Decoder) -> Iterator[BagMessage]:
    try:
        names = {c.id: remapped_topic(c.topic, remap) for c in reader.connections}
        connections = [c for c in reader.connections
                       if names[c.id] is not None and (wanted is None or names[c.id] in wanted)]
        classes = {c.id: message_class(c.msgtype) for c in connections}
        try:
            for connection, stamp_ns, raw in reader.messages(connections=connections):
                topic = str(names[connection.id])
                msg = decode(raw, classes[connection.id], topic, int(stamp_ns))
                if msg is not None:
                    yield BagMessage(topic, int(stamp_ns), msg)
        except (ReaderError, OSError, ValueError) as exc:
            raise BagError(f"bag {str(path)!r} is corrupt: {exc}") from exc
    finally:
        decode.report()
        if reader.is_open:
            reader.close()


def _recovered_messages(recovered: RecoveredBag, path: Path, wanted: set[str] | None,
                        remap: Mapping[str, str] | None, decode: _Decoder) -> Iterator[BagMessage]:
    classes: dict[str, type] = {}
    names = {topic: remapped_topic(topic, remap) for topic in recovered.topics}
    sources = [topic for topic, name in names.items() if name is not None and (wanted is None or name in wanted)]
    try:
        for topic, type_name, stamp_ns, raw in recovered.messages(sources):
            cls = classes.get(type_name) or classes.setdefault(type_name, message_class(type_name))
            msg = decode(raw, cls, str(names[topic]), stamp_ns)
            if msg is not None:
                yield BagMessage(str(names[topic]), stamp_ns, msg)
    except OSError as exc:
        raise BagError(f"bag {str(path)!r} cannot be read: {exc}") from exc
    finally:
        decode.report()


def read_bag(path: str | os.PathLike[str], topics: Iterable[str] | None = None, *,
             remap: Mapping[str, str] | None = None) -> BagMessages:
    """Messages of a bag in log-time order, deserialised as rclpy messages; with ``remap`` (bag topic ->
    name) its topics go by those names (:func:`remapped_topic`), ``topics`` and the messages' included.

    A damaged bag (cut short, no footer, metadata.yaml missing or stale) yields every complete
    message before the damage; a warning and the result's ``recovery`` say how many and where
    reading stopped. A message whose own bytes are damaged is skipped (``skipped``, a warning).

    Raises:
        BagError: the bag is missing, holds nothing readable, or an unknown message type.
    """
    path = Path(path)
    wanted = set(topics) if topics is not None else None
    reader, recovered = _open(path)
    decode = _Decoder(path)
    if recovered is not None:
        return BagMessages(_recovered_messages(recovered, path, wanted, remap, decode), recovered.recovery,
                           decoder=decode)
    assert reader is not None
    return BagMessages(_sound_messages(reader, path, wanted, remap, decode), None, reader, decoder=decode)


def replay(
    path: str | os.PathLike[str],
    handlers: dict[str, Callable[[Any], Any]],
    *,
    on_message: Callable[[BagMessage], None] | None = None,
    remap: Mapping[str, str] | None = None,
) -> int:
    """Feed each message of the bag to ``handlers[topic]`` in bag order, one after another (topics under
    ``remap``, as :func:`read_bag`).

    Every handler call returns before the next message is read, so the replay is
    deterministic and as fast as the handlers allow. ``on_message`` sees every
    message (handled or not) first. Returns the number of messages handled.
    """
    handled = 0
    topics = None if on_message is not None else list(handlers)
    for item in read_bag(path, topics, remap=remap):
        if on_message is not None:
            on_message(item)
        handler = handlers.get(item.topic)
        if handler is not None:
            handler(item.msg)
            handled += 1
    return handled
