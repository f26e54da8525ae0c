"""Noise nobody told you: how far a log's stated noise is from the truth, learnt online, per
direction.

A log states the covariance of every odometry step and every detection. A real front-end
leaves out part of its odometry's drift (a calibrated model, a bias), and a detector's noise
is a guess; stated wrong, the association gates are wrong, and a robust back-end stops being
robust. With `[noise] estimate` (mm-nh), the back-end learns a variance scale per direction,
applied to every stated covariance, D S D with D = diag(sqrt(s)):
- the odometry's per body-frame direction (`ODOMETRY_AXES`: roll, pitch, yaw, forward,
  lateral, vertical), from drift windows: the odometry composed over a window against the
  estimate's relative pose of the window's ends (`drift.py`), each read anew at every reading
  (a loop closed later corrects the poses inside it, and a move the whole estimate);
- a detection's per component (`MEASUREMENT_COMPONENTS`: bearing, elevation, range), from
  what each keyframe's detections disagree about at the current estimate, the pose's error
  projected out (`contrasts.py`).

Both are the same likelihood (`components.py`): each observation Gaussian with a covariance
linear in the scales' pair coefficients, each possibly an outlier (a window bent by a wrong
association, a keyframe with a wrong pairing), the scales' prior centred on the log's
statement. Every `update_every` keyframes the scales are fitted anew from the latest
observations, whatever scales they were taken under; a direction moves only when its fit lies
`deadband` times or more from its scale and its profile likelihood ratio, less the gains of the
`drop` observations that gain most, is at least `evidence` nats. A move reweights every factor
of its kind in the graph, which iSAM2 then solves anew (`learner.py`). Every move and its
evidence per direction go to metrics.json (`noise_scales`).

What a log without loops can tell: the windows see an odometry's excess only where the
landmarks decide part of a window's motion (a share e of a direction: its discrepancy's
variance is e (1 - e) + s e^2 in the stated odometry's units), so that a heading the landmarks
hardly see is learnt slowly, and a slow bias hides until a loop closes (the windows across it
say it). Only overstated or understated by more than the deadband is corrected.

`loops.py` weighs the loop tests of `merges.py` by how far the drift may still exceed the map's
covariance, from the loops closed so far.
"""

from pipeline.backend.noise.learner import HeldDetections, NoiseChange, NoiseLearner, NoiseMove
from pipeline.backend.noise.loops import DriftScaleBelief
from pipeline.backend.noise.scales import (
    MEASUREMENT_COMPONENTS,
    ODOMETRY_AXES,
    NoiseScales,
    scaled_covariance,
)

__all__ = [
    "MEASUREMENT_COMPONENTS",
    "ODOMETRY_AXES",
    "DriftScaleBelief",
    "HeldDetections",
    "NoiseChange",
    "NoiseLearner",
    "NoiseMove",
    "NoiseScales",
    "scaled_covariance",
]
