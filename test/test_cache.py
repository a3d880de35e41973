"""The shared on-disk cache helpers (core/cache.py): directory, budget, least-recently-used pruning, reading."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest
from cache_damage import damaged

from robot_localization_suite.core.cache import (
    CACHE_BUDGET_ENV,
    DEFAULT_CACHE_BUDGET_MB,
    cache_budget_bytes,
    default_cache_dir,
    load_cached,
    mark_used,
    prune_cache,
)
from robot_localization_suite.core.errors import CacheError

MB = 1024 * 1024


def _file(directory: Path, name: str, size: int, mtime: float) -> Path:
    path = directory / name
    path.write_bytes(b"x" * size)
    os.utime(path, (mtime, mtime))
    return path


def test_the_cache_directory_follows_rls_cache_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("RLS_CACHE_DIR", str(tmp_path))
    assert default_cache_dir() == tmp_path
    monkeypatch.delenv("RLS_CACHE_DIR")
    assert default_cache_dir() == Path.home() / ".cache" / "robot_localization_suite"


def test_the_budget_is_the_setting_else_the_environment_else_the_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(CACHE_BUDGET_ENV, raising=False)
    assert cache_budget_bytes(0.0) == int(DEFAULT_CACHE_BUDGET_MB * MB)
    assert cache_budget_bytes(3.0) == 3 * MB
    monkeypatch.setenv(CACHE_BUDGET_ENV, "0.5")
    assert cache_budget_bytes(0.0) == MB // 2
    assert cache_budget_bytes(3.0) == 3 * MB  # an explicit setting wins over the environment
    monkeypatch.setenv(CACHE_BUDGET_ENV, "lots")
    with pytest.raises(ValueError, match="RLS_CACHE_BUDGET_MB.*'lots'"):
        cache_budget_bytes(0.0)
    with pytest.raises(ValueError, match="-1.0"):
        cache_budget_bytes(-1.0)


def test_pruning_deletes_the_least_recently_used_files_down_to_the_budget(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # five 100-byte files used at t = 1000 (oldest) .. 5000; the one just written is the oldest by mtime
    # (a clock step back must not make it a victim); a tmp file of a concurrent writer and another kind of file
    written = _file(tmp_path, "e_written.npz", 100, 1000.0)
    old = [_file(tmp_path, f"{name}.npz", 100, mtime) for name, mtime in (("a", 2000.0), ("b", 3000.0), ("c", 4000.0))]
    newest = _file(tmp_path, "d.npz", 100, 5000.0)
    in_progress = _file(tmp_path, "f.npz.tmp123", 500, 500.0)
    other = _file(tmp_path, "notes.txt", 500, 500.0)
    with caplog.at_level(logging.INFO, logger="robot_localization_suite.core.cache"):
        removed = prune_cache(tmp_path, 250, keep=written)
    # 500 bytes of .npz, budget 250: drop a, b, c (oldest first) -> written + d = 200 bytes
    assert removed == old
    assert written.is_file() and newest.is_file() and in_progress.is_file() and other.is_file()
    assert not any(path.exists() for path in old)
    messages = " ".join(record.getMessage() for record in caplog.records)
    assert all(str(path) in messages for path in old)
    # within the budget now: nothing more goes
    assert prune_cache(tmp_path, 250, keep=written) == []


def test_the_file_just_written_is_kept_even_alone_over_the_budget(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    written = _file(tmp_path, "big.npz", 300, 2000.0)
    older = _file(tmp_path, "old.npz", 100, 1000.0)
    lines: list[str] = []
    with caplog.at_level(logging.WARNING, logger="robot_localization_suite.core.cache"):
        removed = prune_cache(tmp_path, 200, keep=written, log=lines.append)
    assert removed == [older] and written.is_file()
    assert len(lines) == 1 and "old.npz" in lines[0]
    assert any("still holds" in record.getMessage() for record in caplog.records)


def test_a_cache_hit_makes_a_file_the_most_recently_used(tmp_path: Path) -> None:
    hit = _file(tmp_path, "hit.npz", 100, 1000.0)
    other = _file(tmp_path, "other.npz", 100, 2000.0)
    written = _file(tmp_path, "new.npz", 100, 3000.0)
    mark_used(hit)
    assert hit.stat().st_mtime > 3000.0
    assert prune_cache(tmp_path, 200, keep=written) == [other]
    assert hit.is_file()
    mark_used(tmp_path / "missing.npz")  # a file pruned by another process meanwhile: no error


def _read(path: Path) -> int:
    with np.load(path, allow_pickle=False) as archive:
        return int(archive["value"].sum())


def test_load_cached_reads_a_good_file_and_marks_it_used(tmp_path: Path) -> None:
    path = tmp_path / "good.npz"
    np.savez(path, value=np.arange(10))
    os.utime(path, (1000.0, 1000.0))
    warnings: list[str] = []
    assert load_cached(path, _read, what="test", warn=warnings.append) == 45
    assert path.stat().st_mtime > 1000.0 and not warnings
    assert load_cached(tmp_path / "missing.npz", _read, what="test", warn=warnings.append) is None
    assert not warnings  # no file is a miss, not a fault


def test_load_cached_warns_once_naming_a_damaged_file_whatever_it_raises(tmp_path: Path) -> None:
    path = tmp_path / "damaged.npz"
    np.savez(path, value=np.arange(10))
    for how, content in damaged(path.read_bytes()).items():
        path.write_bytes(content)
        warnings: list[str] = []
        assert load_cached(path, _read, what="Test", warn=warnings.append, then="redoing it") is None, how
        assert len(warnings) == 1, (how, warnings)
        assert warnings[0].startswith(f"Test cache {str(path)!r} is unreadable: ") and warnings[0].endswith(
            "; redoing it"), (how, warnings)


def test_load_cached_passes_on_a_cache_errors_own_message(tmp_path: Path) -> None:
    path = tmp_path / "stale.npz"
    path.write_bytes(b"anything")

    def stale(_: Path) -> int:
        raise CacheError(f"cache {str(path)!r} was built with other settings")

    warnings: list[str] = []
    assert load_cached(path, stale, what="Test", warn=warnings.append) is None
    assert warnings == [f"cache {str(path)!r} was built with other settings; rebuilding it"]


def test_the_source_digest_follows_the_code_of_the_modules(tmp_path: Path) -> None:
    import types

    from robot_localization_suite.core import cache

    def module(name: str, text: str) -> types.ModuleType:
        path = tmp_path / f"{name}.py"
        path.write_text(text)
        made = types.ModuleType(name)
        made.__file__ = str(path)
        return made

    first, same, edited = module("a", "X = 1\n"), module("b", "X = 1\n"), module("c", "X = 2\n")
    assert cache.source_digest(first) == cache.source_digest(same)  # the content, not the file's name
    assert cache.source_digest(first) != cache.source_digest(edited)
    assert cache.source_digest(first, edited) != cache.source_digest(edited, first)

