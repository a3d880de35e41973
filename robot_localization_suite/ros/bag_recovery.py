"""What a damaged MCAP bag still holds: every complete message before the damage, read as a stream.

``ros/bag.py`` comes here only when rosbags refuses a bag (no footer or summary, a file cut
mid-chunk, metadata.yaml missing or stale). Records are read in file order with ``mcap``'s
``StreamReader``; messages come out in the order rosbags gives an intact bag. How and why:
``docs/benchmark.md``, "Damaged bags".
"""

from __future__ import annotations

import heapq
import io
import re
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, NamedTuple

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, McapRecord, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from ..core.errors import BagError

__all__ = ["Recovery", "RecoveredBag", "recover"]

_MAGIC = b"\x89MCAP0\r\n"
_HEADER = struct.Struct("<BQ")  # a record's opcode and length


@dataclass(frozen=True)
class Recovery:
    """What was read back from a damaged bag, and where reading stopped."""

    reason: str  # why the normal reader refused the bag
    messages: int  # complete messages recovered, every topic
    topic_counts: dict[str, int]
    file: Path  # the MCAP file where reading stopped (the last one when nothing was lost)
    stopped_at: int  # [byte] offset in ``file`` of the first byte not used
    file_size: int  # [byte]
    stop: str  # why reading stopped there
    last_log_time_ns: int | None
    complete: bool  # every file was read to its footer: nothing was lost
    compression: str  # chunk compression seen ('' none, 'zstd', 'lz4')

    def summary(self) -> str:
        """One line: how many messages, up to which log time, where reading stopped and why."""
        last = f"{self.last_log_time_ns * 1e-9:.3f} s" if self.last_log_time_ns is not None else "none"
        where = ("read to the end, nothing lost" if self.complete else
                 f"reading stopped at byte {self.stopped_at} of {self.file_size} of {self.file.name!r}: {self.stop}")
        return f"recovered {self.messages} messages (last log time {last}); {where}"


@dataclass
class _Source:
    """A span of one file read as a unit: a chunk record, a run of top-level records, or a cut chunk."""

    start: int
    end: int
    first_ns: int
    channels: set[int]
    partial: bool = False


@dataclass
class _FileScan:
    path: Path
    size: int
    channels: dict[int, tuple[str, str]] = field(default_factory=dict)  # id -> (topic, type name)
    sources: list[_Source] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    last_ns: int | None = None
    stopped_at: int = 0
    stop: str = ""
    complete: bool = False
    compression: str = ""


class _Window:
    """Bytes ``[start, end)`` of a file, so the stream reader meets a clean end of file at ``end``.

    Unbuffered on purpose: ``tell()`` is then the end of the record just read.
    """

    def __init__(self, stream: IO[bytes], start: int, end: int) -> None:
        self._stream, self._pos, self._end = stream, start, end
        stream.seek(start)

    def tell(self) -> int:
        return self._pos

    def read(self, size: int = -1) -> bytes:
        size = self._end - self._pos if size < 0 else min(size, self._end - self._pos)
        data = self._stream.read(size) if size > 0 else b""
        self._pos += len(data)
        return data


def _natural(path: Path) -> list[object]:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _mcap_files(path: Path, reason: str) -> list[Path]:
    if path.is_file():
        return [path]
    files = sorted(path.glob("*.mcap"), key=_natural)
    if not files:
        raise BagError(f"bag {str(path)!r} cannot be read ({reason}) and holds no .mcap file to recover from")
    return files


class _Prefix(NamedTuple):
    end: int  # end of the last whole top-level record
    cut: int | None  # start of a chunk record cut short (read up to ``cut_end``), or None
    cut_end: int
    stop: str  # why reading stops
    complete: bool  # footer and closing magic read


def _last_written(stream: IO[bytes], start: int, end: int) -> int:
    """One past the last non-zero byte of ``[start, end)`` (``start`` if all are zero)."""
    stream.seek(start)
    data = stream.read(end - start)
    return start + len(data.rstrip(b"\0"))


