"""The `mmslam` command line: parses arguments and calls the pipeline, nothing else.

Heavy modules are imported inside the commands so that `--help` answers at once.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import logging
import os
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pipeline.arguments import method_list
from pipeline.backend.methods import METHODS
from pipeline.errors import (
    InputError,
    SolverError,
    Terminated,
    WorkerError,
    describe_os_error,
    terminated_on_sigterm,
)


class RegistryNames(Sequence[str]):
    """The names of a registry (`module.attribute`), imported when first read: argparse's
    choices from a module slow to import, so that `--help` and the other commands need not."""

    def __init__(self, module: str, attribute: str):
        self.module, self.attribute = module, attribute

    @functools.cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(getattr(importlib.import_module(self.module), self.attribute))

    def __getitem__(self, index):  # type: ignore[override]
        return self.names[index]

    def __len__(self) -> int:
        return len(self.names)


# The built-in scenarios are data_tools.scenarios.SCENARIOS (importing it loads NumPy and GTSAM);
# the association methods, pipeline.backend.methods.METHODS (cheap to import).
SCENARIOS = RegistryNames("data_tools.scenarios", "SCENARIOS")
# Our own loggers: -v shows their debug lines; third-party libraries stay at warnings.
OWN_LOGGERS = ("pipeline", "data_tools", "mmslam")

EXAMPLES = """examples:
  mmslam simulate kitti05-cars --out out/kitti05.mcap --seed 1 --odom-noise-scale 2
  mmslam inspect out/kitti05.mcap
  mmslam replay out/kitti05.mcap --method mm-nh --out out/kitti05-mmnh --rrd out/run.rrd
  mmslam compare out/kitti05.mcap --methods known,ml,mm-nh --out out/kitti05-runs --rrd out/cmp.rrd
  mmslam export out/kitti05.mcap --ground-truth out/kitti05-gt.tum
  mmslam plot out/kitti05.mcap out/kitti05-mmnh --out out/kitti05.png
  mmslam frontend out/seq --out out/seq.mcap
  mmslam sweep small --out out/sweep --workers 2
  mmslam convert victoria_park.txt --out out/vp.mcap

-v and -q go anywhere on the line; `mmslam COMMAND -h` shows each command's options.
"""

COMMAND_EXAMPLES = {
    "simulate": """examples:
  mmslam simulate indoor-tags --out out/tags.mcap --seed 2 --odom-noise-scale 4 \\
      --misclassification 0.1 --true-covariance
  mmslam simulate kitti05-cars --out out/kitti05.mcap --seed 1
  mmslam simulate indoor-tags --out out/short.mcap --config my-route.toml
""",
    "restate": """examples:
  mmslam restate out/vp.mcap --stated-detections bearing=4,range=4 --out out/vp-loose.mcap
  mmslam restate out/kitti05.mcap --stated-odometry yaw=0.1 --out out/kitti05-yaw.mcap

Factors are on variances: 4 states sigmas twice what they are, 0.1 about a third. Everything
else in the log is copied as it was. mmslam simulate takes the same options.
""",
    "frontend": "",  # the layouts, each with an example: frontend_examples()
    "replay": """examples:
  mmslam replay out/tags.mcap --method mm-nh --out out/tags-mm-nh
  mmslam replay out/tags.mcap --method ml --out out/tags-ml --rrd out/tags-ml.rrd
  mmslam replay out/tags.mcap --method mm-nh --out out/tags-mm-nh --mcap out/tags-mm-nh.mcap
  mmslam replay out/tags.mcap --method gpda --out out/tags-gpda --config strict.toml
""",
    "compare": """examples:
  mmslam compare out/tags.mcap --methods known,ml,mm-nh --out out/tags-runs --rrd out/tags.rrd
  mmslam compare out/tags.mcap --methods ml,mm-nh --out out/tags-runs --spawn --workers 2

Each method's outputs go to DIR/METHOD/, as `mmslam replay --out DIR/METHOD` writes them. The
recording shows every run on the same timeline: the maps side by side, a line per method in
each plot, a table of the results. It is put together once every run has finished (with
--spawn or --connect, the viewer gets it then).
""",
    "inspect": """examples:
  mmslam inspect out/tags.mcap
  mmslam inspect out/tags.mcap --json | python -m json.tool
""",
    "sweep": """examples:
  mmslam sweep small --out out/sweep-small --workers 2
  mmslam sweep kitti05 --out out/kitti05 --seeds 20
  mmslam sweep configs/sweeps/indoor-tags.toml --out out/indoor --dask tcp://host:8786
