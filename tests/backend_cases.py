"""Small back-end states built by hand: a context whose solver holds a few poses and point
landmarks, each pinned by a prior of known width, so that marginals, gates and decisions can be
worked out on paper; detections seen from those poses; records of past associations."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from pipeline.backend.candidates import Candidates, KeyframeCovariance, PosePrediction
from pipeline.backend.hypotheses import AssociationRecord
from pipeline.backend.landmarks import LandmarkKind, LandmarkMap
from pipeline.backend.measurements import Measurement, make_measurement
from pipeline.backend.methods.base import BackendContext, Keyframe
from pipeline.backend.solver import Isam2Solver
from pipeline.config import Config, load_config
from pipeline.geometry import bearing_elevation_range
from pipeline.log import Detection

CONFUSION = np.array([[0.9, 0.1], [0.1, 0.9]])
DETECTION_SIGMAS = np.array([0.01, 0.01, 0.1])  # bearing, elevation, range


def with_settings(config: Config, **sections) -> Config:
    """`config` with some settings of some sections replaced: `merges={"max_partners": 2}`."""
    return dataclasses.replace(
        config,
        **{
            name: dataclasses.replace(getattr(config, name), **values)
            for name, values in sections.items()
        },
    )


def keyframe_at(
    pose_index: int,
    pose: gtsam.Pose3 | None = None,
    measurements: list[Measurement] | None = None,
    candidates: list[Candidates] | None = None,
    joint: KeyframeCovariance | None = None,
) -> Keyframe:
    """A keyframe as the association step gets it, its pose predicted at `pose`."""
    prediction = PosePrediction(
        pose_index, X(pose_index - 1), pose or gtsam.Pose3(), np.eye(6), np.zeros((6, 6))
    )
    return Keyframe(prediction, measurements or [], candidates or [], joint)


def hand_context(config: Config | None = None, confusion: np.ndarray = CONFUSION):
    """An empty back-end state: a solver, a landmark map, nothing in either."""
    config = config or load_config()
    solver = Isam2Solver(config.isam2)
    landmarks = LandmarkMap(num_classes=confusion.shape[0], cell_size=10.0)
    return BackendContext(solver, landmarks, confusion, config)


def add_pose(context: BackendContext, index: int, pose: gtsam.Pose3, sigmas) -> None:
    """Pose `index` at `pose`, held by a prior of these tangent sigmas (rx ry rz tx ty tz)."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.broadcast_to(np.asarray(sigmas, float), (6,)))
    context.solver.add(gtsam.PriorFactorPose3(X(index), pose, noise))
    context.solver.insert(X(index), pose)


def add_landmark(
    context: BackendContext, position, sigma: float, classes=None, anchor: bool = True
) -> int:
    """A point landmark at `position` held by an isotropic prior of `sigma` (its marginal, as
    long as nothing else holds it), with these class probabilities (uniform by default)."""
    position = np.asarray(position, dtype=float)
    landmark = context.landmarks.create(LandmarkKind.POINT, position)
    if classes is not None:
        landmark.class_probabilities = np.asarray(classes, dtype=float)
    context.solver.insert(L(landmark.id), position)
    noise = gtsam.noiseModel.Isotropic.Sigma(3, sigma)
    handle = context.solver.add(gtsam.PriorFactorPoint3(L(landmark.id), position, noise))
    if anchor:  # the weak prior create_landmark gives a landmark, here the one holding it
        landmark.anchor = handle
    return landmark.id


def detection_of(
    pose: gtsam.Pose3, point, class_id: int = 0, sigmas=DETECTION_SIGMAS, truth: int | None = None
) -> Detection:
    """The exact detection of the world `point` from `pose`."""
    z = bearing_elevation_range(pose.transformTo(np.asarray(point, dtype=float)))
    return detection_at(z, class_id, sigmas, truth)


def detection_at(
    z, class_id: int = 0, sigmas=DETECTION_SIGMAS, truth: int | None = None
) -> Detection:
    """A detection measuring z = (bearing, elevation, range), with these sigmas."""
    bearing, elevation, range_m = z
    return Detection(
        class_id=class_id,
        score=0.9,
        bearing=float(bearing),
        elevation=float(elevation),
        range=float(range_m),
        covariance=tuple(np.diag(np.asarray(sigmas, float) ** 2).ravel()),
        source="bbox",
        truth_landmark_id=truth,
    )


def measurement(pose_index: int, detection: Detection, index: int = 0) -> Measurement:
    return make_measurement(pose_index, index, detection, use_relative_pose=False)


def past_record(
    context: BackendContext,
    m: Measurement,
    landmark_ids: list[int],
    weights,
    active: int,
    null_weight: float = 0.0,
) -> AssociationRecord:
    """A record as a method leaves it: its active component's factor in the solver (none if
    the null won), indexed by the context under every landmark it may be."""
    record = AssociationRecord(
        m, list(landmark_ids), np.asarray(weights, float), null_weight=null_weight, active=active
    )
    if active >= 0:
        record.handles = [context.add_factor(m, landmark_ids[active])]
    context.register(record)
    return record


def factor_keys(solver: Isam2Solver) -> list[tuple[int, ...]]:
    """The keys of every factor now in iSAM2 (after an update)."""
    graph = solver.isam.getFactorsUnsafe()
    return [
        tuple(graph.at(k).keys())
        for k in range(graph.size())
        if graph.exists(k) and graph.at(k) is not None
    ]
