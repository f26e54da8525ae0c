"""Local worker processes, for runs side by side (`mmslam compare --workers`, `mmslam sweep`).

Workers are started with "spawn" (GTSAM and Rerun run threads: no fork) and die with the
process that started them, however it dies: Linux's parent-death signal (elsewhere a thread
that watches the parent), so a killed command leaves no worker running on. Ctrl-C reaches the
whole process group; workers leave it to their parent, which ends the runs in progress itself
when it stops waiting for them (`process_pool`).
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import resource_tracker

_PR_SET_PDEATHSIG = 1  # prctl(2)


def die_with(parent: int) -> None:
    """A worker's start: it dies when `parent` does, and ignores Ctrl-C."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        watched = libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
    except (OSError, AttributeError):
        watched = False
    if os.getppid() != parent:  # the parent died before the signal was set up
        os._exit(1)
    if not watched:

        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(1.0)
            os._exit(1)

        threading.Thread(target=watch, daemon=True).start()


def stop_workers(pool: ProcessPoolExecutor) -> None:
    """End the runs in progress: their results will not be collected."""
    # ProcessPoolExecutor has no public way to end running work before Python 3.14.
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()


def quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker without its "leaked semaphore" warning. When
    the parent is killed, the tracker removes the pool's semaphores the parent could not, as it
    should, and then warns of them, which tells whoever killed it nothing."""
    saved = list(sys.warnoptions)
    sys.warnoptions.append("ignore::UserWarning:multiprocessing.resource_tracker")
    try:
        resource_tracker.ensure_running()  # with this interpreter's -W options
    finally:
        sys.warnoptions[:] = saved


@contextlib.contextmanager
def process_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` processes that die with this one. Leaving the block other than by
    its end (an error, Ctrl-C, SIGTERM, a consumer that stops) ends the runs in progress and
    drops those not started; at its end the pool waits for its work."""
    quiet_resource_tracker()
    pool = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=die_with,
        initargs=(os.getpid(),),
    )
    finished = False
    try:
        yield pool
        finished = True
    finally:
        if not finished:
            stop_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)