""",
    "export": """examples:
  mmslam export out/tags.mcap --ground-truth out/tags-gt.tum
  mmslam export out/tags.mcap --ground-truth out/gt.tum --landmarks out/gt-landmarks.csv
  evo_ape tum out/tags-gt.tum out/tags-mm-nh/trajectory.tum --align_origin
""",
    "plot": """examples:
  mmslam plot out/tags.mcap out/tags-known out/tags-ml out/tags-mm-nh --out out/tags.png
""",
    "convert": """examples:
  mmslam convert victoria_park.txt --out out/vp.mcap
  mmslam replay out/vp.mcap --method known --out out/vp-known
  mmslam replay out/vp.mcap --method mm-nh --out out/vp-mm-nh

Victoria Park ships with GTSAM; this prints where:
  python -c 'import gtsam; print(gtsam.findExampleDataFile("victoria_park.txt"))'
The file's landmark ids become each detection's truth_landmark_id: known replays the given
associations, and every replay's metrics.json scores its associations against them.
""",
}


def frontend_examples() -> str:
    """`mmslam frontend --help`'s epilog: every layout it reads, what it holds, an example."""
    from pipeline.datasets import LAYOUTS

    lines = ["layouts (chosen by what SEQUENCE holds), each with an example:"]
    for name, holds, example in LAYOUTS:
        lines += [f"  {name}: {holds}", f"    {example}"]
    lines += [
        "",
        "more examples:",
        "  mmslam frontend out/seq --out out/seq.mcap --images --rrd out/seq.rrd",
        "  mmslam frontend my_bag.mcap --out out/bag.mcap --calibration calibration.toml",
    ]
    return "\n".join(lines) + "\n"


class _VersionAction(argparse.Action):
    """`--version`: mmslam's version, its git commit when run from a checkout, and the
    libraries' versions. Asked for only when given, so that other commands never run git."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, help="show the versions and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> None:
        from pipeline.provenance import version_text

        print(version_text(), flush=True)
        parser.exit(0)


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr and exit status 2, as the contract asks."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def number_in(
    kind: type, low: float | None = None, high: float | None = None
) -> Callable[[str], Any]:
    """An argparse type: `kind` within [low, high] (either end open when None)."""
    name = "an integer" if kind is int else "a number"

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {name}, got {text!r}") from None
        if (kind is float and value != value) or value in (float("inf"), float("-inf")):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if (low is not None and value < low) or (high is not None and value > high):
            if high is None:
                wanted = f">= {low:g}"
            elif low is None:
                wanted = f"<= {high:g}"
            else:
                wanted = f"within {low:g}..{high:g}"
            raise argparse.ArgumentTypeError(f"must be {wanted}, got {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def builtin_sweeps() -> list[str]:
    from pipeline.settings import config_path

    return sorted(p.stem for p in config_path("sweeps").glob("*.toml"))


def sweep_config(name_or_path: str) -> Path:
    """A sweep file, or the name of a built-in sweep (`small` is configs/sweeps/small.toml)."""
    from pipeline.settings import config_path

    path = Path(name_or_path)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    builtin = config_path(f"sweeps/{name_or_path}.toml")
    if not builtin.exists():
        raise InputError(
            f"sweep {name_or_path!r}: no such file and no built-in sweep of that name; "
            f"built-in: {', '.join(builtin_sweeps())}"
        )
    return builtin


def _command_line(args: argparse.Namespace) -> list[str]:
    return ["mmslam", *args.argv]


def _say(args: argparse.Namespace, *lines: str) -> None:
    """A command's result lines on stdout; none under -q (errors only)."""
    if not args.quiet:
        for line in lines:
            print(line)


def _stated_noise(args: argparse.Namespace) -> Any:
    """The `--stated-*` options as a `StatedNoise` (variance factors per direction)."""
    from data_tools.stated_noise import (
        DETECTION_COMPONENTS,
        ODOMETRY_AXES,
        StatedNoise,
        parse_factor,
        parse_factors,
    )

    return StatedNoise(
        odometry=parse_factors(args.stated_odometry, ODOMETRY_AXES, "--stated-odometry"),
        detections=parse_factors(
            args.stated_detections, DETECTION_COMPONENTS, "--stated-detections"
        ),
        relative_pose=parse_factor(args.stated_tag_pose, "--stated-tag-pose"),
    )


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
        stated=_stated_noise(args),
    )
    _say(args, summary.summary_line())
    return 0


def _cmd_restate(args: argparse.Namespace) -> int:
    from data_tools.stated_noise import restate_log

    stated = _stated_noise(args)
    steps, detections = restate_log(args.log, args.out, stated)
    print(
        f"{args.log}: {steps} odometry steps and {detections} detections stated as "
        f"{stated.describe() or 'they were'} -> {args.out}"
    )
    return 0


