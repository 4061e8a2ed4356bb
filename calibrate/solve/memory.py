"""numpy's huge-page advice switched off for a solve that makes arrays of tens of MB afresh as it goes.

A calibration makes new problems as it goes (a subsample, the noise learnt again, outliers left out), and
each forms its frame blocks afresh: tens of MB each.  numpy advises transparent huge pages for every
array over 4 MB, so the kernel zeroes each new array 2 MB at a time on first touch: on pig_walk a tenth of
the command line's CPU samples (docs/benchmarks.md).  Within `no_huge_pages` numpy gives no such advice
(its setting restored on exit): the command line 0.3 s faster.  Keeping freed memory in the C library's
heap as well (glibc's mallopt) saved little more and raised 100 000 squat frames' peak memory (2 125
against 2 098 MB): not done.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def no_huge_pages() -> Iterator[None]:
    """numpy's transparent-huge-page advice off within the block (module docstring)."""
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
