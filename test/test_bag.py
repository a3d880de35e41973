"""ros/bag.py on damaged bags: committed bags cut short (as a power cut leaves them) give back their intact part."""

from __future__ import annotations

import logging
import shutil
from functools import cache
from pathlib import Path

import pytest
import yaml
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from robot_localization_suite.core.errors import BagError
from robot_localization_suite.ros import bag_recovery
from robot_localization_suite.ros.bag import BagMessage, bag_topics, read_bag

BAGS = Path(__file__).resolve().parent.parent / "bags"
# office_kidnap: 5 zstd chunks (scan_sim, equal stamps per step); intel: 3 uncompressed chunks (CARMEN).
CUT_BAGS = ("office_kidnap", "intel")


@cache
def intact(name: str) -> tuple[BagMessage, ...]:
    return tuple(read_bag(BAGS / name))


@cache
def chunk_layout(name: str) -> tuple[tuple[int, int, int], ...]:
    """(start byte, end byte, messages) of the first two chunk records of a committed bag."""
    layout = []
    with open(BAGS / name / f"{name}.mcap", "rb") as stream:
        records = StreamReader(stream, emit_chunks=True).records
        while len(layout) < 2:
            start = stream.tell()
            record = next(records)
            if isinstance(record, Chunk):
                inner = breakup_chunk(record)
                layout.append((start, stream.tell(), sum(isinstance(r, Message) for r in inner)))
    return tuple(layout)


def damaged_copy(name: str, folder: Path, size: int, *, zeros: bool = False, metadata: bool = True) -> Path:
    """The bag with its MCAP cut to ``size`` bytes (``zeros``: the rest left as zero bytes, file size kept)."""
    data = (BAGS / name / f"{name}.mcap").read_bytes()
    bag = folder / name
    bag.mkdir(parents=True)
    if metadata:
        shutil.copy(BAGS / name / "metadata.yaml", bag)
    (bag / f"{name}.mcap").write_bytes(data[:size] + (bytes(len(data) - size) if zeros else b""))
    return bag


def same(a: BagMessage, b: BagMessage) -> bool:
    return a.topic == b.topic and a.stamp_ns == b.stamp_ns and a.msg == b.msg


def assert_prefix(recovered: list[BagMessage], name: str) -> None:
    full = intact(name)
    assert 0 < len(recovered) <= len(full)
    bad = [i for i, (a, b) in enumerate(zip(recovered, full, strict=False)) if not same(a, b)]
    assert not bad, f"message {bad[0]} differs from the intact read"


