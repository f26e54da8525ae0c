"""`mmslam replay`: a log through the back-end, then evaluation, then the outputs.

Runs the loop and nothing else: the algorithm is in `pipeline/backend`, the metrics in
`pipeline/evaluation.py`, the file formats in `pipeline/outputs.py`, viewing in `pipeline/viz`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline import evaluation, outputs, provenance
from pipeline.backend.factors import pose_from_message
from pipeline.backend.planar import uses_plane
from pipeline.backend.slam import Backend, BackendResult
from pipeline.config import Config
from pipeline.errors import InputError, SolverError, first_line
from pipeline.log import DetectionLog, read_log
from pipeline.log.messages import Detection, Odometry
from pipeline.progress import Progress
from pipeline.viz.sink import NullSink, Sink

logger = logging.getLogger(__name__)


@dataclass
class ReplayResult:
    method: str
    out_dir: Path
    num_poses: int
    num_detections: int
    num_landmarks: int
    runtime_s: float
    metrics: dict[str, Any]

    def summary_line(self) -> str:
        m = self.metrics
        line = (
            f"{self.method}: {self.num_poses} poses, {self.num_detections} detections, "
            f"{self.num_landmarks} landmarks in {self.runtime_s:.2f} s"
        )
        if "translation_error_m" in m:
            t = m["translation_error_m"]
            line += f"; translation error rmse {t['rmse']:.3f} m max {t['max']:.3f} m"
        if "association" in m:
            a = m["association"]
            line += f"; associations {a['correct']} correct, {a['wrong']} wrong, {a['null']} null"
        fallbacks = m["solver_fallbacks"]
        if any(fallbacks.values()):
            kinds = ", ".join(f"{n} {kind}" for kind, n in fallbacks.items() if n)
            line += f"; SOLVER FELL BACK {sum(fallbacks.values())} times ({kinds}): a bug to report"
        return line + f" -> {self.out_dir}"


def keyframes(log: DetectionLog) -> Iterator[tuple[Odometry | None, list[Detection]]]:
    """Per pose: the odometry that reaches it (none for pose 0) and all its detections, in log
    order."""
    by_pose: dict[int, list[Detection]] = {}
    for message in log.detections:
        by_pose.setdefault(message.pose_index, []).extend(message.detections)
    for index in range(log.num_poses):
        yield (log.odometry[index - 1] if index else None), by_pose.get(index, [])


def pose_stamps_s(log: DetectionLog) -> np.ndarray:
    return np.array(log.pose_stamps_ns(), dtype=np.int64) / 1e9


def check_inputs(log: DetectionLog, method: str) -> None:
    if method == "known":
        for index, message in enumerate(log.detections):
            for k, detection in enumerate(message.detections):
                if detection.truth_landmark_id is None:
                    raise InputError(
                        f"method 'known' needs truth_landmark_id on every detection: /detections "
                        f"message {index} detection {k} has none"
                    )


@contextmanager
def solver_failures() -> Iterator[None]:
    """What GTSAM, or the numerics around it, throws on a graph it cannot solve ends as one
    `SolverError` line, wherever the back-end, the evaluation or the sink called it."""
    try:
        yield
    except SolverError:
        raise
    except (RuntimeError, ArithmeticError, np.linalg.LinAlgError) as exc:
        reason = first_line(str(exc)) or type(exc).__name__
        raise SolverError(f"the back-end failed: {reason}") from exc


def new_backend(
    log: DetectionLog, method: str, config: Config, heartbeat: Callable[[str], None] | None = None
) -> Backend:
    """The back-end for replaying `log`: its detector's confusion, its plane if it has one;
    `heartbeat` hears what a keyframe is doing while it runs."""
    confusion = np.asarray(log.metadata.confusion_matrix, dtype=float)
    return Backend(config, confusion, method, uses_plane(config.prior.planar, log), heartbeat)


def one_blas_thread() -> threadpool_limits:
    """numpy's and scipy's BLAS on one thread (a context): the back-end's matrices are small (a
    keyframe's innovations, a few landmarks' covariances), and on them OpenBLAS's threads only
    wait for each other, the longer the busier the machine. The planar park's first 1,500
    keyframes with mm-nh: 38.3 s on two threads, 25.9 s on one (scipy's triangular solves of a
    few rows, 1.8 ms a call against 0.08 ms). One thread also sums in the same order on every
    machine."""
    return threadpool_limits(limits=1, user_api="blas")


def run_backend(
    log: DetectionLog, method: str, config: Config, sink: Sink, progress: bool
) -> Backend:
    shown = Progress(log.num_poses, f"replay {method}", "pose", enabled=progress)
    # A slow keyframe (a thousand detections) says what it is doing instead of going silent.
    backend = new_backend(log, method, config, heartbeat=shown.beat)
    completed = False
    try:
        with one_blas_thread():
            for odometry, detections in keyframes(log):
                start = time.perf_counter()
                report = backend.add_keyframe(odometry, detections)
                sink.keyframe(report, time.perf_counter() - start)
                shown.update()
        completed = True
    finally:
        shown.close(completed)
    return backend


def compute_metrics(
    log: DetectionLog, result: BackendResult, method: str, runtime_s: float
) -> dict[str, Any]:
    """The run's counts, always; its errors against the ground truth where the log has it."""
    truth = [r.measurement.detection.truth_landmark_id for r in result.records]
    chosen = [r.landmark_id for r in result.records]
    metrics: dict[str, Any] = {
        "method": method,
        "num_poses": log.num_poses,
        "num_detections": log.num_detections,
        "num_landmarks": len(result.landmark_ids),
        "runtime_s": round(runtime_s, 3),
        "solver_fallbacks": result.solver_fallbacks,
        "nulls": sum(j < 0 for j in chosen),
        "switches": result.switches,
        "merges": result.merges,
        # the scales the replay ended with, per direction, and every move with its evidence
        "noise_scales": {
            **result.noise.report(),
            "moves": [move.report() for move in result.noise_moves],
        },
        **({"loop_drift": result.loop_drift} if result.loop_drift is not None else {}),
    }
    if any(t is not None for t in truth):
        counts = evaluation.association_counts(truth, chosen)
        counts["unlabelled"] = sum(t is None for t in truth)
        metrics["association"] = counts
        metrics["association_one_to_one"] = evaluation.association_scores(truth, chosen)
    if log.has_ground_truth:
        indices = [m.pose_index for m in log.ground_truth_poses]
        reference = np.stack(
            [pose_from_message(m.translation, m.rotation).matrix() for m in log.ground_truth_poses]
        )
        estimated = np.stack([result.poses[i].matrix() for i in indices])
        translation, rotation = evaluation.absolute_errors(
            estimated, reference, pose_stamps_s(log)[indices]
        )
        metrics["translation_error_m"] = translation
        metrics["rotation_error_rad"] = rotation
    return metrics


