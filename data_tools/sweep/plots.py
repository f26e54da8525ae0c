"""Box plots like the paper's Fig. 4: a run's translation and rotation RMSE against one factor,
a box per method at each value (over the seeds of that cell)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from data_tools.sweep.config import FACTOR_LABELS, Axis
from data_tools.sweep.grid import Cell
from data_tools.sweep.results import ResultRow
from data_tools.sweep.stats import series
from data_tools.sweep.tables import factor_text, method_name
from pipeline.outputs import AtomicFile

# One colour per method, the same in every figure.
COLOURS = {
    "known": "#7f7f7f",
    "ml": "#d62728",
    "gpda": "#ff7f0e",
    "mm": "#1f77b4",
    "mm-nh": "#2ca02c",
}
PANELS = (("translation_rmse", "translation RMSE (m)"), ("rotation_rmse", "rotation RMSE (rad)"))


def box_figure(
    rows: Sequence[ResultRow],
    methods: Sequence[str],
    axis: Axis,
    along: Sequence[Cell],
    out: Path,
    title: str,
) -> Path:
    """Write the PNG of one axis to `out` (atomically) and return its path."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    shown = [m for m in methods if any(series(rows, along, m, "translation_rmse"))]
    figure = Figure(figsize=(11, 3.8), dpi=100, layout="constrained")
    panels = figure.subplots(1, len(PANELS))
    width = 0.8 / max(len(shown), 1)
    for panel, (column, label) in zip(panels, PANELS, strict=True):
        for k, method in enumerate(shown):
            data = series(rows, along, method, column)
            positions = [i + (k - (len(shown) - 1) / 2) * width for i in range(len(along))]
            kept = [(p, d) for p, d in zip(positions, data, strict=True) if d]
            if not kept:
                continue
            colour = COLOURS.get(method, "#9467bd")
            panel.boxplot(
                [d for _, d in kept],
                positions=[p for p, _ in kept],
                widths=width * 0.85,
                patch_artist=True,
                manage_ticks=False,
                boxprops={"facecolor": colour, "alpha": 0.75, "edgecolor": colour},
                medianprops={"color": "black"},
                whiskerprops={"color": colour},
                capprops={"color": colour},
                flierprops={"marker": ".", "markeredgecolor": colour, "markersize": 4},
            )
        panel.set_xticks(range(len(along)))
        panel.set_xticklabels([factor_text(axis.factor, v) for v in axis.values])
        panel.set_xlim(-0.5, len(along) - 0.5)
        panel.set_xlabel(FACTOR_LABELS[axis.factor])
        panel.set_ylabel(label)
        panel.grid(axis="y", alpha=0.3)
    handles = [Patch(color=COLOURS.get(m, "#9467bd"), alpha=0.75) for m in shown]
    figure.legend(handles, [method_name(m) for m in shown], loc="outside right center")
    figure.suptitle(title, fontsize=10)
    with AtomicFile(out) as png:
        figure.savefig(png.file, format="png")
    return out
