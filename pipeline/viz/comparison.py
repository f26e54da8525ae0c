"""One recording of several runs over the same log, to compare methods at a glance: each run's
own recording (as its sink wrote it, in whatever process ran it) moved under `/runs/<method>`,
their maps side by side and one legend beside them (naming what any run drew), each plot a
line per method with a legend (the reference, known, wide beneath the others, so that a
method that matches it leaves it visible), a table of their results. The log's poses are
every run's timeline, so the time cursor stands at the same moment in all of them.

Why a comparison is put together from finished recordings rather than logged live by one
process: the runs can go on in parallel processes, and each run's recording stays exactly what
`mmslam replay --rrd` makes of it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import rerun.chunk as rerun_chunk

from pipeline.viz import entities as e
from pipeline.viz import legend, marks
from pipeline.viz.blueprint import (
    events_view,
    legend_view,
    map_view,
    panels,
    plot_view,
    series_styles,
)
from pipeline.viz.frame import MapFrame
from pipeline.viz.plots import Plot, Series

RUNS = "/runs"
COMPARISON = "/comparison"
SUMMARY = "/comparison/summary"  # a table of the runs' results (static)
LEGEND_ROOT = "/comparison/legend"  # the legend's own small world, one for all the maps
PROPERTIES = "/__properties"  # where a recording keeps its properties (Rerun's own path)
# The top row of the layout (the maps, then the legend) at a 16:10 window is this many times as
# wide as it is high: N maps side by side and the legend share it as N and LEGEND_SHARE.
MAPS_ROW_ASPECT = 3.0
LEGEND_SHARE = 0.5

# A line colour for each method in the plots (and its name, in the map's title): none is a
# landmark class's (`draw.class_colors`), and red is kept for wrong associations. Known, the
# reference, is a wide white line drawn first, beneath the others.
METHOD_COLOURS: dict[str, tuple[tuple[int, int, int], str]] = {
    "known": ((235, 235, 235), "white"),
    "ml": ((250, 195, 40), "gold"),
    "gpda": ((170, 225, 100), "lime"),
    "mm": ((255, 150, 120), "salmon"),
    "mm-nh": ((90, 190, 255), "sky blue"),
    "dcsam": ((215, 175, 255), "lavender"),
}
REFERENCE_METHOD = "known"
LINE_WIDTHS = (4.0, 1.5)  # UI points: the reference's, the others'
# The width of the table of results beside the plots' grid, as a share of the grid's: room
# for every column at a 16:10 window.
TABLE_SHARE = 0.42


def run_root(method: str) -> str:
    return f"{RUNS}/{method}"


def map_aspect(count: int) -> float:
    """Width over height of each of `count` maps side by side (beside the legend)."""
    return MAPS_ROW_ASPECT / (max(count, 1) + LEGEND_SHARE)


def legend_aspect(count: int) -> float:
    """Width over height of the legend beside `count` maps."""
    return LEGEND_SHARE * map_aspect(count)


def comparison_legend(items: Sequence[legend.LegendItem], count: int) -> legend.Board:
    """Where the swatches of `items` go in the legend's world beside `count` maps: a board
    with nothing above it."""
    origin = np.zeros(3)
    return legend.legend_board(len(items), origin, origin, legend_aspect(count))


def moved_path(path: str, method: str) -> str | None:
    """Where an entity of a run's recording goes in the comparison; None: left out (the run's
    recording name and start time, the comparison has its own; what recording the run cost,
    which says nothing of the method; its legend, the comparison draws one for all; its noise
    scales, which only mm-nh learns: each run's own recording plots them). The
    run's description, `/__properties/run`, becomes the comparison's property named after
    the method."""
    if path in (PROPERTIES, e.VIZ_MS) or path.startswith((e.LEGEND + "/", e.NOISE + "/")):
        return None
    if path.startswith(PROPERTIES + "/"):
        return f"{PROPERTIES}/{method}"
    return run_root(method) + ("" if path == "/" else path)


def moved_chunks(
    recording: Path, method: str, legend_labels: set[str]
) -> Iterator[rerun_chunk.Chunk]:
    """The chunks of a run's recording, each under its new path; the labels of its legend as
    it ended (the sink logs it again at the end, naming only what the run drew) are added to
    `legend_labels` once the last chunk is read."""
    labels: dict[str, set[str]] = {}
    for chunk in rerun_chunk.RrdReader(recording).stream():
        if chunk.entity_path in (e.LEGEND_LINES, e.LEGEND_MARKS):  # static: the last one holds
            # a chunk may hold the legend as first logged (every item) and as it ended: the
            # last row is the one a static entity shows
            columns = chunk.to_record_batch().to_pydict()
            for column, values in columns.items():
                rows = [row for row in values if row]
                if column.endswith(":labels") and rows:
                    labels[chunk.entity_path] = set(rows[-1])
        path = moved_path(chunk.entity_path, method)
        if path is not None:
            yield chunk.with_entity_path(path)
    for found in labels.values():
        legend_labels.update(found)


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
    # the plots' legends and the maps' titles name the methods' colours
    order = sorted(methods, key=lambda m: m != REFERENCE_METHOD)  # the reference beneath
    return [
        Plot(
            m.title,
            tuple(
                Series(
                    run_root(method) + m.path,
                    method,
                    *METHOD_COLOURS[method],
                    width=LINE_WIDTHS[method != REFERENCE_METHOD],
                )
                for method in order
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
    """The maps side by side across the top, the legend beside them; the plots below, each
    with a legend (the null-hypothesis rate and the time, and the switches and the merges,
    as tabs of one cell each), and the table of results beside them (each run's summary and
    the runs' association events as tabs behind it)."""
    aspect = map_aspect(len(methods))
    # every map framed alike, on the map alone: the legend is a view of its own
    maps = [map_view(map_title(m), frame.map_extent, aspect, root=run_root(m)) for m in methods]
    board = comparison_legend(frame.items, len(methods))
    key = legend_view("Legend", LEGEND_ROOT, board.extent, legend_aspect(len(methods)))
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
    views = [plot_view(p, plot_window, legend=True) for p in plots]
    cells = [
        *views[:-4],
        rrb.Tabs(*views[-4:-2], active_tab=0),
        rrb.Tabs(*views[-2:], active_tab=0),
    ]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*maps, key, column_shares=[*[1.0] * len(maps), LEGEND_SHARE]),
            rrb.Horizontal(
                rrb.Grid(*cells, grid_columns=3), table, column_shares=[1.0, TABLE_SHARE]
            ),
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
    drawn: set[str] = set()
    for method, part in parts.items():
        rr.send_chunks(moved_chunks(part, method, drawn), recording=rec)
    # after the runs' own styles: static data logged later wins
    for path, style in series_styles(plots):
        rec.log(path, style, static=True)
    rec.log(SUMMARY, rr.TextDocument(summary, media_type="text/markdown"), static=True)
    # one legend beside the maps: every mark any run drew
    rec.log(LEGEND_ROOT, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    shown = legend.drawn_items(frame.items, drawn)
    board = comparison_legend(frame.items, len(methods))
    for path, swatches in marks.legend_swatches(shown, board):
        rec.log(LEGEND_ROOT + path.removeprefix(e.LEGEND), swatches, static=True)
