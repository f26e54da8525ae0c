"""The map's marks beside the estimate, as Rerun archetypes: the legend's board, wrong
associations in red, and the history of null-hypothesis decisions and merges. What they mean
and where they go is decided elsewhere (`legend.py`, `correctness.py`, the sink); this module
only draws them, one style for each."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from pipeline.viz import draw
from pipeline.viz import entities as e
from pipeline.viz.legend import Board, LegendItem

# How far below a wrongly associated landmark its red ring is drawn (m): behind the landmark's
# own dot from above, near enough to stay round it.
RING_DEPTH_M = 0.1
# The robot's heading arrow, as a share of the height of map the default eye shows: seen at
# that eye whatever the map's size (its axes, a metre long, are a few pixels on a city). The
# marker floats this share above the pose, in front of the landmarks around it from above.
HEADING_SHARE = 0.05
LIFT_SHARE = 0.02
OUTLINE_RGB = (15, 15, 15)


def robot_marks(shown_height_m: float) -> list[tuple[str, object]]:
    """(entity, archetype) of the robot's marker, in its body frame: a yellow dot a fixed size
    on screen, outlined in black, and an arrow along x that the default eye sees."""
    lift = np.array([0.0, 0.0, LIFT_SHARE * shown_height_m])
    colour = draw.packed_rgba(draw.ROBOT_RGB)
    dot = rr.Points3D(
        [lift, 0.9 * lift],  # the outline just behind the dot, seen from above
        colors=[colour, draw.packed_rgba(OUTLINE_RGB)],
        radii=[rr.Radius.ui_points(8.0), rr.Radius.ui_points(11.0)],
        labels=["robot", "robot"],
        show_labels=False,
    )
    arrow = rr.Arrows3D(
        origins=[lift],
        vectors=[[HEADING_SHARE * shown_height_m, 0.0, 0.0]],
        colors=colour[None],
        radii=rr.Radius.ui_points(3.0),
    )
    return [(e.ROBOT_MARKER, dot), (e.ROBOT_HEADING, arrow)]


def legend_swatches(items: Sequence[LegendItem], board: Board) -> list[tuple[str, object]]:
    """(entity, archetype) of the legend's swatches, each labelled: a short line for lines, a
    dot for marks. The items take the board's places in order (fewer items than places leave
    its last places empty)."""
    half = np.array([board.half_line, 0.0, 0.0])
    out: list[tuple[str, object]] = []
    places = board.centres[: len(items)]
    for line in (True, False):
        chosen = [(c, item) for c, item in zip(places, items, strict=True) if item.line == line]
        if not chosen:
            continue
        style = {
            "colors": draw.packed_rgba([item.rgb for _, item in chosen]),
            "labels": [item.label for _, item in chosen],
            "show_labels": True,
        }
        if line:
            strips = [np.array([c - half, c + half]) for c, _ in chosen]
            out.append(
                (e.LEGEND_LINES, rr.LineStrips3D(strips, radii=rr.Radius.ui_points(3.0), **style))
            )
        else:
            points = [c for c, _ in chosen]
            out.append(
                (e.LEGEND_MARKS, rr.Points3D(points, radii=rr.Radius.ui_points(6.0), **style))
            )
    return out


def wrong_lines(
    pose_positions: np.ndarray, landmark_positions: np.ndarray, labels: Sequence[str]
) -> list:
    """A red line from each wrongly associated detection's pose to its landmark (N, 3 each),
    and a red ring round that landmark (a larger red dot just below it: a short line is lost
    in a map seen whole)."""
    strips = np.stack([pose_positions, landmark_positions], axis=1)
    return [
        rr.LineStrips3D(
            strips,
            colors=draw.packed_rgba(draw.WRONG_RGB)[None],
            radii=rr.Radius.ui_points(4.0),
            labels=list(labels),
            show_labels=False,  # hundreds in a broken map: hover for which detection
        ),
        rr.Points3D(
            landmark_positions - [0.0, 0.0, RING_DEPTH_M],
            colors=draw.packed_rgba(draw.WRONG_RGB)[None],
            radii=rr.Radius.ui_points(9.0),
        ),
    ]


def null_decisions(
    points: np.ndarray, labels: Sequence[str], radius_ui: float = 3.5
) -> rr.Points3D:
    """Where detections were left to the null hypothesis (the points they measured), dots of
    `radius_ui` UI points: the history's small, this keyframe's larger. Unlabelled in the map
    (the lines and the event log say it); hover for more."""
    return rr.Points3D(
        points,
        colors=draw.packed_rgba(draw.NULL_WINNER_RGB)[None],
        radii=rr.Radius.ui_points(radius_ui),
        labels=list(labels),
        show_labels=False,
    )


def switches(strips: Sequence[np.ndarray], labels: Sequence[str]) -> rr.LineStrips3D:
    """A line from each detection whose association switched at this keyframe to what it went
    to (a landmark, or the point it measured for the null hypothesis)."""
    return rr.LineStrips3D(
        strips,
        colors=draw.packed_rgba(draw.SWITCH_RGB)[None],
        radii=rr.Radius.ui_points(4.0),
        labels=list(labels),
    )


def merges(duplicates: np.ndarray, survivors: np.ndarray, labels: Sequence[str]) -> rr.LineStrips3D:
    """A line from each merged duplicate (where it was last drawn) to its survivor: thin and
    half transparent, since a long run's merges pile up (a thousand on kitti05-cars)."""
    return rr.LineStrips3D(
        np.stack([duplicates, survivors], axis=1),
        colors=draw.packed_rgba(draw.MERGE_RGB, alpha=150)[None],
        radii=rr.Radius.ui_points(1.5),
        labels=list(labels),
        show_labels=False,
    )
