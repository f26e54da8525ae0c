"""Redo the tables and figures of a sweep folder from its results.csv:

    python -m data_tools.sweep.report DIR

rewrites DIR/tables.md, DIR/fig_<axis>.png (one per axis of the sweep) and, where the runs'
folders are there, DIR/fig_trajectories.png.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from data_tools.sweep.reporting import report
from pipeline.errors import InputError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m data_tools.sweep.report",
        description="Redo tables.md and the figures of a sweep folder from its results.csv.",
    )
    parser.add_argument("out", type=Path, metavar="DIR", help="the folder of `mmslam sweep`")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        written = report(args.out)
    except InputError as exc:
        print(f"report: error: {exc}", file=sys.stderr)
        return 2
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
