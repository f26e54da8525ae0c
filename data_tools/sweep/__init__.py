"""Sweeps: the paper's experiments (section V) as many replays, then tables and box plots.

`run_sweep(CONFIG, OUT)` runs every (cell, seed, method) of a sweep config not finished yet in
OUT, in a local process pool or on a Dask cluster, and writes OUT/results.csv, OUT/tables.md,
a box plot per axis (OUT/fig_<axis>.png) and the base cell's representative trajectories
(OUT/fig_trajectories.png). Configs live in `configs/sweeps/`.

One job per module: `config` (the TOML file), `grid` (cells, runs, folders), `work` (one run on
a worker), `executors` (where runs execute), `results` (results.csv), `stats` (pooling over
runs), `inference` (bootstrap intervals and paired tests over seeds), `tables` (Markdown),
`plots` (PNG), `reporting` (tables and figures from results.csv), `report` (its command:
`python -m data_tools.sweep.report DIR`), `sweep` (the whole command). Every file is written
all-or-nothing (`pipeline/outputs.py`).
"""

from __future__ import annotations

from data_tools.sweep.config import Axis, SweepConfig, load_sweep_config
from data_tools.sweep.sweep import SweepSummary, run_sweep

__all__ = ["Axis", "SweepConfig", "SweepSummary", "load_sweep_config", "run_sweep"]
