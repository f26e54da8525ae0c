"""Errors the command line turns into a one-line message: exit status 2 for bad input, 1 for a
solver or a worker process that failed on good input, 143 for SIGTERM (`Terminated`)."""

import contextlib
import errno
import signal
import threading
from collections.abc import Iterator
from types import FrameType

# The system failed, not the path the user gave: a full disk, a quota, a file-size limit, I/O.
SYSTEM_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.ENOMEM})


class InputError(Exception):
    """Bad input or usage: the message is one line naming what is wrong and where."""


class LogError(InputError):
    """A detection log that breaks the contract (docs/log-format.md)."""

    def __init__(self, path: str, reason: str, topic: str | None = None, index: int | None = None):
        where = f"{topic} message {index}: " if topic is not None and index is not None else ""
        if topic is not None and index is None:
            where = f"{topic}: "
        super().__init__(f"bad log {path}: {where}{reason}")
        self.detail = where + reason  # what is wrong and where, without the file
        self.path = path
        self.topic = topic
        self.index = index
        self.reason = reason


class SolverError(RuntimeError):
    """iSAM2 could not solve the graph (e.g. an indeterminate system after divergence)."""


class WorkerError(RuntimeError):
    """A worker process died without an answer (killed, out of memory, a crash)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM: what is under way stops as on Ctrl-C (a KeyboardInterrupt), and the command
    line says it was terminated (exit status 143, as a shell reports a process SIGTERM ends)."""


def first_line(text: str) -> str:
    """The first non-blank line: GTSAM's messages open with a blank line and run to ten."""
    return next((line for line in text.splitlines() if line.strip()), "")


def describe_os_error(exc: OSError) -> tuple[str, int]:
    """One line naming the path and what the system said, and the exit status: 1 when the
    system failed (a full disk), 2 when the path was wrong (under a file, not allowed)."""
    where = exc.filename if exc.filename is not None else "a file"
    reason = exc.strerror or first_line(str(exc)) or type(exc).__name__
    return f"{where}: {reason}", 1 if exc.errno in SYSTEM_ERRNOS else 2


@contextlib.contextmanager
def terminated_on_sigterm() -> Iterator[None]:
    """Within the block, SIGTERM (a scheduler or `kill` stopping the process) raises
    `Terminated` in the main thread, so that what is under way ends as on Ctrl-C: outputs not
    yet complete are discarded, workers stopped. Elsewhere than in the main thread (where
    signals are not delivered to Python), nothing changes."""

    def terminate(signum: int, frame: FrameType | None) -> None:
        raise Terminated

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
