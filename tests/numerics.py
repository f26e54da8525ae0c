"""Numerical derivatives for checking the hand-written Jacobians, and inputs perturbed in their
last digits for checking that a result does not hinge on them."""

from __future__ import annotations

import dataclasses
import heapq
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.log import Detection, DetectionLog, LogWriter, RelativePose, read_log


def numerical_jacobian(
    function: Callable[[Any], np.ndarray],
    x0: Any,
    retract: Callable[[Any, np.ndarray], Any] | None = None,
    dim: int | None = None,
    step: float = 1e-6,
) -> np.ndarray:
    """Central differences of `function` at `x0`, a column per tangent direction.

    `retract(x, d)` moves `x` by the tangent vector `d` (e.g. `Pose3.retract`); by default `x0`
    is a vector and `d` is added to it."""
    if retract is None:
        x0 = np.asarray(x0, float)
        retract = np.add
    dim = np.size(x0) if dim is None else dim
    columns = []
    for k in range(dim):
        d = np.zeros(dim)
        d[k] = step
        plus, minus = function(retract(x0, d)), function(retract(x0, -d))
        columns.append((np.asarray(plus) - np.asarray(minus)) / (2 * step))
    return np.stack(columns, axis=-1)


# --- perturbations: results that must not hinge on the last bits ------------------------------
# numpy's BLAS picks its kernels by CPU, so sums come out in another order on another machine
# and differ in the last bits. A result a test relies on must survive inputs moved by about
# that much: `perturbed` moves every continuous input of a log (or an array) by a relative
# 1e-9, far above rounding (1e-16) and far below any noise a log states.


def _scaled(values, relative: float, rng: np.random.Generator) -> np.ndarray:
    """`values` times (1 + relative * N(0, 1)), elementwise."""
    values = np.asarray(values, dtype=float)
    return values * (1.0 + relative * rng.standard_normal(values.shape))


def _unit_quaternion(q, relative: float, rng: np.random.Generator) -> tuple[float, ...]:
    moved = _scaled(q, relative, rng)
    return tuple(float(v) for v in moved / np.linalg.norm(moved))


def _covariance(flat, relative: float, rng: np.random.Generator) -> tuple[float, ...]:
    """D C D with D = diag(1 + relative * N(0, 1)): each entry moved by about `relative`, the
    matrix still symmetric and positive definite (a congruence), its zeros still zeros."""
    n = math.isqrt(len(flat))
    d = _scaled(np.ones(n), relative, rng)
    C = np.reshape(np.asarray(flat, dtype=float), (n, n))
    return tuple(float(v) for v in (d[:, None] * C * d[None, :]).ravel())


def _perturbed_detection(det: Detection, relative: float, rng) -> Detection:
    bearing, elevation, range_m = _scaled([det.bearing, det.elevation, det.range], relative, rng)
    relative_pose = det.relative_pose
    if relative_pose is not None:
        relative_pose = RelativePose(
            tuple(float(v) for v in _scaled(relative_pose.translation, relative, rng)),
            _unit_quaternion(relative_pose.rotation, relative, rng),
            _covariance(relative_pose.covariance, relative, rng),
        )
    return dataclasses.replace(
        det,
        # kept inside the contract's ranges (a bearing of pi moved outwards would be refused)
        bearing=float(np.clip(bearing, -math.pi, math.pi)),
        elevation=float(np.clip(elevation, -math.pi / 2, math.pi / 2)),
        range=float(range_m),
        covariance=_covariance(det.covariance, relative, rng),
        relative_pose=relative_pose,
    )


def perturbed(log_or_values, relative: float = 1e-9, *, seed: int, out=None):
    """The inputs moved by a relative `relative` (each value times 1 + relative * N(0, 1)).

    An array (or anything `np.asarray` takes) comes back perturbed. A log (a path, or a
    `DetectionLog` as `read_log` gives it) is written anew to `out` with `LogWriter`, and `out`
    is returned: every odometry step's translation and rotation (the quaternion re-normalised)
    and covariance, every detection's bearing, elevation, range and covariance, and a tag's
    relative pose the same way. Covariances are moved as D C D (still positive definite); what
    is zero stays zero, so a planar log stays planar. Metadata, ground truth, calibration,
    scores and boxes are copied as they are: they are not what the back-end computes with
    (scores and boxes are the front-end's); so are images, those of a `DetectionLog` only if
    it was read with them (a path is)."""
    rng = np.random.default_rng(seed)
    if not isinstance(log_or_values, str | os.PathLike | DetectionLog):
        return _scaled(log_or_values, relative, rng)
    if out is None:
        raise ValueError("perturbing a log needs `out`, the path of the new log")
    log = log_or_values
    if not isinstance(log, DetectionLog):
        log = read_log(log, load_images=True)
    odometry = [
        dataclasses.replace(
            o,
            translation=tuple(float(v) for v in _scaled(o.translation, relative, rng)),
            rotation=_unit_quaternion(o.rotation, relative, rng),
            covariance=_covariance(o.covariance, relative, rng),
        )
        for o in log.odometry
    ]
    detections = [
        dataclasses.replace(
            m, detections=tuple(_perturbed_detection(d, relative, rng) for d in m.detections)
        )
        for m in log.detections
    ]
    # Each topic in its own order, the topics interleaved by stamp (the writer checks both).
    topics: list[list[tuple[object, str | None]]] = [
        [(log.ground_truth_landmarks, None)] if log.ground_truth_landmarks else [],
        [(log.calibration, None)] if log.calibration else [],
        [(o, None) for o in odometry],
        [(g, None) for g in log.ground_truth_poses],
        [(m, None) for m in detections],
        *[[(image, topic) for image in images] for topic, images in sorted(log.images.items())],
    ]
    ordered = heapq.merge(*topics, key=lambda item: item[0].stamp_ns)
    with LogWriter(out, log.metadata) as writer:
        for message, topic in ordered:
            writer.write(message, topic)
    return Path(out)