def _add_stated_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--stated-odometry", default="", metavar="DIR=F,...",
        help="state the odometry's variance F times what it is, per direction (roll, pitch, "
        "yaw, forward, lateral, vertical, or all), e.g. yaw=0.1",
    )  # fmt: skip
    parser.add_argument(
        "--stated-detections", default="", metavar="COMP=F,...",
        help="state a detection's variance F times what it is, per component (bearing, "
        "elevation, range, or all), e.g. bearing=4,range=4",
    )  # fmt: skip
    parser.add_argument(
        "--stated-tag-pose", default="1", metavar="F",
        help="state a tag's relative pose covariance F times what it is (default 1)",
    )  # fmt: skip


def _cmd_convert(args: argparse.Namespace) -> int:
    from data_tools.landmarks2d import convert_landmarks2d, load_landmarks2d_config

    summary = convert_landmarks2d(args.source, args.out, load_landmarks2d_config(args.config))
    _say(args, summary.summary_line())
    return 0


def _cmd_frontend(args: argparse.Namespace) -> int:
    from pipeline.frontend.run import run_frontend
    from pipeline.viz import frontend_sink_from_options

    sink = frontend_sink_from_options(args.rrd, args.spawn, args.connect, "mmslam frontend")
    try:
        summary = run_frontend(
            args.sequence,
            args.out,
            args.config,
            images=args.images,
            progress=not args.quiet,
            sink=sink,
            left_topic=args.left_topic,
            right_topic=args.right_topic,
            calibration=args.calibration,
        )
    finally:
        sink.close()
    _say(args, summary.summary_line())
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from data_tools.sweep import run_sweep

    if args.workers is not None and args.dask is not None:
        raise InputError("--workers and --dask: choose one")
    summary = run_sweep(
        sweep_config(args.config),
        args.out,
        workers=args.workers,
        dask_address=args.dask,
        seeds=args.seeds,
        progress=not args.quiet,
    )
    _say(args, summary.summary_line(), *summary.method_lines)
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
    sink = sink_from_options(
        args.rrd, args.spawn, args.connect, application="mmslam replay", mcap=args.mcap
    )
    result = replay(
        args.log,
        args.method,
        args.out,
        config,
        sink=sink,
        progress=not args.quiet,
        command=_command_line(args),
    )
    logging.getLogger("mmslam").info("wrote %s", args.out)
    _say(args, result.summary_line())
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from pipeline.compare import compare

    results = compare(
        args.log,
        args.methods,
        args.out,
        args.config,
        rrd=args.rrd,
        spawn=args.spawn,
        connect=args.connect,
        workers=args.workers,
        progress=not args.quiet,
        command=_command_line(args),
    )
    _say(args, *(result.summary_line() for result in results))
    if args.rrd is not None:
        _say(args, f"wrote {args.rrd}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from pipeline.export import export_ground_truth

    for path in export_ground_truth(args.log, args.ground_truth, args.landmarks):
        _say(args, f"wrote {path}")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from data_tools.plot_runs import plot_runs

    plot_runs(args.log, args.runs, args.out)
    _say(args, f"wrote {args.out}")
    return 0


def _add_log_out(parser: argparse.ArgumentParser) -> None:
    """`--out LOG.mcap`: the log the command writes."""
    parser.add_argument("--out", required=True, type=Path, metavar="LOG.mcap")


def _add_config_option(parser: argparse.ArgumentParser, defaults: str) -> None:
    """`--config FILE`: a TOML file whose keys are put over the `defaults`."""
    parser.add_argument("--config", type=Path, metavar="FILE", help=f"TOML over {defaults}")


def _add_viz_options(parser: argparse.ArgumentParser) -> None:
    viz = parser.add_mutually_exclusive_group()
    viz.add_argument("--rrd", type=Path, metavar="FILE", help="save a Rerun recording to FILE")
    viz.add_argument("--spawn", action="store_true", help="stream to a new Rerun viewer")
    viz.add_argument("--connect", metavar="ADDR", help="stream to a running Rerun viewer")


def _verbosity(defaults: bool) -> argparse.ArgumentParser:
    """-v and -q, for the main parser (`defaults`) and every subcommand (no defaults, so that
    a subcommand without them keeps what was given before it)."""
    parent = argparse.ArgumentParser(add_help=False)
    keep = {} if defaults else {"default": argparse.SUPPRESS}
    group = parent.add_mutually_exclusive_group()
    group.add_argument(
        "-v", "--verbose", action="store_true", help="log mmslam's debug messages", **keep
    )
    group.add_argument(
        "-q", "--quiet", action="store_true",
        help="errors only: no progress, no result lines (inspect still prints its report)",
        **keep,
    )  # fmt: skip
    return parent


def _subcommand(
    commands: Any, name: str, help_text: str, run: Callable[[argparse.Namespace], int]
) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        name,
        help=help_text,
        description=help_text[0].upper() + help_text[1:] + ".",
        epilog=frontend_examples() if name == "frontend" else COMMAND_EXAMPLES[name],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        parents=[_verbosity(defaults=False)],
    )
    parser.set_defaults(run=run)
    return parser


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mmslam",
        description="Robust semantic SLAM with max-mixture data association over stereo logs.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        parents=[_verbosity(defaults=True)],
    )
    parser.add_argument("--version", action=_VersionAction)
    commands = parser.add_subparsers(
        dest="command", required=True, parser_class=_Parser, metavar="COMMAND"
    )

    simulate = _subcommand(
        commands, "simulate", "write a log from a built-in scenario", _cmd_simulate
    )
    # a metavar, so that argparse does not read the choices (import the scenarios) to build it
    simulate.add_argument("scenario", choices=SCENARIOS, metavar="SCENARIO", help="%(choices)s")
    _add_log_out(simulate)
    simulate.add_argument(
        "--seed", type=number_in(int, 0), default=0, help="draws all noise, >= 0 (default 0)"
    )
    simulate.add_argument(
        "--odom-noise-scale", type=number_in(float, 0), metavar="K",
        help="times the paper's added odometry noise, within 0..100; the paper sweeps 0..10 "
        "(default: the scenario's)",
    )  # fmt: skip
    simulate.add_argument(
        "--misclassification", type=number_in(float, 0, 1), default=0.0, metavar="A",
        help="detector misclassification rate alpha, 0..1 (default 0)",
    )  # fmt: skip
    simulate.add_argument(
        "--num-classes", type=number_in(int, 1), metavar="C",
        help="semantic classes, >= 1 (default: the scenario's)",
    )  # fmt: skip
    simulate.add_argument(
        "--true-covariance", action="store_true",
        help="write the odometry covariance of the noise drawn, not the calibrated model's",
    )  # fmt: skip
    _add_config_option(simulate, "the scenario's")
    _add_stated_options(simulate)

    restate = _subcommand(
        commands, "restate", "a log with its noise stated wrong on purpose", _cmd_restate
    )
    restate.add_argument("log", type=Path, metavar="LOG.mcap")
    _add_log_out(restate)
    _add_stated_options(restate)

    frontend = _subcommand(commands, "frontend", "stereo images to a detection log", _cmd_frontend)
    frontend.add_argument(
        "sequence", type=Path, metavar="SEQUENCE",
        help="a folder (KITTI, EuRoC or plain layout) or a ROS 2 bag (folder or file)",
    )  # fmt: skip
    _add_log_out(frontend)
    _add_config_option(frontend, "configs/frontend.toml")
    frontend.add_argument("--images", action="store_true", help="write the keyframes' images")
    frontend.add_argument(
        "--left-topic", metavar="TOPIC",
        help="a bag's left image topic (default: found when the bag has one obvious pair)",
    )  # fmt: skip
    frontend.add_argument("--right-topic", metavar="TOPIC", help="a bag's right image topic")
    frontend.add_argument(
        "--calibration", type=Path, metavar="FILE",
        help="a bag's rectified stereo calibration, as the plain layout's calibration.toml "
        "(default: the bag's CameraInfo)",
    )  # fmt: skip
    _add_viz_options(frontend)

    convert = _subcommand(
        commands, "convert", "a 2-D landmark dataset (Victoria Park) to a log", _cmd_convert
    )
    convert.add_argument(
        "source", type=Path, metavar="FILE",
        help="GTSAM's 2-D landmark text format: ODOMETRY/EDGE2, LANDMARK and BR lines",
    )  # fmt: skip
    _add_log_out(convert)
    _add_config_option(convert, "configs/landmarks2d.toml")

    inspect = _subcommand(
        commands, "inspect", "what a log holds, and whether it is valid", _cmd_inspect
    )
    inspect.add_argument("log", type=Path, metavar="LOG.mcap")
    inspect.add_argument("--json", action="store_true", help="print the report as JSON")

    sweep = _subcommand(
        commands, "sweep", "the paper's experiments: many replays, tables, plots", _cmd_sweep
    )
    sweep.add_argument(
        "config", metavar="CONFIG",
        help=f"a sweep file, or a built-in sweep: {', '.join(builtin_sweeps())}",
    )  # fmt: skip
    sweep.add_argument("--out", required=True, type=Path, metavar="DIR")
    sweep.add_argument(
        "--workers", type=number_in(int, 1), metavar="N", help="processes (default: every core)"
    )
    sweep.add_argument("--dask", metavar="ADDRESS", help="run on a Dask cluster instead")
    sweep.add_argument(
        "--seeds", type=number_in(int, 1), metavar="N",
        help="run seeds 0..N-1 instead of the config's (runs already there are kept)",
    )  # fmt: skip

    replay = _subcommand(commands, "replay", "the SLAM back-end over a log", _cmd_replay)
    replay.add_argument("log", type=Path, metavar="LOG.mcap")
    replay.add_argument("--method", required=True, choices=METHODS)
    replay.add_argument("--out", required=True, type=Path, metavar="DIR")
    _add_config_option(replay, "configs/default.toml")
    replay.add_argument(
        "--mcap", type=Path, metavar="FILE",
        help="also write the estimate as Foxglove messages to FILE (an MCAP file)",
    )  # fmt: skip
    _add_viz_options(replay)

    compare = _subcommand(
        commands,
        "compare",
        "several methods over one log: each run's outputs, one recording of them all",
        _cmd_compare,
    )
    compare.add_argument("log", type=Path, metavar="LOG.mcap")
    compare.add_argument(
        "--methods", type=method_list, default=["known", "ml", "mm-nh"], metavar="M1,M2,...",
        help=f"comma-separated, from {', '.join(METHODS)} (default: known,ml,mm-nh)",
    )  # fmt: skip
    compare.add_argument(
        "--out", required=True, type=Path, metavar="DIR", help="DIR/METHOD/ for each method"
    )
    _add_config_option(compare, "configs/default.toml")
    compare.add_argument(
        "--workers", type=number_in(int, 1), default=1, metavar="N",
        help="runs at a time, each in its own process (default 1: one after another)",
    )  # fmt: skip
    _add_viz_options(compare)

    export = _subcommand(
        commands, "export", "a log's ground truth for other tools (evo, a spreadsheet)", _cmd_export
    )
    export.add_argument("log", type=Path, metavar="LOG.mcap")
    export.add_argument(
        "--ground-truth", type=Path, metavar="FILE.tum",
        help="the ground-truth trajectory in TUM format, stamped as replay's trajectory.tum",
    )  # fmt: skip
    export.add_argument(
        "--landmarks", type=Path, metavar="FILE.csv",
        help="the ground-truth landmarks: id,x,y,z,class_id",
    )  # fmt: skip

    plot = _subcommand(
        commands, "plot", "top-down plot of replays against the ground truth", _cmd_plot
    )
    plot.add_argument("log", type=Path, metavar="LOG.mcap")
    plot.add_argument("runs", type=Path, nargs="+", metavar="RUN_DIR", help="replay --out folders")
    plot.add_argument("--out", required=True, type=Path, metavar="FIGURE.png")
    return parser


