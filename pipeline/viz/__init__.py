"""Where a run's results are shown as they happen: a Rerun sink, or a sink that does nothing.

The replay loop calls the same methods on either, so it never asks whether viewing is on.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.viz.sink import NullSink, Sink, TeeSink


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


__all__ = ["NullSink", "Sink", "TeeSink", "sink_from_options"]
