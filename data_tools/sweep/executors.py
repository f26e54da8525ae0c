"""Where the runs of a sweep execute: in this process, a local process pool, or a Dask cluster.

Each executor takes the tasks and yields their outcomes as they complete; the sweep does not
care which one ran them. Runs are CPU-bound Python and GTSAM, so the local pool uses processes
(`pipeline.workers`: started with "spawn", no state inherited from the driver). Pool workers
die with the sweep, however it dies, and a sweep that is stopped ends the runs in progress.
With Dask, every worker must see the output folder at the same path (a shared file system) to
keep the runs' files; the metrics come back to the driver either way.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool

from data_tools.sweep.work import RunOutcome, RunTask, run_task
from pipeline.errors import InputError, WorkerError
from pipeline.workers import process_pool


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_in_process(tasks: Sequence[RunTask]) -> Iterator[RunOutcome]:
    for task in tasks:
        yield run_task(task)


def run_in_pool(tasks: Sequence[RunTask], workers: int) -> Iterator[RunOutcome]:
    with process_pool(workers) as pool:
        futures = [pool.submit(run_task, task) for task in tasks]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BrokenProcessPool:
            raise WorkerError(
                "a worker process died abruptly (killed, out of memory, or a crash); the runs "
                "finished so far are kept: run the sweep again to resume"
            ) from None


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
