"""`mmslam compare`: one log through several association methods. Each method's run writes
what `mmslam replay` writes, in a folder of its own (`DIR/<method>/`); with `--rrd`, `--spawn`
or `--connect`, one Rerun recording shows every run on the same timeline, side by side
(`pipeline/viz/comparison.py`).

The runs are `replay()` calls, one after another or in worker processes (`--workers`,
`pipeline.workers`: they die with the command however it dies); each records to a file of its
own, and the comparison is put together from those files once all runs are done.

The comparison is all or nothing, as a replay's outputs are: the runs write into a staging
folder beside DIR (their recordings too), which is swapped with DIR in one rename once every
run has finished (`OutputFolder`, nested); entries of DIR the runs do not write (other methods'
folders, files of your own) are kept. A compare stopped at any instant, SIGKILL included,
leaves DIR as it was or as the new comparison, and the next run that writes DIR deletes the
staging folder it left. The recording is written only if every run finished.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pipeline.errors import WorkerError
from pipeline.outputs import OutputFolder, remove_tree
from pipeline.replay import ReplayResult

logger = logging.getLogger(__name__)

RECORDINGS = ".recordings"  # the runs' own recordings, in the staging folder until the swap


@dataclass(frozen=True)
class _Run:
    log: Path
    method: str
    out_dir: Path
    config: Path | None
    recording: Path | None  # the run's own recording, moved into the comparison later
    map_aspect: float
    progress: bool
    command: tuple[str, ...] | None


def _replay(run: _Run) -> ReplayResult:
    """One method's run, as `mmslam replay` makes it (in this process or a worker)."""
    from pipeline.config import load_config
    from pipeline.replay import replay

    sink = None
    if run.recording is not None:
        from pipeline.viz.config import load_viz_config
        from pipeline.viz.rerun_sink import RerunSink

        # the runs share the log: its images once would do, so none
        viz = dataclasses.replace(load_viz_config(), image_every=0)
        sink = RerunSink.open(
            "mmslam replay", rrd=run.recording, config=viz, map_aspect=run.map_aspect
        )
    return replay(
        run.log,
        run.method,
        run.out_dir,
        load_config(run.config),
        sink=sink,
        progress=run.progress,
        command=run.command,
    )


def _run_all(runs: list[_Run], workers: int) -> list[ReplayResult]:
    """Every run, in order or `workers` at a time; the first failure (in method order) is
    raised once all have ended."""
    if workers <= 1 or len(runs) == 1:
        return [_replay(run) for run in runs]
    from concurrent.futures.process import BrokenProcessPool

    from pipeline.workers import process_pool

    with process_pool(min(workers, len(runs))) as pool:
        futures = [pool.submit(_replay, run) for run in runs]
        concurrent.futures.wait(futures)
    results = []
    for run, future in zip(runs, futures, strict=True):
        error = future.exception()
        if isinstance(error, BrokenProcessPool):
            raise WorkerError(
                f"the worker replaying {run.method} died abruptly (killed, out of memory, or a "
                "crash); nothing was written"
            )
        if error is not None:
            raise error
        result = future.result()
        logger.info("%s done", run.method)
        results.append(result)
    return results


def compare(
    log_path: str | Path,
    methods: Sequence[str],
    out_dir: str | Path,
    config_path: str | Path | None = None,
    *,
    rrd: str | Path | None = None,
    spawn: bool = False,
    connect: str | None = None,
    workers: int = 1,
    progress: bool = True,
    command: Sequence[str] | None = None,
) -> list[ReplayResult]:
    """Replay `log_path` with each of `methods`, the outputs of each in `out_dir/<method>`;
    with a Rerun destination, one recording of them all."""
    from pipeline.config import load_config
    from pipeline.viz.comparison import map_aspect

    out_dir = Path(out_dir)
    methods = list(methods)
    config = Path(config_path) if config_path is not None else None
    load_config(config)  # a bad config is told before anything runs
    destination = None
    if rrd is not None or spawn or connect is not None:
        from pipeline.viz.stream import Destination

        # before the runs: a bad --rrd or an absent viewer is told at once
        destination = Destination.open("mmslam compare", rrd=rrd, spawn=spawn, connect=connect)
    finished = False
    try:
        with OutputFolder(out_dir, nested=True) as folder:
            recordings = folder.staging / RECORDINGS
            runs = [
                _Run(
                    Path(log_path),
                    method,
                    folder.staging / method,
                    config,
                    recordings / f"{method}.rrd" if destination is not None else None,
                    map_aspect(len(methods)),
                    progress and workers <= 1,
                    tuple(command) if command is not None else None,
                )
                for method in methods
            ]
            if destination is not None:
                recordings.mkdir()
            results = _run_all(runs, workers)
            if destination is not None:
                _record(destination, Path(log_path), runs, results)
                remove_tree(recordings)
            folder.commit({}, stale=methods)
            finished = True
    finally:
        if destination is not None:
            destination.close(finished)
    return [dataclasses.replace(r, out_dir=out_dir / r.method) for r in results]


def _record(destination, log_path: Path, runs: list[_Run], results: list[ReplayResult]) -> None:
    """The comparison recording, from the runs' own."""
    from pipeline.log import read_log
    from pipeline.viz.comparison import comparison_plots, write_comparison
    from pipeline.viz.config import load_viz_config
    from pipeline.viz.frame import replay_frame
    from pipeline.viz.summary import comparison_markdown

    viz = load_viz_config()
    frame = replay_frame(read_log(log_path), runs[0].map_aspect)
    methods = [run.method for run in runs]
    plots = comparison_plots(methods, frame.ground_truth, frame.truth_labels, viz.smoothing_window)
    destination.start()
    write_comparison(
        destination.rec,
        {run.method: run.recording for run in runs},
        frame,
        plots,
        viz.plot_window,
        comparison_markdown(results),
    )
