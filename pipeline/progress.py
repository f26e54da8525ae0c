"""Progress of a long loop on stderr: a tqdm bar on a terminal, else a plain line every few
seconds, so that a log file or a CI job shows progress instead of a bar's carriage returns."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import IO, Any, TypeVar

T = TypeVar("T")

# Often enough to show a run is alive, rarely enough to keep a CI log short.
LINE_INTERVAL_S = 5.0


def progress_line(
    description: str, done: int, total: int | None, unit: str, elapsed_s: float
) -> str:
    """`replay mm-nh: 120/2761 poses (4%), 12 s`; without a total, the count alone."""
    count = f"{done}/{total} {unit}s ({100 * done // total}%)" if total else f"{done} {unit}s"
    return f"{description}: {count}, {elapsed_s:.0f} s"


class Progress:
    """Counts done items; shows a bar (terminal) or prints a line at most every
    `interval_s` and once at the end (anything else). Disabled, it shows nothing."""

    def __init__(
        self,
        total: int | None,
        description: str,
        unit: str = "item",
        *,
        enabled: bool = True,
        stream: IO[str] | None = None,
        interval_s: float = LINE_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.total, self.description, self.unit = total, description, unit
        self.stream = stream if stream is not None else sys.stderr
        self.interval_s, self.clock = interval_s, clock
        self.done = 0
        self.shown_done = 0  # the count the last line showed
        self.enabled = enabled
        self.started = self.last_line = clock()
        self.bar: Any = None
        if enabled and self.stream.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=description, unit=unit, file=self.stream)

    def update(self, count: int = 1, note: str | None = None) -> None:
        self.done += count
        if self.bar is not None:
            if note:
                self.bar.set_postfix_str(note, refresh=False)
            self.bar.update(count)
        elif self.enabled and self.clock() - self.last_line >= self.interval_s:
            self._line()

    def beat(self, doing: str) -> None:
        """A heartbeat from inside one long item (a slow keyframe): what it is `doing`, shown
        with the counts as a line when `interval_s` has passed since the last (on a terminal,
        beside the bar), so that a slow item shows progress instead of silence."""
        if not self.enabled or self.clock() - self.last_line < self.interval_s:
            return
        if self.bar is not None:
            self.last_line = self.clock()
            self.bar.set_postfix_str(doing)
        else:
            self._line(doing)

    def _line(self, doing: str | None = None) -> None:
        now = self.clock()
        self.last_line, self.shown_done = now, self.done
        line = progress_line(self.description, self.done, self.total, self.unit, now - self.started)
        self.stream.write(line + (f"; {doing}" if doing else "") + "\n")
        self.stream.flush()

    def close(self, completed: bool = True) -> None:
        """Ends the bar; without a terminal, a last line if the work `completed`, lines were
        shown before and the last one did not show this count already (a run short enough to
        show none stays quiet, so that an error found after its loop is the one line it prints;
        after a failure the error is the last word)."""
        if self.bar is not None:
            self.bar.close()
        elif (
            self.enabled
            and self.done
            and completed
            and self.last_line > self.started
            and self.shown_done != self.done
        ):
            self._line()


def track(
    items: Iterable[T],
    total: int | None,
    description: str,
    unit: str = "item",
    *,
    enabled: bool = True,
    **options: Any,
) -> Iterator[T]:
    """`items`, one at a time, with their progress shown (see `Progress`)."""
    shown = Progress(total, description, unit, enabled=enabled, **options)
    try:
        for item in items:
            yield item
            shown.update()
    except BaseException:  # the loop failed, or stopped early (GeneratorExit)
        shown.close(completed=False)
        raise
    shown.close()
