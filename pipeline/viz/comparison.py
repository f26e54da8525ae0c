"""One recording of several runs over the same log, to compare methods at a glance: each run's
own recording (as its sink wrote it, in whatever process ran it) moved under `/runs/<method>`,
their maps side by side, each plot a line per method, a table of their results. The log's
poses are every run's timeline, so the time cursor stands at the same moment in all of them.

Why a comparison is put together from finished recordings rather than logged live by one
process: the runs can go on in parallel processes, and each run's recording stays exactly what
`mmslam replay --rrd` makes of it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb
import rerun.chunk as rerun_chunk

from pipeline.viz import entities as e
from pipeline.viz.blueprint import events_view, map_view, panels, plot_view, series_styles
from pipeline.viz.frame import MapFrame
from pipeline.viz.plots import Plot, Series

RUNS = "/runs"
COMPARISON = "/comparison"
SUMMARY = "/comparison/summary"  # a table of the runs' results (static)
PROPERTIES = "/__properties"  # where a recording keeps its properties (Rerun's own path)
# The top row of the layout (the maps) at a 16:10 window is this many times as wide as it is
# high: N maps side by side are each 1 / N of it.
MAPS_ROW_ASPECT = 3.0

# A line colour for each method in the plots (and its name, in the map's title); red is kept
# for wrong associations.
METHOD_COLOURS: dict[str, tuple[tuple[int, int, int], str]] = {
    "known": ((200, 200, 200), "grey"),
    "ml": ((255, 127, 14), "orange"),
    "gpda": ((188, 189, 34), "olive"),
    "mm": ((23, 190, 207), "cyan"),
    "mm-nh": ((80, 140, 255), "blue"),
    "dcsam": ((196, 156, 148), "rose"),
}


def run_root(method: str) -> str:
    return f"{RUNS}/{method}"


def map_aspect(count: int) -> float:
    """Width over height of each of `count` maps side by side."""
    return MAPS_ROW_ASPECT / max(count, 1)


def moved_path(path: str, method: str) -> str | None:
    """Where an entity of a run's recording goes in the comparison; None: left out (the run's
    recording name and start time, the comparison has its own; what recording the run cost,
    which says nothing of the method). The run's description, `/__properties/run`, becomes
    the comparison's property named after the method."""
    if path in (PROPERTIES, e.VIZ_MS):
        return None
    if path.startswith(PROPERTIES + "/"):
        return f"{PROPERTIES}/{method}"
    return run_root(method) + ("" if path == "/" else path)


def moved_chunks(recording: Path, method: str) -> Iterator[rerun_chunk.Chunk]:
    """The chunks of a run's recording, each under its new path."""
    for chunk in rerun_chunk.RrdReader(recording).stream():
        path = moved_path(chunk.entity_path, method)
        if path is not None:
            yield chunk.with_entity_path(path)


@dataclass(frozen=True)
class Metric:
    title: str
    path: str


def comparison_plots(
    methods: Sequence[str], ground_truth: bool, truth_labels: bool, smoothing_window: int
) -> list[Plot]:
    """Each plot a line per method, in the method's colour. The last two (switches and
    merges) share a cell of the layout, as tabs."""
    metrics = []
    if ground_truth:
        metrics += [
            Metric("Translation error, newest pose (m)", e.ERROR_ONLINE),
            Metric("Translation error, final estimate (m)", e.ERROR_FINAL),
        ]
    if truth_labels:
        metrics.append(Metric("Wrong associations (detections)", e.WRONG_COUNT))
    metrics += [
        Metric("Landmarks", e.LANDMARK_COUNT),
        Metric("Null-hypothesis rate", e.NULL_RATE),
        Metric(f"Back-end time per keyframe (ms, median of {smoothing_window})", e.STEP_MS),
        Metric("Switches (total)", e.SWITCH_COUNT),
        Metric("Merges (total)", e.MERGE_COUNT),
    ]
    # the maps' titles name the methods' colours: the plots' titles are the metric alone
    return [
        Plot(
            m.title,
            tuple(
                Series(run_root(method) + m.path, method, *METHOD_COLOURS[method])
                for method in methods
            ),
            colours_in_title=False,
        )
        for m in metrics
    ]


def map_title(method: str) -> str:
    return f"{method} ({METHOD_COLOURS[method][1]} in the plots)"


def comparison_blueprint(
    frame: MapFrame, methods: Sequence[str], plots: list[Plot], plot_window: int
) -> rrb.Blueprint:
    """The maps side by side across the top, each with its legend; the plots and the table of
    results below (switches and merges as tabs of one cell; each run's summary and the runs'
    association events as tabs behind the table)."""
    aspect = map_aspect(len(methods))
    maps = [map_view(map_title(m), frame.extent, aspect, root=run_root(m)) for m in methods]
    # one event log for all runs, each line naming its run's entity
    events = events_view(
        "Association events", RUNS, [f"+ {run_root(m)}{e.EVENTS}" for m in methods]
    )
    # the table of results first; each run's own summary (its counts as it goes) behind it
    table = rrb.Tabs(
        rrb.TextDocumentView(name="Results", origin=SUMMARY),
        *[rrb.TextDocumentView(name=m, origin=run_root(m) + e.SUMMARY) for m in methods],
        events,
        active_tab=0,
    )
    views = [plot_view(p, plot_window) for p in plots]
    cells = [*views[:-2], rrb.Tabs(*views[-2:], active_tab=0), table]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*maps),
            rrb.Grid(*cells, grid_columns=4 if len(cells) > 6 else 3),
            row_shares=[6, 4],
        ),
        *panels(),
    )


def write_comparison(
    rec: rr.RecordingStream,
    parts: dict[str, Path],
    frame: MapFrame,
    plots: list[Plot],
    plot_window: int,
    summary: str,
) -> None:
    """Lay the runs' recordings (`parts`, by method) out in `rec`: the layout, every run's
    chunks moved under its root, the plots' lines named and coloured by method, the table."""
    methods = list(parts)
    rec.send_blueprint(comparison_blueprint(frame, methods, plots, plot_window))
    rec.send_recording_name(f"mmslam compare: {', '.join(methods)}")
    for method, part in parts.items():
        rr.send_chunks(moved_chunks(part, method), recording=rec)
    # after the runs' own styles: static data logged later wins
    for path, style in series_styles(plots):
        rec.log(path, style, static=True)
    rec.log(SUMMARY, rr.TextDocument(summary, media_type="text/markdown"), static=True)
