"""The `mmslam` command line: parses arguments and calls the pipeline, nothing else.

Heavy modules are imported inside the commands so that `--help` answers at once.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

from pipeline.errors import InputError, SolverError, describe_os_error

METHODS = ("known", "ml", "gpda", "mm", "mm-nh")

EXAMPLES = """examples:
  mmslam simulate kitti05-cars --out out/kitti05.mcap --seed 1 --odom-noise-scale 2
  mmslam inspect out/kitti05.mcap
  mmslam replay out/kitti05.mcap --method mm-nh --out out/kitti05-mmnh --rrd out/run.rrd
  mmslam frontend out/seq --out out/seq.mcap
  mmslam sweep configs/sweeps/small.toml --out out/sweep --workers 2
"""


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2, as the contract asks."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _add_viz_options(parser: argparse.ArgumentParser) -> None:
    viz = parser.add_mutually_exclusive_group()
    viz.add_argument("--rrd", type=Path, metavar="FILE", help="save a Rerun recording to FILE")
    viz.add_argument("--spawn", action="store_true", help="stream to a new Rerun viewer")
    viz.add_argument("--connect", metavar="ADDR", help="stream to a running Rerun viewer")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from data_tools.scenarios import simulate

    summary = simulate(
        args.scenario,
        args.out,
        seed=args.seed,
        odom_noise_scale=args.odom_noise_scale,
        misclassification=args.misclassification,
        num_classes=args.num_classes,
        true_covariance=args.true_covariance,
        config_path=args.config,
    )
    print(summary.summary_line())
    return 0


def _cmd_frontend(args: argparse.Namespace) -> int:
    from pipeline.frontend.run import run_frontend

    sink = None
    if args.rrd or args.spawn or args.connect:
        from pipeline.viz import sink_from_options

        sink = sink_from_options(args.rrd, args.spawn, args.connect, "mmslam frontend")
    try:
        summary = run_frontend(
            args.sequence,
            args.out,
            args.config,
            images=args.images,
            progress=not args.quiet,
            sink=sink,
        )
    finally:
        if sink is not None:
            sink.close()
    print(summary.summary_line())
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from data_tools.sweep import run_sweep

    if args.workers is not None and args.dask is not None:
        raise InputError("--workers and --dask: choose one")
    summary = run_sweep(
        args.config,
        args.out,
        workers=args.workers,
        dask_address=args.dask,
        progress=not args.quiet,
    )
    print(summary.summary_line())
    return 1 if summary.failed else 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from pipeline.inspect import inspect_log, render_text

    report = inspect_log(args.log)
    if args.json:
        import json

        print(json.dumps(report, indent=2, sort_keys=True))
    else:
        print(render_text(report))
    if not report["valid"]:
        raise InputError(report["problem"])
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from pipeline.config import load_config
    from pipeline.replay import replay
    from pipeline.viz import sink_from_options

    config = load_config(args.config)
    sink = sink_from_options(args.rrd, args.spawn, args.connect, application="mmslam replay")
    result = replay(args.log, args.method, args.out, config, sink=sink, progress=not args.quiet)
    logging.getLogger("mmslam").info("wrote %s", args.out)
    print(result.summary_line())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mmslam",
        description="Robust semantic SLAM with max-mixture data association over stereo logs.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    simulate = commands.add_parser("simulate", help="write a log from a built-in scenario")
    simulate.add_argument("scenario", choices=("indoor-tags", "kitti05-cars"))
    simulate.add_argument("--out", required=True, type=Path, metavar="LOG.mcap")
    simulate.add_argument("--seed", type=int, default=0, help="draws all noise (default 0)")
    simulate.add_argument(
        "--odom-noise-scale", type=float, metavar="K",
        help="times the paper's added odometry noise, 0..10 (default: the scenario's)",
    )  # fmt: skip
    simulate.add_argument(
        "--misclassification", type=float, default=0.0, metavar="A",
        help="detector misclassification rate alpha, 0..1 (default 0)",
    )  # fmt: skip
    simulate.add_argument("--num-classes", type=int, metavar="C", help="semantic classes")
    simulate.add_argument(
        "--true-covariance", action="store_true",
        help="write the odometry covariance of the noise drawn, not the calibrated model's",
    )  # fmt: skip
    simulate.add_argument("--config", type=Path, metavar="FILE", help="TOML over the scenario's")
    simulate.set_defaults(run=_cmd_simulate)

    frontend = commands.add_parser("frontend", help="stereo images to a detection log")
    frontend.add_argument("sequence", type=Path, metavar="SEQUENCE_DIR")
    frontend.add_argument("--out", required=True, type=Path, metavar="LOG.mcap")
    frontend.add_argument(
        "--config", type=Path, metavar="FILE", help="TOML over configs/frontend.toml"
    )
    frontend.add_argument("--images", action="store_true", help="write the keyframes' images")
    frontend.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_viz_options(frontend)
    frontend.set_defaults(run=_cmd_frontend)

    inspect = commands.add_parser("inspect", help="what a log holds, and whether it is valid")
    inspect.add_argument("log", type=Path, metavar="LOG.mcap")
    inspect.add_argument("--json", action="store_true", help="print the report as JSON")
    inspect.set_defaults(run=_cmd_inspect)

    sweep = commands.add_parser(
        "sweep", help="the paper's experiments: many replays, tables, plots"
    )
    sweep.add_argument("config", type=Path, metavar="CONFIG", help="e.g. configs/sweeps/small.toml")
    sweep.add_argument("--out", required=True, type=Path, metavar="DIR")
    sweep.add_argument("--workers", type=int, metavar="N", help="processes (default: every core)")
    sweep.add_argument("--dask", metavar="ADDRESS", help="run on a Dask cluster instead")
    sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    sweep.set_defaults(run=_cmd_sweep)

    replay = commands.add_parser("replay", help="the SLAM back-end over a log")
    replay.add_argument("log", type=Path, metavar="LOG.mcap")
    replay.add_argument("--method", required=True, choices=METHODS)
    replay.add_argument("--out", required=True, type=Path, metavar="DIR")
    replay.add_argument(
        "--config", type=Path, metavar="FILE", help="TOML over configs/default.toml"
    )
    replay.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_viz_options(replay)
    replay.set_defaults(run=_cmd_replay)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return args.run(args)
    except InputError as exc:
        print(f"mmslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except SolverError as exc:
        print(f"mmslam {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"mmslam {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `mmslam inspect LOG | head`: the reader has gone, nothing to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a path the system refuses, a full disk
        message, status = describe_os_error(exc)
        print(f"mmslam {args.command}: error: {message}", file=sys.stderr)
        return status


if __name__ == "__main__":
    sys.exit(main())
