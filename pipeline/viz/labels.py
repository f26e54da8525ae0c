"""Which labels around the current pose to show, so that none covers another at the map's
default eye: the viewer draws every label at a fixed size, so a dozen landmarks a few metres
apart, seen over a whole run, pile their labels up. Those left out keep their text for
hovering and selecting where the entity allows it. Pure, no Rerun.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pipeline.viz.draw import Hypothesis

# A label as the viewer draws it (px): about 14 characters wide, one line high, below its
# anchor and centred on it.
LABEL_PX = (110.0, 22.0)
# The map view's height in the default layouts (px, at 1600x1000); with its height in metres it
# gives metres per pixel.
MAP_VIEW_PX = 600.0


def label_box(shown_height_m: float, view_px: float = MAP_VIEW_PX) -> tuple[float, float]:
    """Width and height (m) a label covers in a map view showing `shown_height_m` metres in
    `view_px` pixels."""
    scale = shown_height_m / view_px
    return LABEL_PX[0] * scale, LABEL_PX[1] * scale


def spaced(anchors: np.ndarray, order: Sequence[int], box: tuple[float, float]) -> np.ndarray:
    """Which labels to show (bool per anchor): in `order` (most wanted first), each label
    whose box, below its anchor (N, 2+: x, y in the view's plane), covers no label already
    chosen. Labels not in `order` are never shown."""
    anchors = (
        np.asarray(anchors, dtype=float).reshape(len(anchors), -1)[:, :2]
        if len(anchors)
        else np.zeros((0, 2))
    )
    width, height = box
    shown = np.zeros(len(anchors), dtype=bool)
    chosen: list[int] = []
    for k in order:
        if chosen:
            apart = np.abs(anchors[chosen] - anchors[k])
            if np.any((apart[:, 0] < width) & (apart[:, 1] < height)):
                continue
        chosen.append(k)
        shown[k] = True
    return shown


def keyframe_labels(
    hypotheses: Sequence[Hypothesis],
    strips: Sequence[np.ndarray],
    weighed: Sequence[int],
    centres: Sequence[np.ndarray],
    box: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Which labels of a keyframe's association view to show: of the landmarks `weighed` (at
    `centres`), and of the hypothesis lines (`strips`, one a hypothesis; a line's label sits at
    its middle). The chosen landmarks first, then the winners' lines (only winners' lines are
    labelled), then the other candidates by their best weight. (landmarks', lines') bools."""
    anchors = np.array(
        [*centres, *(np.mean(strip, axis=0) for strip in strips)], dtype=float
    ).reshape(-1, 3)
    chosen = {h.landmark_id for h in hypotheses if h.winner}
    best: dict[int, float] = {}
    for h in hypotheses:
        best[h.landmark_id] = max(best.get(h.landmark_id, 0.0), h.weight)
    winners = [k for k, j in enumerate(weighed) if j in chosen]
    lines = [len(weighed) + n for n, h in enumerate(hypotheses) if h.winner]
    others = sorted(
        (k for k, j in enumerate(weighed) if j not in chosen), key=lambda k: -best[weighed[k]]
    )
    shown = spaced(anchors, [*winners, *lines, *others], box)
    return shown[: len(weighed)], shown[len(weighed) :]
