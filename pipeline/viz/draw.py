"""What a recording draws, computed from a run: pure functions on numpy, no Rerun.

Colours per class and per kind of line, uncertainty ellipsoids from covariances, each
detection's hypotheses with their weights and winner, the labels of landmarks and detections,
the reference trajectories (ground truth aligned at pose 0, dead reckoning) that the estimate is
shown against, the default eye over the map, and a trailing median for plots of noisy
per-keyframe values. The legend: `legend.py`.
"""

from __future__ import annotations

import colorsys
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.backend.association import chi2_gate
from pipeline.backend.candidates import Candidates
from pipeline.backend.hypotheses import NULL, AssociationRecord
from pipeline.geometry import quaternion_from_rotation, rotation_from_quaternion
from pipeline.log.messages import Detection, GroundTruthPose, Odometry

# Qualitative colours for the first classes (chosen to stay apart from the trajectory and
# hypothesis colours below); further classes take hues spaced by the golden angle.
_PALETTE = np.array(
    [
        [31, 119, 180],  # blue
        [255, 127, 14],  # orange
        [148, 103, 189],  # purple
        [23, 190, 207],  # cyan
        [227, 119, 194],  # pink
        [188, 189, 34],  # olive
        [140, 86, 75],  # brown
        [44, 160, 44],  # green
    ],
    dtype=np.uint8,
)

# Trajectories: the estimate bright, ground truth grey (its landmarks too), odometry a dim
# yellow (it drifts across the whole map: in full yellow it hid the estimate). The robot's
# pose: a bright yellow dot and arrow.
ESTIMATE_RGB = (245, 245, 245)
TRUTH_RGB = (125, 125, 125)
ODOMETRY_RGB = (150, 135, 60)
ROBOT_RGB = (255, 220, 0)

# Hypothesis lines: the winner stands out, losers are thin and bluish grey, the null hypothesis
# violet; switches magenta. Red is kept for what is wrong: an association whose landmark
# stands for another true landmark (`correctness.py`). Merges: ice blue.
WINNER_RGB = (60, 220, 90)
NEW_LANDMARK_RGB = (175, 240, 175)
LOSER_RGB = (140, 150, 175)
NULL_WINNER_RGB = (130, 110, 255)
NULL_LOSER_RGB = (95, 85, 160)
SWITCH_RGB = (255, 60, 255)
WRONG_RGB = (240, 40, 40)
MERGE_RGB = (120, 235, 255)

# Rerun's default vertical field of view of a 3-D view (re_view_spatial's Eye::DEFAULT_FOV_Y).
RERUN_FOV_Y = math.radians(55.0)
# The least half height (m) the default eye shows: a map of one point still gets a view.
MIN_VIEW_HALF_HEIGHT = 1.0


def packed_rgba(rgb, alpha: int = 255) -> np.ndarray:
    """Colours (..., 3) as 0xRRGGBBAA uint32: the form Rerun takes without conversion."""
    rgb = np.asarray(rgb, dtype=np.uint32)
    return (rgb[..., 0] << 24) | (rgb[..., 1] << 16) | (rgb[..., 2] << 8) | np.uint32(alpha)


def class_colors(num_classes: int) -> np.ndarray:
    """(C, 3) uint8: a distinct, deterministic colour per class."""
    colours = [_PALETTE[c] for c in range(min(num_classes, len(_PALETTE)))]
    golden = 0.618033988749895
    for c in range(len(_PALETTE), num_classes):
        hue = (0.11 + c * golden) % 1.0
        colours.append(np.array(colorsys.hsv_to_rgb(hue, 0.65, 0.9)) * 255)
    return np.array(colours, dtype=np.uint8).reshape(num_classes, 3)


