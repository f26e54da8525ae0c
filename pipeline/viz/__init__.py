"""Where a run's results are shown as they happen: a Rerun sink, or a sink that does nothing.

The replay loop calls the same methods on either, so it never asks whether viewing is on.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.viz.sink import NullSink, Sink


def sink_from_options(
    rrd: Path | None, spawn: bool, connect: str | None, application: str = "mmslam"
) -> Sink:
    """The sink the command-line options ask for: `--rrd FILE`, `--spawn`, `--connect ADDR`."""
    if rrd is None and not spawn and connect is None:
        return NullSink()
    from pipeline.viz.rerun_sink import RerunSink

    return RerunSink.open(application, rrd=rrd, spawn=spawn, connect=connect)


__all__ = ["NullSink", "Sink", "sink_from_options"]
