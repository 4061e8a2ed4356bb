"""Work run ahead on the other core, in a forked process.

Parts of a calibration hold the GIL most of their time (frame-by-frame inverse kinematics, the short
solves of the start's race): threads cannot run two of them at once, and on pig_walk they took a fifth
of the command line with one core idle.  `run_ahead(values)` forks the process and lets the child compute
the iterator's values while the caller goes on with its own work; each value comes back pickled over a
pipe when the caller asks for it, in order, exactly as the iterator in the caller would have made it
(same code, same data, same arithmetic: the child runs its compiled loops serially, as a worker thread
does, and they give the same bits either way).  Closing the iterator before its end kills the child:
work started on a guess (the race's second candidate, when the first fits at once) costs no wall time.

Only on Linux with two or more cores, and never from inside a child or a worker thread; elsewhere the
iterator is returned as it is, to be computed in the caller when asked.  A child prints nothing (its
callers pass it no progress) and leaves by os._exit: no atexit handler, no buffered output, runs twice.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import BinaryIO, TypeVar

import numpy as np

from .assembly import WORKER_NAME, WORKERS, worker_thread

T = TypeVar("T")

__all__ = ["ahead_split", "can_run_ahead", "idle_core", "iter_after", "run_ahead"]

#: Jobs of less work than this in all (frames, for `calibrate ik`'s trials) are not split: the fork and the
#: second process's own kinematics would take what the other core saves.
AHEAD_LEAST = 500.0


def can_run_ahead() -> bool:
    """Whether run_ahead forks here: Linux, two or more cores, and not within a worker or a child."""
    return sys.platform.startswith("linux") and hasattr(os, "fork") and WORKERS >= 2 and not worker_thread()


def idle_core() -> bool:
    """Whether a core is idle now, for work run ahead on a guess (the start race's second candidate, not needed
    when the first fits at once): fewer tasks running on the machine, this one among them, than the cores this
    process may use (Linux's /proc/stat procs_running).  When the other core is busy (two calibrations at once,
    a test suite in two processes) the guess would only take its time; the answer is the same bits either way.
    True where it cannot be read."""
    try:
        with open("/proc/stat", encoding="ascii") as stat:
            for line in stat:
                if line.startswith("procs_running"):
                    return int(line.split()[1]) < len(os.sched_getaffinity(0))
    except (OSError, ValueError, AttributeError):
        pass
    return True


def ahead_split(work: Sequence[float], least: float = AHEAD_LEAST) -> int:
    """Where to cut jobs of sizes `work` (in their order) so that the caller does the first part and a child run
    ahead (run_ahead) the rest, the two about equal: the index of the first job run ahead, or len(work) where none
    is (one job, less than `least` in all, or run_ahead cannot fork here)."""
    n = len(work)
    total = float(sum(work))
    if n < 2 or total < least or not can_run_ahead():
        return n
    done = 0.0
    best, gap = 1, np.inf
    for k in range(1, n):  # the caller's part: jobs [0, k)
        done += float(work[k - 1])
        if abs(2.0 * done - total) < gap:
            best, gap = k, abs(2.0 * done - total)
    return best


def iter_after(make: Callable[[], Sequence[T]]) -> Iterator[T]:
    """The values `make()` returns, each yielded once all are made: run ahead (run_ahead), the child then does all
    its work before it sends the first, which it cannot do before the caller reads it (a pipe holds 64 kB)."""
    yield from make()


def run_ahead(values: Iterator[T]) -> Iterator[T]:
    """The iterator's values, computed in a forked child from now on (module docstring); the iterator
    itself where that is not possible.  The child's exception, if it raises one, is raised at the value
    that raised it.  `values` must not be used by the caller afterwards."""
    if not can_run_ahead():
        return values
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()  # nothing buffered is written twice
        except (AttributeError, OSError, ValueError):
            pass
    r, w = os.pipe()
    with warnings.catch_warnings():
        # Python 3.12 warns on a fork while threads run: the worker pool's threads are idle (no lock of
        # theirs is held; the child never uses the pool, its loops run serially).
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:  # the child: compute, send, leave
        try:
            os.close(r)
            threading.current_thread().name = f"{WORKER_NAME}-process"
            with os.fdopen(w, "wb") as out:
                _send_all(values, out)
        finally:
            os._exit(0)
    os.close(w)
    return _Ahead(pid, os.fdopen(r, "rb"))


def _send_all(values: Iterator, out: BinaryIO) -> None:
    """Each value pickled to `out` as it is made, then the end (or the exception raised)."""
    try:
        for v in values:
            pickle.dump(("value", v), out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()
        message = ("end", None)
    except BaseException as exc:  # noqa: BLE001 - every failure is the caller's to raise
        message = ("error", exc)
    try:
        pickle.dump(message, out, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception:  # an exception that does not pickle: its words
        pickle.dump(("error", RuntimeError(repr(message[1]))), out, protocol=pickle.HIGHEST_PROTOCOL)


class _Ahead(Iterator[T]):
    """The caller's side: values read from the child in order; close() kills and reaps it."""

    def __init__(self, pid: int, pipe: BinaryIO):
        self._pid: int | None = pid
        self._pipe = pipe

    def __next__(self) -> T:
        if self._pid is None:
            raise StopIteration
        try:
            kind, value = pickle.load(self._pipe)
        except EOFError:
            pid = self._pid
            self.close()
            raise RuntimeError(f"calibrate: the process computing ahead ({pid}) ended without its result") from None
        if kind == "value":
            return value
        self.close()
        if kind == "error":
            raise value
        raise StopIteration

    def close(self) -> None:
        """Stop the child (if still running) and reap it."""
        if self._pid is None:
            return
        pid, self._pid = self._pid, None
        self._pipe.close()
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(pid, 0)

    def __del__(self) -> None:
        self.close()
