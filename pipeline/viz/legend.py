"""The map's legend: which colours it names, and where its swatches go. Pure, no Rerun.

The legend is drawn in the map itself, as a board of swatches below the map's extent, so that
it stays in view in every layout, the map maximised included (a legend in a view of its own
is hidden then). The default eye looks down on the map and the board together; labels are
drawn by the viewer at a fixed size below each swatch, so the board's rows are spaced by a
share of the view's height, not by metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.viz import draw

# A board row (a swatch and its label) is this share of the map view's height.
ROWS_PER_VIEW = 16
# Columns of swatches by the map view's width over its height: about 130 px a label.
COLUMNS_PER_ASPECT = 4.2
MAX_COLUMNS = 6
# Rows of space left for the labels below the last row of swatches.
LABEL_ROOM = 0.8


@dataclass(frozen=True)
class LegendItem:
    label: str
    rgb: tuple[int, int, int]
    line: bool  # a short line (trajectories, hypotheses) or a dot (landmarks, marks)


def class_legend(class_names: Sequence[str]) -> list[LegendItem]:
    rgb = draw.class_colors(len(class_names))
    return [
        LegendItem(name, (int(rgb[c, 0]), int(rgb[c, 1]), int(rgb[c, 2])), line=False)
        for c, name in enumerate(class_names)
    ]


def replay_legend(
    class_names: Sequence[str], ground_truth: bool, truth_labels: bool = False
) -> list[LegendItem]:
    """The landmark classes, the trajectories, and the marks of the association step.
    `ground_truth`: the log has a true trajectory; `truth_labels`: its detections name their
    true landmark, so wrong associations are drawn."""
    truth = [LegendItem("ground truth", draw.TRUTH_RGB, True)] if ground_truth else []
    wrong = [LegendItem("wrong association", draw.WRONG_RGB, True)] if truth_labels else []
    return [
        *class_legend(class_names),
        LegendItem("estimate", draw.ESTIMATE_RGB, True),
        *truth,
        LegendItem("odometry alone", draw.ODOMETRY_RGB, True),
        LegendItem("chosen", draw.WINNER_RGB, True),
        LegendItem("new landmark", draw.NEW_LANDMARK_RGB, True),
        LegendItem("other candidate", draw.LOSER_RGB, True),
        *wrong,
        LegendItem("null hypothesis", draw.NULL_WINNER_RGB, False),
        LegendItem("switch", draw.SWITCH_RGB, True),
        LegendItem("merge", draw.MERGE_RGB, True),
    ]


def frontend_legend(class_names: Sequence[str]) -> list[LegendItem]:
    return [*class_legend(class_names), LegendItem("visual odometry", draw.ESTIMATE_RGB, True)]


def board_columns(aspect: float) -> int:
    """Swatches a row in a map view of this width over height."""
    return max(2, min(MAX_COLUMNS, math.floor(aspect * COLUMNS_PER_ASPECT)))


@dataclass(frozen=True)
class Board:
    """Where the legend's swatches go in the map (world frame)."""

    centres: np.ndarray  # (n, 3), one a legend item, row by row
    half_line: float  # half the length of a line swatch
    row_spacing: float
    extent: np.ndarray  # (4, 3): corners the default eye must see, the labels' room included
    shown_height: float  # the height (m) the default eye shows, map and board together


def legend_board(count: int, low: np.ndarray, high: np.ndarray, aspect: float) -> Board:
    """A board of `count` swatches below the map whose box is `low`..`high` (3,), for a view of
    this `aspect` (width / height): rows a fixed share of the height the eye will show,
    columns across the width it will show, centred under the map."""
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    columns = board_columns(aspect)
    rows = max(1, math.ceil(count / columns))
    per_view = max(ROWS_PER_VIEW, rows + 6)
    width, height = high[0] - low[0], high[1] - low[1]
    # The height the eye shows: the map's width at this aspect, or the map's height plus the
    # board (its rows, the first a row below the map, and the labels' room below the last),
    # each row 1 / per_view of it.
    share = (rows + LABEL_ROOM) / per_view
    shown = max(width / aspect, height / (1.0 - share), 2 * draw.MIN_VIEW_HALF_HEIGHT)
    spacing = shown / per_view
    column_spacing = shown * aspect / columns
    k = np.arange(count)
    centre_x = 0.5 * (low[0] + high[0])
    x = centre_x + (k % columns - 0.5 * (columns - 1)) * column_spacing
    y = low[1] - spacing * (1 + k // columns)
    centres = np.stack([x, y, np.full(count, low[2])], axis=1)
    half_line = 0.3 * column_spacing
    half_width = 0.5 * (columns - 1) * column_spacing + half_line
    bottom = low[1] - spacing * (rows + LABEL_ROOM)
    extent = np.array(
        [
            [centre_x - half_width, low[1] - spacing, low[2]],
            [centre_x + half_width, low[1] - spacing, low[2]],
            [centre_x - half_width, bottom, low[2]],
            [centre_x + half_width, bottom, low[2]],
        ]
    )
    return Board(centres, half_line, spacing, extent, shown)
