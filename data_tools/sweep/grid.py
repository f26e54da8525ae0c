"""The grid of a sweep: its cells, its runs, and where each run lives in the output folder.

A cell is a pair (odometry noise scale, misclassification rate). The grid is the base cell and
every cell on an axis, each once, in the order of the config. A run is a (cell, seed, method);
it lives in `runs/<cell>/seed<seed>/<method>/`, beside the log its cell and seed share.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from data_tools.sweep.config import Axis, SweepConfig
from pipeline.errors import InputError

RUNS_DIR = "runs"
LOG_NAME = "log.mcap"


@dataclass(frozen=True, order=True)
class Cell:
    odom_noise_scale: float
    misclassification: float

    @property
    def name(self) -> str:
        return f"noise{self.odom_noise_scale:g}-mis{self.misclassification:g}"

    def label(self) -> str:
        return (
            f"odometry noise scale {self.odom_noise_scale:g}, "
            f"misclassification {100 * self.misclassification:g} %"
        )


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
    return [Cell(base.odom_noise_scale, v) for v in axis.values]


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
