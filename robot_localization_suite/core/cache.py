"""The on-disk precomputation cache shared by the localizers: where it lives and how it is kept bounded.

Every localizer that precomputes something from a map (IR's index, PIL's
pseudo-images) writes one file per map + parameter combination into its own
subdirectory of :func:`default_cache_dir`. After writing a new file it calls
:func:`prune_cache` on that subdirectory: the least recently used files
(modification time, refreshed by :func:`mark_used` on every hit) are deleted
until the subdirectory fits :func:`cache_budget_bytes`; the file just written
is never deleted, and only names matching the given pattern are considered.
:func:`load_cached` reads a cache file: a corrupt one (any error reading it) is
reported by one warning naming it, then rebuilt by the caller.

:func:`log_kernel_compilations` makes a cold start say which compiled kernel it is compiling (numba
keeps them in ``numba/`` of the same directory; a warm start loads them and says nothing).

Notes (why modification time, per-directory budgets, concurrent writers): docs/ir.md, "Cache".
"""

from __future__ import annotations

import functools
import hashlib
import logging
import math
import os
import struct
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from .errors import CacheError

__all__ = [
    "CACHE_BUDGET_ENV",
    "DEFAULT_CACHE_BUDGET_MB",
    "cache_budget_bytes",
    "default_cache_dir",
    "load_cached",
    "log_kernel_compilations",
    "mark_used",
    "npz_member_memmap",
    "prune_cache",
    "source_digest",
]

_LOG = logging.getLogger(__name__)

#: Environment variable giving the budget of each cache subdirectory [MB].
CACHE_BUDGET_ENV = "RLS_CACHE_BUDGET_MB"
#: Budget of each cache subdirectory when neither a setting nor the environment gives one [MB]:
#: room for 5-15 IR indexes of the maps in config/maps (120-400 MB each).
DEFAULT_CACHE_BUDGET_MB = 2048.0

_BYTES_PER_MB = 1024 * 1024
_T = TypeVar("_T")


def default_cache_dir() -> Path:
    """``$RLS_CACHE_DIR`` or ``~/.cache/robot_localization_suite``."""
    env = os.environ.get("RLS_CACHE_DIR", "")
    return Path(env) if env else Path.home() / ".cache" / "robot_localization_suite"


def cache_budget_bytes(budget_mb: float = 0.0) -> int:
    """The size budget [bytes] of one cache subdirectory.

    Args:
        budget_mb: the budget [MB, 2**20 bytes]; 0: ``$RLS_CACHE_BUDGET_MB`` when set,
            else :data:`DEFAULT_CACHE_BUDGET_MB`.

    Raises:
        ValueError: on a negative or non-finite budget, or an unreadable ``$RLS_CACHE_BUDGET_MB``.
    """
    source = "budget_mb"
    if budget_mb == 0.0:
        env = os.environ.get(CACHE_BUDGET_ENV, "").strip()
        if env:
            source = f"${CACHE_BUDGET_ENV}"
            try:
                budget_mb = float(env)
            except ValueError:
                raise ValueError(f"${CACHE_BUDGET_ENV} must be a number of megabytes, got {env!r}") from None
        else:
            budget_mb = DEFAULT_CACHE_BUDGET_MB
    if not (math.isfinite(budget_mb) and budget_mb >= 0.0):
        raise ValueError(f"{source} must be >= 0 and finite [MB], got {budget_mb!r}")
    return int(budget_mb * _BYTES_PER_MB)


def mark_used(path: Path) -> None:
    """Record a cache hit on ``path`` (its modification time becomes now) for :func:`prune_cache`."""
    try:
        os.utime(path)
    except OSError as exc:  # read-only cache: it is still usable, only its order is not kept
        _LOG.debug("could not mark %s as used: %s", path, exc)


def load_cached(
    path: Path, load: Callable[[Path], _T], *, what: str, warn: Callable[[str], None], then: str = "rebuilding it"
) -> _T | None:
    """``load(path)`` (a hit: marked used), or None when there is no file or it cannot be used.

    Any error from ``load`` means a corrupt or stale file, which the caller then rebuilds: it is reported
    by exactly one ``warn(text)`` naming the file (a :class:`CacheError`'s own message, or
    ``"<what> cache '<path>' is unreadable: <error>"``) followed by ``; <then>``. A garbled zip header
    raises NotImplementedError or a tokenizer error in ``np.load``, not only OSError or ValueError.
    """
    if not path.is_file():
        return None
    try:
        value = load(path)
    except Exception as exc:  # noqa: BLE001 - whatever a damaged file raises, the cache is rebuilt
        reason = str(exc) if isinstance(exc, CacheError) else (
            f"{what} cache {str(path)!r} is unreadable: {type(exc).__name__}: {exc}")
        warn(f"{reason}; {then}")
        return None
    mark_used(path)
    return value