def position_covariance(covariance: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
    """The 3x3 world-frame covariance of a landmark's position: a point's marginal as is; for a
    Pose3 landmark, the translation block of its 6x6 marginal (tangent order rx ry rz tx ty tz,
    perturbed in its own frame), rotated into the world by its rotation."""
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape == (3, 3):
        return covariance
    if covariance.shape != (6, 6) or rotation is None:
        raise ValueError("a 3x3 covariance, or a 6x6 one with the landmark's rotation")
    R = np.asarray(rotation, dtype=float)
    return R @ covariance[3:, 3:] @ R.T


@functools.cache
def ellipsoid_scale(confidence: float) -> float:
    """Standard deviations to the surface of the ellipsoid holding `confidence` (3 dof)."""
    return float(np.sqrt(chi2_gate(3, confidence)))


def ellipsoid(covariance: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-axes and orientation ([x, y, z, w]) of the ellipsoid holding `confidence` of a 3-D
    Gaussian with this covariance: R diag(half_sizes^2) R^T = k^2 covariance, k^2 the
    chi-square quantile with 3 dof."""
    covariance = np.asarray(covariance, dtype=float)
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if np.linalg.det(vectors) < 0:  # eigh may return a reflection; the axes are the same
        vectors[:, 0] = -vectors[:, 0]
    half_sizes = ellipsoid_scale(confidence) * np.sqrt(np.clip(values, 0.0, None))
    return half_sizes, quaternion_from_rotation(vectors)


@dataclass(frozen=True)
class Hypothesis:
    """One line of the association view: a detection and one landmark it may be (or none)."""

    detection_index: int
    landmark_id: int  # NULL for the null hypothesis
    weight: float
    winner: bool
    new_landmark: bool  # the detection made this landmark: nothing in the map matched it
    wrong: bool = False  # the winner, judged against ground truth: another object's landmark


def detection_hypotheses(
    record: AssociationRecord, candidates: Candidates, created: bool
) -> list[Hypothesis]:
    """Every landmark a detection was weighed against, with its weight, and which one won.

    GPDA's record keeps the current EM weights; a mixture keeps its components; ML commits to
    one landmark but weighed all the candidates; a detection without candidates is a new
    landmark (or, with `known`, the true one), also when mm-nh found its candidates too
    unsure. The null hypothesis comes last where it is a component. `created`: the record's
    landmark was made by this detection."""
    if record.graph_weights is not None:
        ids, weights = list(record.landmark_ids), np.asarray(record.graph_weights, dtype=float)
    else:
        # Every candidate weighed, with the record's own weight where it is a component (a
        # mixture's weights leave room for the null); then a landmark the detection made
        # itself because no candidate was a sure match.
        own = dict(zip((int(j) for j in record.landmark_ids), record.weights, strict=True))
        ids = [int(j) for j in candidates.landmark_ids]
        weights = [own.get(j, w) for j, w in zip(ids, candidates.weights, strict=True)]
        ids += [j for j in own if j not in ids]
        weights = np.array(weights + [own[j] for j in ids[len(weights) :]], dtype=float)
    winner = record.landmark_id
    k = record.measurement.detection_index
    out = [
        Hypothesis(k, int(j), float(w), int(j) == winner, created and int(j) == winner)
        for j, w in zip(ids, weights, strict=True)
    ]
    if record.null_weight > 0:
        out.append(Hypothesis(k, NULL, float(record.null_weight), winner == NULL, False))
    return out


def hypothesis_style(h: Hypothesis) -> tuple[tuple[int, int, int], float]:
    """Colour and width (UI points) of a hypothesis line: wider with weight, winner brightest,
    a wrong winner red."""
    if h.landmark_id == NULL:
        colour = NULL_WINNER_RGB if h.winner else NULL_LOSER_RGB
    elif h.winner and h.wrong:
        colour = WRONG_RGB
    elif h.winner:
        colour = NEW_LANDMARK_RGB if h.new_landmark else WINNER_RGB
    else:
        colour = LOSER_RGB
    width = (2.5 if h.winner else 0.75) + 2.0 * min(max(h.weight, 0.0), 1.0)
    return colour, width


def hypothesis_label(h: Hypothesis) -> str:
    """Short, for a line in the map: the landmark end carries the landmark's own label."""
    if h.landmark_id == NULL:
        return f"null {h.weight:.2f}"
    return "new" if h.new_landmark else f"{h.weight:.2f}"


def landmark_label(landmark_id: int, class_name: str, probability: float) -> str:
    return f"L{landmark_id} {class_name} {probability:.2f}"


def detection_label(detection: Detection, name: str, winner: int | None = None) -> str:
    """A detection in an image or the body frame: what it reported, how sure, how far, and
    the landmark it went to (when known). `name`: its class name, or the tag it read."""
    label = f"{name} {detection.score:.2f} {detection.range:.1f} m"
    if winner is None:
        return label
    return f"{label} → {'null' if winner == NULL else f'L{winner}'}"


def trailing_median(values: Sequence[float], window: int) -> float:
    """The median of the last `window` values: per-keyframe times read as a trend, not spikes."""
    return float(np.median(values[-window:]))


def top_down_eye(
    points: np.ndarray, aspect: float, tilt: float, margin: float = 1.1, fov_y: float = RERUN_FOV_Y
) -> tuple[np.ndarray, np.ndarray]:
    """Position and target of a 3-D view's eye that looks down on all `points` (N, 3): above
    the middle of their box, tilted by `tilt` (rad) from the vertical towards -y so that a Z-up
    orbit stays defined, far enough that the box, times `margin`, fits a view of this aspect
    (width / height)."""
    low, high = np.min(points, axis=0), np.max(points, axis=0)
    target = 0.5 * (low + high)
    half_x, half_y = 0.5 * (high[:2] - low[:2])
    half_height = max(half_y, half_x / aspect, MIN_VIEW_HALF_HEIGHT)
    distance = margin * half_height / math.tan(0.5 * fov_y) + 0.5 * (high[2] - low[2])
    position = target + distance * np.array([0.0, -math.sin(tilt), math.cos(tilt)])
    return position, target


def _matrix(translation, rotation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation_from_quaternion(np.asarray(rotation, dtype=float))
    T[:3, 3] = translation
    return T


def ground_truth_alignment(poses: list[GroundTruthPose]) -> np.ndarray | None:
    """The transform taking ground truth into the estimate's frame, where pose 0 is the origin
    (the contract's alignment at the first pose); None without a ground-truth pose 0."""
    for message in poses:
        if message.pose_index == 0:
            return np.linalg.inv(_matrix(message.translation, message.rotation))
    return None


def aligned_ground_truth(
    poses: list[GroundTruthPose], alignment: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pose indices and aligned positions (N, 3) of the ground-truth poses, in index order."""
    ordered = sorted(poses, key=lambda m: m.pose_index)
    indices = np.array([m.pose_index for m in ordered], dtype=int)
    if not ordered:
        return indices, np.zeros((0, 3))
    positions = np.array([m.translation for m in ordered], dtype=float)
    return indices, positions @ alignment[:3, :3].T + alignment[:3, 3]


def aligned_points(points, alignment: np.ndarray) -> np.ndarray:
    """Points (N, 3) of the ground truth's frame in the estimate's."""
    return np.asarray(points, dtype=float).reshape(-1, 3) @ alignment[:3, :3].T + alignment[:3, 3]


def dead_reckoning_poses(odometry: list[Odometry]) -> np.ndarray:
    """The poses (N + 1, 4, 4) the odometry alone gives, from the origin."""
    poses = [np.eye(4)]
    for step in odometry:
        poses.append(poses[-1] @ _matrix(step.translation, step.rotation))
    return np.array(poses)


def dead_reckoning(odometry: list[Odometry]) -> np.ndarray:
    """Positions (N + 1, 3) of the poses the odometry alone gives, from the origin."""
    return dead_reckoning_poses(odometry)[:, :3, 3]


def body_to_world(rows: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points in the body frame of poses given as flat rows [R (9, row-major), t (3)]."""
    rows = np.atleast_2d(rows)
    R = rows[:, :9].reshape(-1, 3, 3)
    return np.einsum("nij,nj->ni", R, np.atleast_2d(points)) + rows[:, 9:]
