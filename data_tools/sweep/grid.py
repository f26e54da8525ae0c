"""The grid of a sweep: its cells, its runs, and where each run lives in the output folder.

A cell is an odometry noise scale, a misclassification rate and, on a stated-noise axis, which
direction of the log's noise is stated wrong by what factor (`data_tools/stated_noise.py`). The
grid is the base cell and every cell on an axis, each once, in the order of the config. A run
is a (cell, seed, method); it lives in `runs/<cell>/seed<seed>/<method>/`, beside the log its
cell and seed share.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from data_tools.stated_noise import StatedNoise, stated_noise_of
from data_tools.sweep.config import Axis, SweepConfig, stated_direction
from pipeline.errors import InputError

RUNS_DIR = "runs"
LOG_NAME = "log.mcap"


@dataclass(frozen=True, order=True)
class Cell:
    odom_noise_scale: float
    misclassification: float
    stated: str = ""  # "DIRECTION=FACTOR" (`config.STATED_FACTORS`), "" for the noise as it is

    @property
    def name(self) -> str:
        name = f"noise{self.odom_noise_scale:g}-mis{self.misclassification:g}"
        return f"{name}-{self.stated.replace('=', '')}" if self.stated else name

    def label(self) -> str:
        label = (
            f"odometry noise scale {self.odom_noise_scale:g}, "
            f"misclassification {100 * self.misclassification:g} %"
        )
        if self.stated:
            direction, factor = self.stated.split("=")
            label += f", {direction} stated {factor}x"
        return label

    def stated_noise(self) -> StatedNoise:
        """What the cell's log states over what it would state."""
        return stated_noise_of(self.stated)


@dataclass(frozen=True)
class RunKey:
    cell: Cell
    seed: int
    method: str

    def label(self) -> str:
        return f"{self.cell.name}/seed{self.seed}/{self.method}"


def base_cell(config: SweepConfig) -> Cell:
    return Cell(config.odom_noise_scale, config.misclassification)


def axis_cells(config: SweepConfig, axis: Axis) -> list[Cell]:
    """The cells of an axis, in the order of its values."""
    base = base_cell(config)
    if axis.factor == "odom_noise_scale":
        return [Cell(v, base.misclassification) for v in axis.values]
    if axis.factor == "misclassification":
        return [Cell(base.odom_noise_scale, v) for v in axis.values]
    direction = stated_direction(axis.factor)
    return [
        Cell(base.odom_noise_scale, base.misclassification, "" if v == 1 else f"{direction}={v:g}")
        for v in axis.values
    ]


def cells(config: SweepConfig) -> list[Cell]:
    """The base cell, then each axis's cells, each cell once."""
    ordered = [base_cell(config)]
    for axis in config.axes:
        ordered += [c for c in axis_cells(config, axis) if c not in ordered]
    names = [c.name for c in ordered]
    if len(set(names)) != len(names):
        raise InputError(f"sweep {config.name}: two cells print alike ({', '.join(names)})")
    return ordered


def runs(config: SweepConfig) -> list[RunKey]:
    """Every run of the sweep, cell by cell, seed by seed, method by method."""
    return [
        RunKey(cell, seed, method)
        for cell in cells(config)
        for seed in config.seeds
        for method in config.methods
    ]


def log_path(out: Path, cell: Cell, seed: int) -> Path:
    return out / RUNS_DIR / cell.name / f"seed{seed}" / LOG_NAME


def run_dir(out: Path, key: RunKey) -> Path:
    return out / RUNS_DIR / key.cell.name / f"seed{key.seed}" / key.method
