"""``rls_bag_repair IN OUT``: rewrite a damaged rosbag2 MCAP bag as a sound one.

IN is read as ``ros/bag.py`` reads any bag (a bag cut short, without footer, or with a missing or
stale metadata.yaml gives back every complete message before the damage); the messages go into
the new bag OUT, a complete MCAP with a new metadata.yaml (``BagWriter``). Notes:
``docs/benchmark.md``, "Damaged bags".
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import BagError

if TYPE_CHECKING:
    from ..ros.bag_recovery import Recovery

__all__ = ["RepairReport", "repair", "main"]


@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair` wrote, and what reading the damaged bag found."""

    source: Path
    target: Path
    topic_counts: dict[str, int]
    recovery: Recovery | None  # None: the source read normally, the target is a copy
    skipped: int = 0  # messages whose bytes could not be decoded, left out

    def summary(self) -> str:
        total = sum(self.topic_counts.values())
        topics = ", ".join(f"{topic} {count}" for topic, count in self.topic_counts.items())
        head = f"rls_bag_repair: wrote {total} messages ({topics}) into {str(self.target)!r}"
        left_out = f"; {self.skipped} undecodable message(s) left out" if self.skipped else ""
        if self.recovery is None:
            return (f"{head}{left_out}" if self.skipped else
                    f"{head}; {str(self.source)!r} was sound: nothing to repair")
        return f"{head}; from {str(self.source)!r}: {self.recovery.summary()}{left_out}"


def repair(source: str | os.PathLike[str], target: str | os.PathLike[str]) -> RepairReport:
    """Write every message readable from the bag ``source`` into the new bag ``target``.

    The bag is written beside ``target`` and renamed into place when complete, so a failed
    repair leaves no half bag behind.

    Raises:
        BagError: ``target`` exists, or ``source`` holds nothing readable.
    """
    from ..ros.bag import BagWriter, read_bag

    source, target = Path(source), Path(target)
    if target.exists():
        raise BagError(f"{str(target)!r} already exists: not overwriting it")
    messages = read_bag(source)
    recovery = messages.recovery
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    counts: dict[str, int] = {}
    try:
        with BagWriter(staging / target.name, compress=recovery is not None and recovery.compression == "zstd") as writer:
            for item in messages:
                writer.write(item.topic, item.msg, item.stamp_ns)
                counts[item.topic] = counts.get(item.topic, 0) + 1
        if not counts:
            raise BagError(f"bag {str(source)!r} holds no message: nothing to write")
        if target.exists():
            raise BagError(f"{str(target)!r} appeared while repairing: not overwriting it")
        (staging / target.name).rename(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return RepairReport(source, target, counts, recovery, messages.skipped)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rls_bag_repair",
        description="Rewrite a damaged rosbag2 MCAP bag (cut short, no footer, metadata.yaml missing or stale) "
        "as a sound one holding every complete message before the damage.",
        epilog="Exit codes: 0 written; 1 OUT cannot be written; 2 nothing recoverable, OUT exists, or bad arguments.",
    )
    parser.add_argument("input", metavar="IN", type=Path, help="the damaged bag directory (or its .mcap file)")
    parser.add_argument("output", metavar="OUT", type=Path, help="the new bag directory; must not exist")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    bag_log = logging.getLogger("robot_localization_suite.ros.bag")
    level = bag_log.level
    bag_log.setLevel(logging.ERROR)  # its warning about the damage would repeat the report printed here
    try:
        report = repair(args.input, args.output)
    except BagError as exc:
        print("rls_bag_repair: " + " ".join(str(exc).split()), file=sys.stderr)  # one line
        return 2
    except OSError as exc:
        print(f"rls_bag_repair: cannot write {str(args.output)!r}: {exc}", file=sys.stderr)
        return 1
    finally:
        bag_log.setLevel(level)
    print(report.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