@pytest.mark.parametrize("name", CUT_BAGS)
def test_bag_cut_at_half_gives_back_every_message_before_the_cut(
    name: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    size = (BAGS / name / f"{name}.mcap").stat().st_size
    bag = damaged_copy(name, tmp_path, size // 2)
    with caplog.at_level(logging.WARNING, logger="robot_localization_suite.ros.bag"):
        reading = read_bag(bag)
        recovered = list(reading)
    assert_prefix(recovered, name)
    recovery = reading.recovery
    assert recovery is not None and not recovery.complete
    assert recovery.messages == len(recovered) == sum(recovery.topic_counts.values())
    assert recovery.last_log_time_ns == max(m.stamp_ns for m in recovered)
    assert recovery.stopped_at == size // 2 and "the file ends inside the chunk record" in recovery.stop
    assert "File end magic is invalid" in recovery.reason
    # Everything up to the cut: office_kidnap 2174 of 4564 messages, intel 981 of 2731 (its 2.2 MB map
    # message comes first), of which 1915 and 551 lie in whole chunks, the rest in the cut chunk's readable start.
    assert len(recovered) == {"office_kidnap": 2943, "intel": 981}[name]
    assert f"recovered {len(recovered)} messages" in caplog.text and str(bag) in caplog.text


@pytest.mark.parametrize("name", CUT_BAGS)
@pytest.mark.parametrize("where", ["record boundary", "inside a chunk", "zero-filled tail"])
def test_cut_at_a_boundary_or_inside_a_chunk(name: str, where: str, tmp_path: Path) -> None:
    (_, _, first_n), (second_start, second_end, second_n) = chunk_layout(name)
    if where == "record boundary":  # the second chunk starts here: the first chunk and its indexes are whole
        bag = damaged_copy(name, tmp_path, second_start)
    else:
        bag = damaged_copy(name, tmp_path, (second_start + second_end) // 2, zeros=where == "zero-filled tail")
    reading = read_bag(bag)
    recovered = list(reading)
    assert_prefix(recovered, name)
    if where == "record boundary":
        assert len(recovered) == first_n
        assert reading.recovery.stopped_at == second_start
        assert reading.recovery.stop == "the file ends there, without a footer"
    else:  # the readable start of the cut chunk too
        assert first_n < len(recovered) < first_n + second_n


def test_topic_filter_and_topics_of_a_damaged_bag(tmp_path: Path) -> None:
    bag = damaged_copy("office_kidnap", tmp_path, 900_000)
    scans = list(read_bag(bag, ["/scan"]))
    assert [m.stamp_ns for m in scans] == [m.stamp_ns for m in list(read_bag(bag)) if m.topic == "/scan"]
    assert scans and all(type(m.msg).__name__ == "LaserScan" for m in scans)
    assert bag_topics(bag) == bag_topics(BAGS / "office_kidnap")


def test_sound_bags_take_todays_path_and_report_no_recovery(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_recovery(*args: object) -> None:
        raise AssertionError("a sound bag must not go through the stream reader")

    monkeypatch.setattr(bag_recovery, "recover", no_recovery)
    for name in sorted(p.name for p in BAGS.iterdir() if (p / "metadata.yaml").is_file()):
        reading = read_bag(BAGS / name, ["/map"])
        maps = len(list(reading))  # one /map, or more in a bag with map changes (office_mapchange: 2)
        assert reading.recovery is None and maps == (2 if name == "office_mapchange" else 1), name
        assert "/scan" in bag_topics(BAGS / name)


def test_missing_metadata_yaml_loses_nothing(tmp_path: Path) -> None:
    name = "room_outliers_bounded"
    bag = damaged_copy(name, tmp_path, (BAGS / name / f"{name}.mcap").stat().st_size, metadata=False)
    reading = read_bag(bag)
    assert [(m.topic, m.stamp_ns) for m in reading] == [(m.topic, m.stamp_ns) for m in intact(name)]
    assert reading.recovery.complete and reading.recovery.messages == 451
    assert "read to the end, nothing lost" in reading.recovery.summary()


def test_stale_metadata_yaml_is_not_trusted(tmp_path: Path) -> None:
    name = "room_outliers_bounded"
    bag = damaged_copy(name, tmp_path, (BAGS / name / f"{name}.mcap").stat().st_size)
    # As written early in a recording: one topic, one message (rosbags would then read the /map alone).
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["message_count"] = 1
    info["topics_with_message_count"] = info["topics_with_message_count"][:1]
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    reading = read_bag(bag)
    assert len(list(reading)) == 451
    assert "metadata.yaml is stale: it counts 1 messages, the MCAP files hold 451" in reading.recovery.reason


def test_split_bag_reads_its_files_in_order(tmp_path: Path) -> None:
    """rosbag2 names split files bag_0.mcap, bag_1.mcap, ...: the last one is the one a crash cuts."""
    bag = tmp_path / "split"
    bag.mkdir()
    shutil.copy(BAGS / "room_outliers_bounded" / "room_outliers_bounded.mcap", bag / "split_2.mcap")
    office = (BAGS / "office_kidnap" / "office_kidnap.mcap").read_bytes()
    (bag / "split_10.mcap").write_bytes(office[:500_000])
    reading = read_bag(bag)
    recovered = list(reading)
    assert [m.stamp_ns for m in recovered[:451]] == [m.stamp_ns for m in intact("room_outliers_bounded")]
    assert_prefix(recovered[451:], "office_kidnap")
    assert reading.recovery.file.name == "split_10.mcap" and reading.recovery.stopped_at == 500_000


def write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (lambda d: d.mkdir() or d, "holds no .mcap file to recover from"),
        (lambda d: write(d / "bag.mcap", b"").parent, "bag.mcap' is empty (0 bytes)"),
        (lambda d: write(d / "bag.mcap", b"x,y\n1,2\n" * 50).parent, "bag.mcap' is not an MCAP file"),
        (lambda d: write(d / "bag.mcap", (BAGS / "intel" / "intel.mcap").read_bytes()[:60]).parent,
         "bag.mcap' holds no complete message: reading stopped at byte 60 of 60: the file ends inside the chunk"),
        (lambda d: write(d / "notes.txt", b"hello"), "notes.txt' is not an MCAP file"),
    ],
    ids=["no mcap", "empty", "not mcap", "header only", "a text file"],
)
def test_bad_input_is_a_bag_error_naming_the_file(tmp_path: Path, make, problem: str) -> None:
    path = make(tmp_path / "bag")
    with pytest.raises(BagError, match="nothing in it can be recovered|no .mcap file") as info:
        list(read_bag(path))
    assert problem in str(info.value) and str(tmp_path / "bag") in str(info.value)
    with pytest.raises(BagError):
        bag_topics(path)


def test_missing_bag_is_a_bag_error(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        read_bag(tmp_path / "nowhere")
