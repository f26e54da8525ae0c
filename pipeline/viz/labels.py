"""Which labels around the current pose to show, so that none covers another at the map's
default eye: the viewer draws every label at a fixed size, so a dozen landmarks a few metres
apart, seen over a whole run, pile their labels up. Those left out keep their text for
hovering and selecting where the entity allows it. Pure, no Rerun.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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