def configure_logging(verbose: bool, quiet: bool) -> None:
    """Third-party libraries log warnings only; mmslam's own loggers debug with -v and errors
    only with -q."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(logging.WARNING)
    level = logging.DEBUG if verbose else logging.ERROR if quiet else logging.WARNING
    for name in OWN_LOGGERS:
        logging.getLogger(name).setLevel(level)


def _stdout_gone() -> None:
    """The reader of stdout has gone (`mmslam inspect LOG | head`): what is left to print goes
    nowhere, so that neither we nor Python's exit complain about it."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _parse(argv: list[str]) -> argparse.Namespace:
    """The arguments; `--version` and `--help` print and exit here, a closed pipe quietly."""
    try:
        return build_parser().parse_args(argv)
    except BrokenPipeError:
        _stdout_gone()
        raise SystemExit(0) from None
    except SystemExit:
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _stdout_gone()
        raise


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parse(argv)
    args.argv = argv
    configure_logging(args.verbose, args.quiet)
    try:
        with terminated_on_sigterm():
            return args.run(args)
    except InputError as exc:
        print(f"mmslam {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except (SolverError, WorkerError) as exc:
        print(f"mmslam {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except Terminated:
        print(f"mmslam {args.command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"mmslam {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `mmslam inspect LOG | head`: the reader has gone, nothing to say
        _stdout_gone()
        return 0
    except OSError as exc:  # a path the system refuses, a full disk
        message, status = describe_os_error(exc)
        print(f"mmslam {args.command}: error: {message}", file=sys.stderr)
        return status


if __name__ == "__main__":
    sys.exit(main())
