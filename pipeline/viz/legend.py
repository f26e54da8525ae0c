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

from pipeline.backend.hypotheses import NULL as NULL_ID
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


# The marks of the association step: a run may draw some of them never (known weighs no
# candidates; a run without merges draws none), and it may map no landmark of a class. The
# legend names those it drew, and always these.
CHOSEN, NEW, OTHER, WRONG = "chosen", "new landmark", "other candidate", "wrong association"
NULL, SWITCH, MERGE = "null hypothesis", "switch", "merge"
ALWAYS = ("estimate", "ground truth", "odometry alone", "robot", "visual odometry")


def replay_legend(
    class_names: Sequence[str], ground_truth: bool, truth_labels: bool = False
) -> list[LegendItem]:
    """The landmark classes, the trajectories, the robot, and the marks of the association
    step. `ground_truth`: the log has a true trajectory; `truth_labels`: its detections name
    their true landmark, so wrong associations are drawn."""
    truth = [LegendItem("ground truth", draw.TRUTH_RGB, True)] if ground_truth else []
    wrong = [LegendItem(WRONG, draw.WRONG_RGB, True)] if truth_labels else []
    return [
        *class_legend(class_names),
        LegendItem("estimate", draw.ESTIMATE_RGB, True),
        *truth,
        LegendItem("odometry alone", draw.ODOMETRY_RGB, True),
        LegendItem("robot", draw.ROBOT_RGB, False),
        LegendItem(CHOSEN, draw.WINNER_RGB, True),
        LegendItem(NEW, draw.NEW_LANDMARK_RGB, True),
        LegendItem(OTHER, draw.LOSER_RGB, True),
        *wrong,
        LegendItem(NULL, draw.NULL_WINNER_RGB, False),
        LegendItem(SWITCH, draw.SWITCH_RGB, True),
        LegendItem(MERGE, draw.MERGE_RGB, True),
    ]


def drawn_marks(hypotheses: Sequence[Sequence[draw.Hypothesis]]) -> set[str]:
    """The association marks a keyframe's hypothesis lines draw."""
    drawn = set()
    for h in (h for hs in hypotheses for h in hs):
        if h.landmark_id == NULL_ID:
            drawn.add(NULL if h.winner else OTHER)
        elif h.winner:
            drawn.add(WRONG if h.wrong else NEW if h.new_landmark else CHOSEN)
        else:
            drawn.add(OTHER)
    return drawn


def drawn_items(items: Sequence[LegendItem], drawn: set[str]) -> list[LegendItem]:
    """The legend of a run that drew `drawn` (association marks, the classes of its
    landmarks): the trajectories and the robot, and of the rest what it drew."""
    return [item for item in items if item.label in ALWAYS or item.label in drawn]


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
