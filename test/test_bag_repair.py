"""rls_bag_repair: a bag cut short becomes a sound bag holding what was recovered; bad input is one line, exit 2."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from robot_localization_suite.ros.bag import read_bag
from robot_localization_suite.tools import bag_repair

BAGS = Path(__file__).resolve().parent.parent / "bags"


def cut_bag(folder: Path, name: str = "office_kidnap") -> Path:
    """A copy of a committed bag whose recording lost power at half: no footer, no metadata.yaml."""
    data = (BAGS / name / f"{name}.mcap").read_bytes()
    bag = folder / name
    bag.mkdir(parents=True)
    (bag / f"{name}.mcap").write_bytes(data[: len(data) // 2])
    return bag


def test_repair_writes_a_sound_bag_with_every_recovered_message(tmp_path: Path, capsys) -> None:
    damaged = cut_bag(tmp_path / "in")
    recovered = list(read_bag(damaged))
    out = tmp_path / "out" / "repaired"
    assert bag_repair.main([str(damaged), str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith(f"rls_bag_repair: wrote {len(recovered)} messages (/map 1, /tf_static 1, /odom ")
    assert "the file ends inside the chunk record" in line and "\n" not in line
    # A sound bag: rosbags reads it without recovery, with its footer and summary, and the same messages.
    reading = read_bag(out)
    repaired = list(reading)
    assert reading.recovery is None and (out / "metadata.yaml").is_file()
    assert [(m.topic, m.stamp_ns) for m in repaired] == [(m.topic, m.stamp_ns) for m in recovered]
    assert all(a.msg == b.msg for a, b in zip(repaired, recovered, strict=True))
    with open(out / "repaired.mcap", "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary.statistics.message_count == len(recovered)
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}  # as the damaged bag was
    assert [p.name for p in out.parent.iterdir()] == ["repaired"]  # no staging directory left


def test_repair_refuses_to_overwrite(tmp_path: Path, capsys) -> None:
    damaged = cut_bag(tmp_path / "in", "room_outliers_bounded")
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert bag_repair.main([str(damaged), str(out)]) == 2
    assert capsys.readouterr().err == f"rls_bag_repair: {str(out)!r} already exists: not overwriting it\n"
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


@pytest.mark.parametrize("content", [b"", b"not a bag at all\n" * 10, None], ids=["empty", "not mcap", "header only"])
def test_nothing_recoverable_is_one_line_and_exit_2(tmp_path: Path, capsys, content: bytes | None) -> None:
    bag = tmp_path / "in"
    bag.mkdir()
    if content is None:
        content = (BAGS / "intel" / "intel.mcap").read_bytes()[:200]  # the header and the start of the 2 MB map
    (bag / "in.mcap").write_bytes(content)
    assert bag_repair.main([str(bag), str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rls_bag_repair: bag ") and err.count("\n") == 1 and "in.mcap" in err
    assert not (tmp_path / "out").exists()


def test_a_sound_bag_is_copied_and_said_so(tmp_path: Path, capsys) -> None:
    assert bag_repair.main([str(BAGS / "room_outliers_bounded"), str(tmp_path / "copy")]) == 0
    assert "was sound: nothing to repair" in capsys.readouterr().out
    assert len(list(read_bag(tmp_path / "copy"))) == 451


def test_console_script_help() -> None:
    script = Path(sys.executable).parent / "rls_bag_repair"
    command = [str(script)] if script.exists() else [sys.executable, "-m", "robot_localization_suite.tools.bag_repair"]
    result = subprocess.run([*command, "--help"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.startswith("usage: rls_bag_repair [-h] IN OUT")


def test_a_message_whose_bytes_are_damaged_is_skipped_and_the_others_kept(tmp_path: Path, capsys) -> None:
    # 3000 bytes overwritten in the middle of a bag stopped rls_bench and rls_bag_repair with an RMWError
    import numpy as np

    from robot_localization_suite.ros import conversions
    from robot_localization_suite.ros.bag import BagWriter

    bag = tmp_path / "damaged"
    with BagWriter(bag) as writer:  # uncompressed: the damage reaches a message, not a chunk's compression
        for k in range(20):
            msg = conversions.odometry_to_msg(1.0 + k, np.array([0.1 * k, 0.0, 0.0]), frame_id="odom")
            writer.write("/odom", msg, int((1.0 + k) * 1e9))
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    frame = b"\x05\x00\x00\x00odom\x00"  # frame_id "odom" as CDR: its length, then the characters
    tenth = [i for i in range(len(data)) if data.startswith(frame, i)][9]
    data[tenth:tenth + 4] = b"\xff\xff\xff\x0f"  # a length past the end of the message
    mcap.write_bytes(bytes(data))
    reading = read_bag(bag)
    kept = list(reading)
    assert len(kept) == 19 and reading.skipped == 1
    assert [m.stamp_ns for m in kept] == [int((1.0 + k) * 1e9) for k in range(20) if k != 9]
    out = tmp_path / "repaired"
    assert bag_repair.main([str(bag), str(out)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("rls_bag_repair: wrote 19 messages (/odom 19)") and "1 undecodable message(s) left out" in line