def _complete_prefix(stream: IO[bytes], size: int) -> _Prefix:
    """Frame the top-level records (9-byte headers only) up to the first one cut short or invalid."""
    pos, last = len(_MAGIC), None  # last: (start, opcode) of the last whole record
    while True:
        if pos == size:
            return _Prefix(pos, None, size, "the file ends there, without a footer", False)
        if pos + _HEADER.size > size:
            return _Prefix(pos, None, size, f"the file ends {size - pos} bytes into a record header", False)
        stream.seek(pos)
        opcode, length = _HEADER.unpack(stream.read(_HEADER.size))
        end = pos + _HEADER.size + length
        if opcode == 0:
            # Space never written (a power cut can leave zeros): the record before may end in it too.
            written = _last_written(stream, last[0], pos) if last is not None else pos
            if last is not None and written < pos:
                cut = last[0] if last[1] == Opcode.CHUNK else None
                return _Prefix(last[0], cut, written, f"zero bytes from byte {written} on (space never written)",
                               False)
            return _Prefix(pos, None, size, "zero bytes from there on (space never written)", False)
        if end > size:
            try:
                name = f"{Opcode(opcode).name.lower()} record"
            except ValueError:
                name = f"record of unknown opcode {opcode:#04x}"
            cut = pos if opcode == Opcode.CHUNK else None
            return _Prefix(pos, cut, size, f"the file ends inside the {name} at byte {pos} ({size - pos} of its "
                           f"{end - pos} bytes)", False)
        if opcode == Opcode.FOOTER:
            stream.seek(end)
            if stream.read(len(_MAGIC)) == _MAGIC:
                return _Prefix(end + len(_MAGIC), None, size, "the footer: nothing lost", True)
            return _Prefix(end, None, size, "the footer is not followed by the closing magic", False)
        pos, last = end, (pos, opcode)


def _decompressed_prefix(chunk: Chunk) -> bytes:
    """As much of a chunk's records as its bytes give (cut short, or ending in garbage such as zeros)."""
    if chunk.compression == "":
        return chunk.data
    if chunk.compression != "zstd":
        return b""  # an lz4 frame that does not decode whole is not read
    decoder, out = zstandard.ZstdDecompressor().decompressobj(), []
    try:
        for at in range(0, len(chunk.data), 1 << 16):  # zstd decodes block by block: keep what came before
            out.append(decoder.decompress(chunk.data[at:at + (1 << 16)]))
    except zstandard.ZstdError:
        pass
    return b"".join(out)


def _whole_records(data: bytes) -> Iterator[McapRecord]:
    """Schema, channel and message records of ``data`` up to the first one cut short."""
    pos = 0
    while pos + _HEADER.size <= len(data):
        opcode, length = _HEADER.unpack_from(data, pos)
        end = pos + _HEADER.size + length
        if end > len(data):
            return
        body = ReadDataStream(io.BytesIO(data[pos + _HEADER.size:end]))
        if opcode == Opcode.MESSAGE:
            yield Message.read(body, length)
        elif opcode == Opcode.CHANNEL:
            yield Channel.read(body)
        elif opcode == Opcode.SCHEMA:
            yield Schema.read(body)
        pos = end


def _damaged_chunk_records(stream: IO[bytes], start: int, end: int) -> list[McapRecord]:
    """The whole records at the start of a chunk record that is cut short or does not decode."""
    stream.seek(start + _HEADER.size)
    records: list[McapRecord] = []
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(stream.read(end - start - _HEADER.size))))
        records.extend(_whole_records(_decompressed_prefix(chunk)))
    except (EndOfFile, struct.error, UnicodeDecodeError):
        pass  # cut inside the chunk's own header, or a record that does not parse: keep what came before
    return records


def _span_records(stream: IO[bytes], source: _Source) -> Iterator[McapRecord]:
    """The records of a source that was read whole in the first pass."""
    window: IO[bytes] = _Window(stream, source.start, source.end)  # type: ignore[assignment]
    reader = StreamReader(window, skip_magic=True, record_size_limit=None)
    try:
        yield from reader.records
    except EndOfFile:
        return


