"""The time series a recording plots: each plot's title and lines (entity, name, colour), read
by the sink that styles the lines and by the blueprint that lays the plots out. No Rerun here.

A replay's plots carry no legend of their own (over a whole run it covers the tops of the
lines): a plot of one line says what it is in its title, a plot of several names their colours
there. A comparison's plots, a line a method, have a legend (`comparison.py`).
"""

from __future__ import annotations

from dataclasses import dataclass

from pipeline.viz import draw
from pipeline.viz import entities as e


@dataclass(frozen=True)
class Series:
    path: str
    name: str
    rgb: tuple[int, int, int]
    colour: str  # the colour in words, for the plot's title
    width: float | None = None  # the line's width (UI points); None: the viewer's


@dataclass(frozen=True)
class Plot:
    title: str
    series: tuple[Series, ...]
    # the title names each line's colour (False where the layout does it elsewhere)
    colours_in_title: bool = True

    @property
    def name(self) -> str:
        """The view's title: what is plotted, and which colour is which line where there are
        several (the line's name up to any parenthesis: its full name shows on hover)."""
        if len(self.series) == 1 or not self.colours_in_title:
            return self.title
        return f"{self.title}: " + ", ".join(
            f"{s.name.split(' (')[0]} {s.colour}" for s in self.series
        )

    @property
    def paths(self) -> list[str]:
        return [s.path for s in self.series]


# The noise scales' lines (`pipeline/backend/noise`): the odometry's directions, then the
# detections' components.
NOISE_SERIES = (
    ("odometry", "roll", (140, 86, 75), "brown"),
    ("odometry", "pitch", (227, 119, 194), "pink"),
    ("odometry", "yaw", (214, 39, 40), "red"),
    ("odometry", "forward", (44, 160, 44), "green"),
    ("odometry", "lateral", (188, 189, 34), "olive"),
    ("odometry", "vertical", (127, 127, 127), "grey"),
    ("detections", "bearing", (31, 119, 180), "blue"),
    ("detections", "elevation", (23, 190, 207), "cyan"),
    ("detections", "range", (255, 127, 14), "orange"),
)


def noise_path(kind: str, name: str) -> str:
    """The entity of one noise scale's line: `kind` odometry or detections."""
    return f"{e.NOISE}/{kind}/{name}"


def replay_plots(ground_truth: bool, truth_labels: bool, smoothing_window: int) -> list[Plot]:
    """A replay's plots. `ground_truth`: the log has a true trajectory (the error plot);
    `truth_labels`: its detections name their true landmark (the wrong associations)."""
    plots = []
    if ground_truth:
        plots.append(
            Plot(
                "Translation error (m)",
                (
                    Series(e.ERROR_ONLINE, "newest pose", (240, 170, 40), "amber"),
                    Series(e.ERROR_FINAL, "final estimate", (60, 120, 230), "blue"),
                ),
            )
        )
    if truth_labels:
        plots.append(
            Plot(
                "Wrong associations (detections)",
                (Series(e.WRONG_COUNT, "wrong", draw.WRONG_RGB, "red"),),
            )
        )
    plots += [
        Plot("Landmarks", (Series(e.LANDMARK_COUNT, "landmarks", (31, 119, 180), "blue"),)),
        Plot(
            "Total",
            (
                Series(e.SWITCH_COUNT, "switches", draw.SWITCH_RGB, "magenta"),
                Series(e.MERGE_COUNT, "merges", draw.MERGE_RGB, "ice blue"),
            ),
        ),
        Plot(
            "Null-hypothesis rate",
            (Series(e.NULL_RATE, "null-hypothesis rate", draw.NULL_WINNER_RGB, "violet"),),
        ),
        Plot(
            "Noise scales in use (log10; 0: as stated)",
            tuple(
                Series(noise_path(kind, name), f"{kind} {name}", rgb, colour)
                for kind, name, rgb, colour in NOISE_SERIES
            ),
        ),
        Plot(
            "Time per keyframe (ms)",
            (
                Series(
                    e.STEP_MS, f"back-end (median of {smoothing_window})", (170, 170, 170), "grey"
                ),
                Series(
                    e.VIZ_MS, f"recording (median of {smoothing_window})", (148, 103, 189), "purple"
                ),
            ),
        ),
    ]
    return plots


def frontend_plots() -> list[Plot]:
    return [
        Plot(
            "Detections",
            (
                Series(e.TAG_COUNT, "tags", (31, 119, 180), "blue"),
                Series(e.BOX_COUNT, "boxes", (255, 127, 14), "orange"),
            ),
        ),
        Plot("VO inliers", (Series(e.VO_INLIERS, "inliers", (44, 160, 44), "green"),)),
    ]
