"""One BLAS thread around IMA's small matrix products: OpenBLAS' thread start-up costs more than the product here.

Notes: docs/ima.md.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools

__all__ = ["single_thread_blas"]


@functools.lru_cache(maxsize=1)
def _openblas_local_setters() -> tuple:
    """``openblas_set_num_threads_local`` of every OpenBLAS loaded in this process (numpy's, scipy's)."""
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line})
    except OSError:
        return ()
    setters = []
    for path in paths:
        try:
            setter = ctypes.CDLL(path).openblas_set_num_threads_local
        except (OSError, AttributeError):
            continue
        setter.argtypes = [ctypes.c_int]
        setter.restype = ctypes.c_int
        setters.append(setter)
    return tuple(setters)


@contextlib.contextmanager
def single_thread_blas():
    """Run the block's matrix products on the calling thread only.

    The IMA products are small (72 x 58 by 58 x 7000): OpenBLAS' threads cost
    more than they bring, and on a loaded 2-core machine their spin-waiting
    made an update 5-30x slower (measured). Uses OpenBLAS' thread-local
    setting, restored on exit; a no-op where no OpenBLAS is found.
    """
    setters = _openblas_local_setters()
    previous = [setter(1) for setter in setters]
    try:
        yield
    finally:
        for setter, count in zip(setters, previous, strict=True):
            setter(count)