class _Scanner:
    """First pass over one file: channels, message counts and the spans the second pass reads."""

    def __init__(self, path: Path) -> None:
        self.scan = _FileScan(path, path.stat().st_size)
        self._schemas: dict[int, str] = {}
        self._data_whole = False  # DataEnd read: whatever follows, no message is lost

    def _take(self, records: Iterable[McapRecord], source: _Source) -> None:
        scan = self.scan
        for record in records:
            if isinstance(record, Schema):
                self._schemas[record.id] = record.name
            elif isinstance(record, Channel) and record.message_encoding == "cdr":  # rosbags reads CDR only
                scan.channels[record.id] = (record.topic, self._schemas.get(record.schema_id, ""))
            elif isinstance(record, Message) and record.channel_id in scan.channels:
                topic = scan.channels[record.channel_id][0]
                scan.counts[topic] = scan.counts.get(topic, 0) + 1
                scan.last_ns = record.log_time if scan.last_ns is None else max(scan.last_ns, record.log_time)
                source.first_ns = min(source.first_ns, record.log_time)
                source.channels.add(record.channel_id)

    def _stopped(self, at: int, why: str) -> None:
        self.scan.stopped_at, self.scan.stop = at, why
        self.scan.complete = self._data_whole

    def run(self, stream: IO[bytes]) -> _FileScan:
        scan = self.scan
        if scan.size == 0:
            raise BagError(f"{str(scan.path)!r} is empty (0 bytes)")
        stream.seek(0)
        if stream.read(len(_MAGIC)) != _MAGIC:
            raise BagError(f"{str(scan.path)!r} is not an MCAP file: it does not start with the MCAP magic")
        prefix = _complete_prefix(stream, scan.size)
        scan.stop, scan.complete = prefix.stop, prefix.complete
        scan.stopped_at = prefix.cut_end if prefix.cut is not None else prefix.end  # a cut chunk is read to its end
        if self._read_whole_records(stream, prefix.end) and prefix.cut is not None:
            self._add_damaged_chunk(stream, prefix.cut, prefix.cut_end)
        scan.sources = [s for s in scan.sources if s.channels]
        return scan

    def _add_damaged_chunk(self, stream: IO[bytes], start: int, end: int) -> None:
        source = _Source(start, end, 2**63, set(), partial=True)
        self.scan.sources.append(source)
        self._take(_damaged_chunk_records(stream, start, end), source)

    def _read_whole_records(self, stream: IO[bytes], end: int) -> bool:
        """Read the records of ``[0, end)``; False when one of them is damaged (reading stops there)."""
        scan = self.scan
        window = _Window(stream, 0, end)
        records = StreamReader(window, emit_chunks=True, record_size_limit=None).records  # type: ignore[arg-type]
        run: _Source | None = None  # top-level messages since the last chunk
        while True:
            start = window.tell()
            try:
                record = next(records)
            except (StopIteration, EndOfFile):
                return True
            except Exception as exc:  # noqa: BLE001 - a record that does not parse ends the readable part
                self._stopped(start, f"a record there does not parse ({type(exc).__name__}: {exc})")
                return False
            if isinstance(record, Chunk):
                run = None
                scan.compression = scan.compression or record.compression
                try:
                    inner = breakup_chunk(record, validate_crc=True)
                except Exception as exc:  # noqa: BLE001 - its decodable start is read, then no more
                    self._stopped(start, f"the chunk record there does not decode ({type(exc).__name__}: {exc})")
                    self._add_damaged_chunk(stream, start, window.tell())
                    return False
                source = _Source(start, window.tell(), 2**63, set())
                scan.sources.append(source)
                self._take(inner, source)
                continue
            if isinstance(record, Message) and run is None:
                run = _Source(start, window.tell(), 2**63, set())
                scan.sources.append(run)
            if run is not None:
                run.end = window.tell()
            if isinstance(record, DataEnd):
                self._data_whole = scan.complete = True
            self._take([record], run or _Source(start, start, 2**63, set()))