def prune_cache(
    directory: Path,
    budget_bytes: int,
    *,
    keep: Path,
    pattern: str = "*.npz",
    log: Callable[[str], None] | None = None,
) -> list[Path]:
    """Delete the least recently used ``pattern`` files of ``directory`` until they total at most ``budget_bytes``.

    Args:
        directory: one cache subdirectory (not searched recursively).
        budget_bytes: the size the files may total [bytes].
        keep: the file just written; never deleted.
        pattern: glob of the cache files.
        log: ``log(text)`` for each deletion; default: this module's logger at INFO.

    Returns:
        The deleted files, oldest first.
    """
    emit = log or _LOG.info
    entries = []
    for path in directory.glob(pattern):
        try:
            status = path.stat()
        except OSError:  # deleted meanwhile by another process
            continue
        if path.is_file():
            entries.append((status.st_mtime, status.st_size, path))
    total = sum(size for _, size, _ in entries)
    if total <= budget_bytes:
        return []
    keep_resolved = keep.resolve()
    removed = []
    for _, size, path in sorted(entries, key=lambda entry: (entry[0], str(entry[2]))):
        if total <= budget_bytes:
            break
        if path.resolve() == keep_resolved:
            continue
        try:
            path.unlink()
        except FileNotFoundError:  # another process pruned it first
            total -= size
            continue
        except OSError as exc:
            _LOG.warning("could not delete the cache file %s: %s", path, exc)
            continue
        total -= size
        removed.append(path)
        emit(f"cache over its {budget_bytes / _BYTES_PER_MB:.1f} MB budget: deleted the least recently used {path} "
             f"({size / _BYTES_PER_MB:.1f} MB)")
    if total > budget_bytes:
        _LOG.warning(
            "cache %s still holds %.1f MB after pruning, over its %.1f MB budget (the file just written, %s, is kept)",
            directory, total / _BYTES_PER_MB, budget_bytes / _BYTES_PER_MB, keep,
        )
    return removed


def npz_member_memmap(path: Path, name: str) -> NDArray[Any] | None:
    """A read-only memory map of the ``.npy`` member ``name`` of an ``.npz``; None if it is compressed.

    ``np.load`` cannot map the members of an archive; each member of an uncompressed one is a
    plain ``.npy`` at a known offset (after its zip local header), which ``np.memmap`` can.

    Raises:
        KeyError: no such member. ValueError: a member that is not a plain ``.npy``.
    """
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(f"{name}.npy")
    if info.compress_type != zipfile.ZIP_STORED:
        return None
    with open(path, "rb") as stream:
        stream.seek(info.header_offset)
        local = stream.read(30)
        if len(local) != 30 or local[:4] != b"PK\x03\x04":
            raise ValueError(f"member {name!r} has no local zip header")
        name_length, extra_length = struct.unpack("<HH", local[26:30])
        stream.seek(info.header_offset + 30 + name_length + extra_length)
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(stream)
        else:
            raise ValueError(f"member {name!r} has .npy version {version}")
        if dtype.hasobject:
            raise ValueError(f"member {name!r} holds Python objects")
        offset = stream.tell()
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")


_compile_listener_lock = threading.Lock()
_compile_listener_installed = False


def log_kernel_compilations() -> None:
    """From now on, log at INFO each numba kernel compiled because the cache lacks it, and how long it took.

    Only the outermost compilation of a kernel is reported (not the helpers it inlines). Loads numba.
    Idempotent: a process (several nodes in one container) installs it once.
    """
    global _compile_listener_installed
    with _compile_listener_lock:
        if _compile_listener_installed:
            return
        from numba.core import event

        depth = threading.local()

        class _Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                depth.value = getattr(depth, "value", 0) + 1
                if depth.value == 1:
                    depth.started = time.perf_counter()
                    _LOG.info("compiling %s (not in the kernel cache %s yet)", _kernel_name(ev), _numba_cache_dir())

            def on_end(self, ev: Any) -> None:
                depth.value -= 1
                if depth.value == 0:
                    _LOG.info("compiled %s in %.1f s", _kernel_name(ev), time.perf_counter() - depth.started)

        event.register("numba:compile", _Listener())
        _compile_listener_installed = True


def _kernel_name(ev: Any) -> str:
    function = ev.data["dispatcher"].py_func
    return f"{function.__module__.removeprefix('robot_localization_suite.')}.{function.__qualname__}"


def _numba_cache_dir() -> str:
    return os.environ.get("NUMBA_CACHE_DIR", "") or str(default_cache_dir() / "numba")


@functools.cache
def _file_digest(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def source_digest(*modules: ModuleType) -> str:
    """A short hash of the source files of ``modules``: part of a cache key, so that a file built by other code
    (another commit, a scratch worktree sharing the cache directory) is never read as this code's."""
    digest = hashlib.sha256()
    for module in modules:
        path = getattr(module, "__file__", None)
        digest.update((_file_digest(path) if path else module.__name__).encode())
    return digest.hexdigest()[:16]
