"""The detections' noise per component, from the innovations of a keyframe's sure pairings.

When a keyframe's detections are associated jointly (`methods/maxmixture`), each pairing of a
detection with a landmark seen at the keyframe before has an innovation nu = h(x_pred, l) - z
at the predicted pose, and the keyframe's joint covariance of the new pose and the landmarks
is at hand. Stacked over the keyframe's pairings, with J their Jacobians in the pose and the
landmarks:

    nu ~ N(0, J Sigma' J^T + H_x Q(s_o) H_x^T + blockdiag Gamma_k(s_m)),

Sigma' the joint with the new pose's uncertainty only what the previous pose carries over,
Q(s_o) the last odometry step's stated covariance at scales s_o, Gamma_k(s_m) each detection's
stated covariance at scales s_m (bearing, elevation, range). Both are linear in their pair
coefficients (`components.py`): one keyframe is one `ScaleObservation` of nine directions.
What the detections share (the step's error moves every bearing alike) tells s_o, what
differs between them tells s_m: the step's scales are read here as a nuisance, so that an
odometry that understates its heading is not taken for a bearing noise understated. (The
odometry's own scales come from the drift windows, `drift.py`: these innovations are gated,
and a step's large errors go to new landmarks instead, so that they read a step's noise too
small.)

Only landmarks seen at the keyframe before count: one seen longer ago carries the older steps'
error, which the model leaves in Sigma' at the scales in use.
"""

from __future__ import annotations

import numpy as np

from pipeline.backend.noise.components import ScaleObservation, nonzero_pairs, pair_basis

STEP_DIRECTIONS = 6


def innovation_observation(
    residuals: np.ndarray,
    pose_jacobians: np.ndarray,
    landmark_jacobians: np.ndarray,
    slots: np.ndarray,
    joint: np.ndarray,
    step_used: np.ndarray,
    step_stated: np.ndarray,
    measured_stated: np.ndarray,
    used: np.ndarray,
) -> ScaleObservation:
    """A keyframe's K pairings as an observation of [the step's 6 scales, the 3 measurement
    scales]: residuals (K, 3), Jacobians in the new pose (K, 3, 6) and in the landmark
    (K, 3, 3), each landmark's first row in the `joint` covariance of the new pose (rows 0-5,
    the step's `step_used` covariance included) and the landmarks, the step's stated
    covariance, each detection's stated covariance (K, 3, 3), and the 9 scales in use."""
    K = len(residuals)
    J = np.zeros((3 * K, len(joint)))
    for k, slot in enumerate(slots):
        J[3 * k : 3 * k + 3, :6] = pose_jacobians[k]
        J[3 * k : 3 * k + 3, slot : slot + 3] = landmark_jacobians[k]
    carried = joint.copy()
    carried[:6, :6] -= step_used
    rest = J @ carried @ J.T
    H = J[:, :6]
    step_pairs = nonzero_pairs(step_stated[None])
    step_basis = H @ pair_basis(step_stated, step_pairs) @ H.T
    measured_pairs = nonzero_pairs(measured_stated)
    blocks = [pair_basis(g, measured_pairs) for g in measured_stated]  # each (P, 3, 3)
    measured_basis = np.zeros((len(measured_pairs), 3 * K, 3 * K))
    for k, block in enumerate(blocks):
        measured_basis[:, 3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = block
    pairs = np.concatenate([step_pairs, measured_pairs + STEP_DIRECTIONS])
    basis = np.concatenate([step_basis, measured_basis])
    return ScaleObservation.made(
        residuals.reshape(-1), 0.5 * (rest + rest.T), basis, pairs, np.asarray(used, dtype=float)
    )