class RecoveredBag:
    """The readable part of a damaged bag: its topics, a :class:`Recovery` and the raw messages."""

    def __init__(self, scans: list[_FileScan], recovery: Recovery) -> None:
        self._scans = scans
        self.recovery = recovery

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type name, of every channel read."""
        return {topic: kind for scan in self._scans for topic, kind in scan.channels.values()}

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """``(topic, type name, log time [ns], CDR bytes)`` in the order rosbags reads an intact bag.

        rosbags reads the files one after another and, in each, merges its chunks by log time,
        keeping file order among equal times; the same here, source by source.
        """
        wanted = set(topics) if topics is not None else None
        for scan in self._scans:
            ids = {cid for cid, (topic, _) in scan.channels.items() if wanted is None or topic in wanted}
            with scan.path.open("rb") as stream:
                sources = [s for s in scan.sources if s.channels & ids]
                merged = heapq.merge(*(self._ordered(stream, scan, index, s, ids) for index, s in enumerate(sources)))
                for log_time, _, _, (cid, data) in merged:
                    if cid >= 0:
                        topic, kind = scan.channels[cid]
                        yield topic, kind, log_time, data

    @staticmethod
    def _ordered(stream: IO[bytes], scan: _FileScan, index: int, source: _Source,
                 ids: set[int]) -> Iterator[tuple[int, int, int, tuple[int, bytes]]]:
        # A first item at the source's earliest time lets heapq.merge start without decoding every chunk.
        yield source.first_ns, index, -1, (-1, b"")
        records = (_damaged_chunk_records(stream, source.start, source.end) if source.partial
                   else _span_records(stream, source))
        found = [(r.log_time, r.channel_id, r.data) for r in records if isinstance(r, Message) and r.channel_id in ids]
        found.sort(key=lambda item: item[0])  # stable: file order among equal log times
        for position, (log_time, cid, data) in enumerate(found):
            yield log_time, index, position, (cid, data)


def recover(path: str | Path, reason: str) -> RecoveredBag:
    """Scan the MCAP file(s) of a bag the normal reader refused (``reason``) for complete messages.

    Raises:
        BagError: no .mcap file, an empty or non-MCAP file, or not one complete message.
    """
    path = Path(path)
    scans: list[_FileScan] = []
    problems: list[tuple[Path, str]] = []
    for file in _mcap_files(path, reason):
        try:
            with file.open("rb") as stream:
                scans.append(_Scanner(file).run(stream))
        except (BagError, OSError) as exc:
            problems.append((file, str(exc)))
    total = sum(sum(s.counts.values()) for s in scans)
    if total == 0:
        problem = problems[0][1] if problems else (
            f"{str(scans[0].path)!r} holds no complete message: reading stopped at byte {scans[0].stopped_at} "
            f"of {scans[0].size}: {scans[0].stop}")
        raise BagError(f"bag {str(path)!r} cannot be read ({reason}) and nothing in it can be recovered: {problem}")
    damaged = next((s for s in scans if not s.complete), None)
    counts: dict[str, int] = {}
    for scan in scans:
        for topic, count in scan.counts.items():
            counts[topic] = counts.get(topic, 0) + count
    where = damaged or scans[-1]
    stop = where.stop
    if problems:
        stop += "; " + "; ".join(text for _, text in problems)
    last = max((s.last_ns for s in scans if s.last_ns is not None), default=None)
    recovery = Recovery(
        reason=reason, messages=total, topic_counts=counts, file=where.path,
        stopped_at=where.stopped_at if damaged else where.size, file_size=where.size, stop=stop,
        last_log_time_ns=last, complete=damaged is None and not problems,
        compression=next((s.compression for s in scans if s.compression), ""),
    )
    return RecoveredBag(scans, recovery)
