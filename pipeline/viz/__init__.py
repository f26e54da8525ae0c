"""Where a run's results are shown as they happen: a Rerun sink, or a sink that does nothing.

The replay loop and the front-end call the same methods on either, so neither asks whether
viewing is on.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.viz.sink import NullSink, Sink, TeeSink

if TYPE_CHECKING:
    from pipeline.viz.frontend import FrontendSink


def sink_from_options(
    rrd: Path | None,
    spawn: bool,
    connect: str | None,
    application: str = "mmslam",
    mcap: Path | None = None,
) -> Sink:
    """The sink the command-line options ask for: `--rrd FILE`, `--spawn`, `--connect ADDR`
    (Rerun), and `--mcap FILE` (Foxglove), either or both."""
    sinks: list[Sink] = []
    if mcap is not None:
        from pipeline.foxglove.replay_file import FoxgloveSink

        sinks.append(FoxgloveSink(mcap))
    if rrd is not None or spawn or connect is not None:
        from pipeline.viz.rerun_sink import RerunSink

        sinks.append(RerunSink.open(application, rrd=rrd, spawn=spawn, connect=connect))
    if not sinks:
        return NullSink()
    return sinks[0] if len(sinks) == 1 else TeeSink(sinks)


def frontend_sink_from_options(
    rrd: Path | None, spawn: bool, connect: str | None, application: str = "mmslam"
) -> FrontendSink:
    """The front-end's sink: Rerun as `--rrd FILE`, `--spawn` or `--connect ADDR` ask, else one
    that shows nothing."""
    if rrd is None and not spawn and connect is None:
        return NullSink()
    from pipeline.viz.rerun_sink import RerunSink

    return RerunSink.open(application, rrd=rrd, spawn=spawn, connect=connect)


__all__ = ["NullSink", "Sink", "TeeSink", "frontend_sink_from_options", "sink_from_options"]