def render_outputs(
    log: DetectionLog, result: BackendResult, metrics: dict[str, Any]
) -> dict[str, str]:
    observations: dict[int, int] = {}
    for record in result.records:
        if record.landmark_id >= 0:
            observations[record.landmark_id] = observations.get(record.landmark_id, 0) + 1
    landmark_rows = []
    for landmark_id, value in zip(result.landmark_ids, result.landmark_values, strict=True):
        landmark = result.landmarks.landmarks[landmark_id]
        position = value.translation() if hasattr(value, "translation") else value
        probabilities = landmark.class_probabilities
        landmark_rows.append(
            (
                landmark_id,
                position,
                landmark.map_class,
                float(probabilities[landmark.map_class]),
                observations.get(landmark_id, 0),
            )
        )
    association_rows = [
        (r.measurement.pose_index, r.measurement.detection_index, r.landmark_id, r.weight)
        for r in result.records
    ]
    return {
        outputs.TRAJECTORY: outputs.trajectory_tum(
            log.pose_stamps_ns(), [p.matrix() for p in result.poses]
        ),
        outputs.LANDMARKS: outputs.landmarks_csv(landmark_rows),
        outputs.ASSOCIATIONS: outputs.associations_csv(association_rows),
        outputs.METRICS: outputs.metrics_json(metrics),
    }


def replay(
    log_path: str | Path,
    method: str,
    out_dir: str | Path,
    config: Config,
    sink: Sink | None = None,
    progress: bool = True,
    command: Sequence[str] | None = None,
) -> ReplayResult:
    """Replay a log with an association method; write the contract's outputs to `out_dir`,
    and `run.json` (how they were made; `command` defaults to this process's)."""
    sink = sink or NullSink()
    started, wall_start = provenance.utc_now(), time.perf_counter()
    out_dir = Path(out_dir)
    try:
        log = read_log(log_path, load_images=sink.wants_images)
        check_inputs(log, method)
        with outputs.OutputFolder(out_dir) as folder, solver_failures():
            sink.start(log, method)
            start = time.perf_counter()
            backend = run_backend(log, method, config, sink, progress)
            result = backend.result()
            runtime_s = time.perf_counter() - start
            metrics = compute_metrics(log, result, method, runtime_s)
            files = render_outputs(log, result, metrics)
            files[provenance.RUN_RECORD] = provenance.run_json(
                {"method": method, "backend": config},
                [log_path],
                started,
                time.perf_counter() - wall_start,
                command,
            )
            folder.commit(files)
            sink.finish(result, metrics)
    finally:
        sink.close()
    return ReplayResult(
        method=method,
        out_dir=out_dir,
        num_poses=log.num_poses,
        num_detections=log.num_detections,
        num_landmarks=len(result.landmark_ids),
        runtime_s=runtime_s,
        metrics=metrics,
    )
