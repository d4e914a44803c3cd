"""The local process pool of `plan` and `batch` (campaign.jobs.plan.executor_for): workers that die with their
parent, and which chunk each worker runs, so that a worker's death costs its own chunk only (campaign.jobs.batch);
a chunk's call sealed as bytes, that a Dask scheduler passes on without importing what it needs.

A worker must not outlive the process that made the pool: killed (SIGKILL, an out-of-memory kill), that process
cannot shut its pool down, and its workers, blocked on a queue whose write end they hold themselves, would wait
forever. Each worker asks the kernel for SIGKILL when its parent dies (Linux prctl(PR_SET_PDEATHSIG), through
ctypes), rather than a watchdog thread polling os.getppid(): the kernel's signal reaches a worker inside a long
computation that holds the GIL (a scipy Fortran routine), at once, with no thread and no polling period in every
worker. Its catch: "parent" is the thread that forked the worker (prctl(2)); the pool's workers are forked by the
thread that submits to it (concurrent.futures: on the first submit, or on each, with a spawn context), the thread
that runs the whole map and waits for it. Where prctl is missing (not Linux), the watchdog thread does the job,
polling every PARENT_POLL_S.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.sharedctypes import RawArray

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
PARENT_POLL_S = 1.0  # the watchdog thread's period where prctl is missing

_started = None  # this worker's view of the map's RawArray: chunk index -> pid of the worker that took it


def _die_with_parent(parent: int | None) -> None:
    """SIGKILL this process when its parent dies; if the parent (None: whoever it is now) is already gone, exit
    now."""
    parent = parent or os.getppid()  # a forkserver's worker: the server, which ends when its maker does
    libc = None
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc is not None and hasattr(libc, "prctl") and libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0:
        if os.getppid() != parent:  # the parent died before prctl: no signal will come
            os._exit(1)
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _worker_init(parent: int | None, started) -> None:
    global _started
    _started = started
    _die_with_parent(parent)


def local_pool(workers: int, started=None) -> ProcessPoolExecutor:
    """A process pool whose workers die with this process; `started` (chunk_marks) records which worker took which
    chunk (run_marked)."""
    forked_here = multiprocessing.get_start_method() in ("fork", "spawn")
    return ProcessPoolExecutor(
        max_workers=workers, initializer=_worker_init, initargs=(os.getpid() if forked_here else None, started)
    )


def chunk_marks(n: int):
    """Shared memory (no lock: one int written by one worker) for n chunks' worker pids, 0 until taken."""
    return RawArray("i", n)


def sealed(fn: Callable[..., list], index: int, chunk: list, args: tuple) -> bytes:
    """One chunk's call as bytes for run_marked. A Dask scheduler unpickles the tasks it is sent: given the call
    itself, it would import what fn's module imports (numpy, scipy, pinocchio: 10 s on a loaded machine, its event
    loop blocked the while, as a stopped scheduler's is); bytes it passes on untouched, to the worker that runs
    them."""
    return pickle.dumps((fn, index, chunk, args))


def run_marked(call: bytes) -> list:
    """fn(chunk, *args) of a sealed call, in a pool worker: the worker's pid marked against the chunk's index
    first."""
    fn, index, chunk, args = pickle.loads(call)  # noqa: S301 - our own call, sealed by this process
    if _started is not None:
        _started[index] = os.getpid()
    return fn(chunk, *args)


def how_it_died(exitcode: int | None) -> str | None:
    """'signal 9' or 'exit code 3' of a worker's exit code; None while it runs or when it ended normally."""
    if exitcode is None or exitcode == 0:
        return None
    return f"signal {-exitcode}" if exitcode < 0 else f"exit code {exitcode}"
