"""The process's allocator set for a solve that allocates and drops arrays of tens of MB every iteration.

A calibration makes new problems as it goes (a subsample, the noise learnt again, outliers left out), and
each forms its frame blocks afresh: tens of MB each on a long trial.  By default glibc hands blocks over
128 kB-32 MB straight back to the system when freed, and numpy asks for transparent huge pages on
every large array, so every fresh array is page-faulted and zeroed by the kernel 2 MB at a time: on
pig_walk a tenth of the run's CPU time (docs/benchmarks.md).  Within `reused_memory`, arrays up to 32 MB
come from the heap and freed memory is kept for reuse (up to TRIM_BYTES), and numpy does not ask for huge
pages (restored on exit).  Where the C library has no `mallopt` (not glibc) only the second applies.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Iterator
from contextlib import contextmanager

MMAP_THRESHOLD = 32 * 2**20  # blocks larger than this still come from (and go back to) the system; glibc's maximum
TRIM_BYTES = 256 * 2**20  # free memory at the top of the heap kept for reuse up to this
TOP_PAD = 64 * 2**20  # the heap grows by at least this much at a time
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3  # glibc's mallopt parameters (malloc.h)


@functools.cache
def _tune_malloc() -> bool:
    """glibc's thresholds set once per process (they are not restored: keeping freed memory for reuse is
    harmless after a solve); False where the C library has no mallopt."""
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library the interpreter runs on
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return all(mallopt(k, v) == 1 for k, v in ((_M_MMAP_THRESHOLD, MMAP_THRESHOLD), (_M_TRIM_THRESHOLD, TRIM_BYTES),
                                               (_M_TOP_PAD, TOP_PAD)))


@contextmanager
def reused_memory() -> Iterator[None]:
    """Large arrays' memory reused within the block instead of faulted in afresh (module docstring)."""
    _tune_malloc()
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:  # another numpy layout: its default kept
        yield
        return
    before = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(before)
