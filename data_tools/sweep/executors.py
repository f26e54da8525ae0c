"""Where the runs of a sweep execute: in this process, a local process pool, or a Dask cluster.

Each executor takes the tasks and yields their outcomes as they complete; the sweep does not
care which one ran them. Runs are CPU-bound Python and GTSAM, so the local pool uses processes
(started with "spawn": no state inherited from the driver). Pool workers die with the sweep,
however it dies, and a sweep that is stopped ends the runs in progress. With Dask, every worker
must see the output folder at the same path (a shared file system) to keep the runs' files;
the metrics come back to the driver either way.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool

from data_tools.sweep.work import RunOutcome, RunTask, run_task
from pipeline.errors import InputError


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_in_process(tasks: Sequence[RunTask]) -> Iterator[RunOutcome]:
    for task in tasks:
        yield run_task(task)


_PR_SET_PDEATHSIG = 1  # prctl(2)


def _die_with(parent: int) -> None:
    """A pool worker's start: it dies when the sweep does, whatever kills the sweep (Linux's
    parent-death signal; elsewhere a thread that watches for the parent to go), and leaves
    Ctrl-C to the sweep, which stops the workers itself."""
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


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """End the runs in progress: their results will not be collected."""
    # ProcessPoolExecutor has no public way to end running work before Python 3.14.
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()


def run_in_pool(tasks: Sequence[RunTask], workers: int) -> Iterator[RunOutcome]:
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=context, initializer=_die_with, initargs=(os.getpid(),)
    )
    futures = [pool.submit(run_task, task) for task in tasks]
    finished = False
    try:
        for future in as_completed(futures):
            yield future.result()
        finished = True
    except BrokenProcessPool:
        raise RuntimeError(
            "a worker process died abruptly (a crash, or out of memory); the runs finished "
            "so far are kept: run the sweep again to resume"
        ) from None
    finally:  # interrupted, or the consumer stopped: drop what has not started, end the rest
        if not finished:
            _stop_workers(pool)
        pool.shutdown(wait=True, cancel_futures=True)


def run_on_dask(tasks: Sequence[RunTask], address: str) -> Iterator[RunOutcome]:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise InputError("--dask needs the package distributed: pip install distributed") from None
    try:
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--dask {address}: cannot connect ({exc})") from None
    try:
        futures = [client.submit(run_task, task, pure=False) for task in tasks]
        try:
            for future in dask_completed(futures):
                yield future.result()
        finally:
            client.cancel([f for f in futures if not f.done()])
    finally:
        client.close()


def execute(
    tasks: Sequence[RunTask], *, workers: int, dask_address: str | None
) -> Iterator[RunOutcome]:
    """The outcomes of `tasks`, in the order they complete."""
    if not tasks:
        return iter(())
    if dask_address is not None:
        return run_on_dask(tasks, dask_address)
    if workers == 1 or len(tasks) == 1:
        return run_in_process(tasks)
    return run_in_pool(tasks, min(workers, len(tasks)))
