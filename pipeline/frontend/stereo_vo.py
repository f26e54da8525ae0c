"""Sparse stereo visual odometry: keyframe to frame, PnP with RANSAC, Gauss-Newton refinement.

At a keyframe, FAST corners of the left image are matched into the right image with pyramidal
Lucas-Kanade (rectified images: the match must stay on its row) and triangulated. Every following
frame tracks those corners frame to frame (Lucas-Kanade from a constant-velocity prediction,
kept only where tracking back returns to the start) and solves the pose of the current camera
in the keyframe's camera frame from the keyframe's 3-D points: P3P inside RANSAC, then
Gauss-Newton on the inliers, weighting each residual by the pixel noise plus the projected
uncertainty of its triangulated point. A new keyframe starts when the camera has moved or
turned enough, after a number of frames, or when too few corners are still tracked; its motion
from the last keyframe (in the body frame) is one odometry step of the log.

A motion is refused when fewer than a fraction of the tracked corners fit it: many wrong tracks
of the same kind (fast motion, repeated texture) agree with each other on a wrong motion, and
then RANSAC finds them. A frame whose tracking fails is looked for again: the keyframe's corners
are matched into it by ORB descriptors, whose motion predicts where to track them from the
keyframe. If that fails too, the step is logged as lost: constant velocity with a large
covariance, and a new keyframe starts.

Covariance, from the data of each fit: the inverse of the Gauss-Newton information of the
inliers (their geometry: how many, how far, how spread over the image), scaled by the residual
variance the fit shows (its chi-square per degree of freedom, which may be below 1: tracked
corners often agree better than the prior pixel noise says; never below `min_residual_scale`,
as a handful of residuals can agree by chance), plus what the residuals cannot show
(`unseen_covariance`):

- The rig's disparity offset: a calibration error that shifts every disparity alike moves
  every point along its ray by offset / disparity of its depth, far points most; the pose
  absorbs most of it (the step's scale and the turn with it) and the residuals barely show
  it. Each fit also estimates the offset with the pose (`common_offset_fit`: near and far
  points disagree about it), the odometry pools the estimates of its steps (a Gaussian prior
  of `disparity_offset_sigma`, forgetting over `disparity_offset_memory` keyframes), and the
  pooled second moment along the fit's sensitivity to the offset is added. Real KITTI clips
  show 0.4-1.2 px (a scale 1-7 % off on far scenes); renders, calibrated exactly, ~0.
- The camera against the vehicle (focal length, principal point, mounting) known to about
  half a degree: each rotation axis within `rotation_sigma_fraction` of the turn, the travel's
  direction within `direction_sigma`.
- Constant floors: the ground truth's own noise and what else is left.

Calibrated on a real KITTI clip outside the project and rendered drives at several noise
levels, and checked on others; `python -m data_tools.bench_frontend --odometry` prints the NEES
per clip. The covariance never changes the motion.

Poses are estimated directly from keyframe to frame, so no drift builds up between keyframes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.datasets.camera import StereoIntrinsics
from pipeline.frontend.config import KeyframeConfig, VoConfig
from pipeline.frontend.geometry import (
    camera_to_body_motion,
    invert_pose,
    project,
    projection_jacobian,
    rotation_angle,
    se3_exp,
    skew,
    stereo_pixel_covariance,
    triangulate,
    triangulation_jacobian,
)

log = logging.getLogger(__name__)

# Chi-square of 2 degrees of freedom at 0.99: a residual beyond this is an outlier.
CHI2_2DOF_99 = 9.21
CHI2_2DOF_MEDIAN = 1.386
UNGATED_ITERATIONS = 2


@dataclass(frozen=True)
class KeyframeStep:
    """A new keyframe and its motion since the previous one, in the body frame."""

    frame_index: int
    motion: np.ndarray  # 4x4: this keyframe's body pose in the previous keyframe's body frame
    covariance: np.ndarray  # 6x6, tangent order (rx, ry, rz, tx, ty, tz), right perturbation
    inliers: int
    lost: bool  # tracking failed: the motion is a constant-velocity guess


def direction_covariance(translation: np.ndarray, sigma: float) -> np.ndarray:
    """Covariance (3x3) of a translation whose direction is known to `sigma` radians about
    every axis: turning it by a small `phi` moves it by `phi x t`, across itself; `sigma^2
    [t]x [t]x^T`."""
    across = skew(np.asarray(translation, float))
    return sigma**2 * across @ across.T


def unseen_covariance(
    camera_motion: np.ndarray,
    offset_sensitivity: np.ndarray,
    offset_second_moment: float,
    config: VoConfig,
) -> np.ndarray:
    """What a step's fit cannot show, as a covariance (6x6) over the same right perturbation of
    `camera_motion` (the current camera in the keyframe's): the rig's disparity offset (its
    second moment along the fit's `offset_sensitivity`), a turn seen to within
    `rotation_sigma_fraction` of its angle on each rotation axis, a travel direction known to
    `direction_sigma` radians, and constant floors."""
    rotation, translation = camera_motion[:3, :3], camera_motion[:3, 3]
    covariance = offset_second_moment * np.outer(offset_sensitivity, offset_sensitivity)
    turn = config.rotation_sigma_fraction * rotation_angle(rotation)
    covariance[:3, :3] += np.eye(3) * (config.min_sigma_rotation**2 + turn**2)
    covariance[3:, 3:] += np.eye(3) * config.min_sigma_translation**2
    # The perturbation's translation is in the current camera's frame: R^T t there.
    covariance[3:, 3:] += direction_covariance(rotation.T @ translation, config.direction_sigma)
    return covariance


@dataclass(frozen=True)
class StereoFeatures:
    """Corners of a keyframe with their 3-D points in its camera frame."""

    pixels: np.ndarray  # (N, 2) left-image pixels
    points: np.ndarray  # (N, 3) camera frame
    covariances: np.ndarray  # (N, 3, 3)


@dataclass(frozen=True)
class CommonOffset:
    """One error shared by every residual of a fit (here: a disparity offset of the rig)."""

    sensitivity: np.ndarray  # (6,): how the fitted pose moves per unit of the offset
    estimate: float  # the offset the residuals show (fitted together with the pose)
    information: float  # the inverse variance of `estimate`


@dataclass(frozen=True)
class PoseFit:
    camera_pose: np.ndarray  # 4x4: the current camera in the keyframe's camera frame
    covariance: np.ndarray  # 6x6 over a right perturbation of camera_pose
    inliers: np.ndarray  # bool (N,)
    chi2_per_dof: float
    disparity_offset: CommonOffset  # the rig's disparity offset: its effect and estimate


def _klt_criteria(iterations: int) -> tuple[int, int, float]:
    return (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, iterations, 0.01)


def track_points(
    previous: np.ndarray,
    current: np.ndarray,
    pixels: np.ndarray,
    window: int,
    levels: int,
    iterations: int,
    max_backward_error: float | None,
    guess: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Lucas-Kanade from `previous` to `current`, kept only where tracking back returns within
    `max_backward_error` px (no check if None). Returns the new pixels (N, 2) and a mask."""
    if len(pixels) == 0:
        return pixels.reshape(0, 2), np.zeros(0, bool)
    start = pixels.astype(np.float32).reshape(-1, 1, 2)
    flags = 0
    target = None
    if guess is not None:
        target = guess.astype(np.float32).reshape(-1, 1, 2)
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    size = (window, window)
    criteria = _klt_criteria(iterations)
    forward, ok, _ = cv2.calcOpticalFlowPyrLK(
        previous,
        current,
        start,
        target,
        winSize=size,
        maxLevel=levels,
        criteria=criteria,
        flags=flags,
    )
    good = ok.ravel().astype(bool)
    if max_backward_error is not None:
        backward, ok_back, _ = cv2.calcOpticalFlowPyrLK(
            current,
            previous,
            forward,
            start.copy(),
            winSize=size,
            maxLevel=levels,
            criteria=criteria,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        error = np.linalg.norm((backward - start).reshape(-1, 2), axis=1)
        good &= ok_back.ravel().astype(bool) & (error < max_backward_error)
    return forward.reshape(-1, 2).astype(float), good


def detect_corners(image: np.ndarray, threshold: int, cell: int, max_count: int) -> np.ndarray:
    """FAST corners, the strongest one in each `cell` x `cell` square (so that they spread over
    the image), at most `max_count` of them, strongest first: (N, 2) pixels."""
    keypoints = cv2.FastFeatureDetector_create(threshold, True).detect(image)
    if not keypoints:
        return np.zeros((0, 2))
    pixels = cv2.KeyPoint_convert(keypoints).astype(float)
    response = np.array([k.response for k in keypoints])
    columns = -(-image.shape[1] // cell)
    cells = (pixels[:, 1] // cell).astype(int) * columns + (pixels[:, 0] // cell).astype(int)
    order = np.lexsort((-response, cells))  # by cell, strongest first within a cell
    first_in_cell = np.r_[True, cells[order][1:] != cells[order][:-1]]
    best = order[first_in_cell]
    best = best[np.argsort(-response[best], kind="stable")][:max_count]
    return pixels[best]


def match_stereo(
    left: np.ndarray, right: np.ndarray, pixels: np.ndarray, config: VoConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Disparities (N,) of left pixels, and a mask of the good ones: tracked into the right
    image and back, on the same row, with a disparity in range."""
    right_pixels, good = track_points(
        left,
        right,
        pixels,
        config.tracking_window,
        config.stereo_levels,
        config.tracking_iterations,
        config.max_backward_error,
    )
    disparity = pixels[:, 0] - right_pixels[:, 0]
    good &= np.abs(right_pixels[:, 1] - pixels[:, 1]) <= config.max_row_error
    good &= (disparity >= config.min_disparity) & (disparity <= config.max_disparity)
    return disparity, good


def stereo_diagnosis(left: np.ndarray, right: np.ndarray, config: VoConfig) -> str:
    """A guess, from one stereo pair, at why no frame of a sequence could be tracked."""
    corners = detect_corners(left, config.fast_threshold, config.feature_cell, config.max_features)
    if len(corners) < config.min_inliers:
        return (
            f"too few corners ({len(corners)}) in the first {left.shape[1]}x{left.shape[0]} "
            "left image: too small, blurred or blank?"
        )
    matched = int(match_stereo(left, right, corners, config)[1].sum())
    # Swapped images: the right image's corners match into the left one instead.
    other = detect_corners(right, config.fast_threshold, config.feature_cell, config.max_features)
    if match_stereo(right, left, other, config)[1].sum() > 2 * max(matched, config.min_inliers):
        return "the left and right images look swapped"
    return f"{matched} of {len(corners)} corners of the first frame match in stereo"


def stereo_features(
    pixels: np.ndarray, disparity: np.ndarray, intrinsics: StereoIntrinsics, pixel_sigma: float
) -> StereoFeatures:
    """Left pixels with their disparities, triangulated, with each point's covariance."""
    uvd = np.column_stack([pixels, disparity])
    jacobian = triangulation_jacobian(uvd, intrinsics)
    covariances = jacobian @ stereo_pixel_covariance(pixel_sigma) @ np.swapaxes(jacobian, 1, 2)
    return StereoFeatures(pixels, triangulate(uvd, intrinsics), covariances)


def detect_stereo_features(
    left: np.ndarray, right: np.ndarray, intrinsics: StereoIntrinsics, config: VoConfig
) -> StereoFeatures:
    """Corners of the left image that match into the right one, triangulated."""
    pixels = detect_corners(left, config.fast_threshold, config.feature_cell, config.max_features)
    disparity, good = match_stereo(left, right, pixels, config)
    return stereo_features(pixels[good], disparity[good], intrinsics, config.pixel_sigma)


def refine_pose(
    camera_pose: np.ndarray,
    points: np.ndarray,
    point_covariances: np.ndarray,
    pixels: np.ndarray,
    intrinsics: StereoIntrinsics,
    pixel_sigma: float,
    iterations: int,
    start_inliers: np.ndarray | None = None,
    min_residual_scale: float = 1.0,
) -> PoseFit:
    """Gauss-Newton on the reprojection of keyframe points into the current left image.

    The unknown is `T` = the current camera in the keyframe's camera frame, perturbed on the
    right; a point `P` is seen at `project(T^-1 P)`. Each residual is weighted by the inverse
    of `pixel_sigma^2 I + J_P Sigma_P J_P^T`. The first two iterations use `start_inliers`
    (default: every point); after them the inliers are re-selected among all points at every
    iteration: chi-square within 9.21 (2 dof, 0.99) times the robust scale of the last
    inliers' residuals, if above 1. The covariance is `fit_covariance`'s; the rig's disparity
    offset is fitted against the final pose and inliers (`common_offset_fit`).
    """
    start = np.ones(len(points), bool) if start_inliers is None else np.asarray(start_inliers)
    pose = camera_pose.copy()
    inliers = start.copy()
    information = np.eye(6)
    chi2 = np.zeros(len(points))
    for iteration in range(iterations + 1):
        rotation, translation = pose[:3, :3], pose[:3, 3]
        local = (points - translation) @ rotation  # T^-1 P for every point
        in_front = local[:, 2] > 1e-3
        safe = np.where(in_front[:, None], local, np.array([0.0, 0.0, 1.0]))
        residual = pixels - project(safe, intrinsics)
        projection = projection_jacobian(safe, intrinsics)  # (N, 2, 3)
        # d(local)/d(xi) for T Exp(xi): [skew(local), -I]; d(local)/dP = R^T.
        d_local = np.zeros((len(points), 3, 6))
        d_local[:, :, :3] = skew(safe)
        d_local[:, :, 3:] = -np.eye(3)
        jacobian = projection @ d_local  # (N, 2, 6)
        point_jacobian = projection @ rotation.T
        noise = pixel_sigma**2 * np.eye(2) + point_jacobian @ point_covariances @ np.swapaxes(
            point_jacobian, 1, 2
        )
        weight = np.linalg.inv(noise)
        chi2 = np.einsum("ni,nij,nj->n", residual, weight, residual)
        # The first steps use the starting set (RANSAC's inliers: the start may be a few pixels
        # off); the gate then chooses among all points by the refined pose. It widens with the
        # robust scale (median) of the last inliers' residuals, so that noise larger than
        # pixel_sigma widens the covariance instead of thinning the points; outliers, however
        # many, do not widen it.
        previous = inliers & in_front
        inliers = start & in_front
        if iteration >= UNGATED_ITERATIONS and previous.any():
            scale = max(1.0, float(np.median(chi2[previous])) / CHI2_2DOF_MEDIAN)
            inliers = in_front & (chi2 < CHI2_2DOF_99 * scale)
        if inliers.sum() < 3:
            break
        jw = np.swapaxes(jacobian[inliers], 1, 2) @ weight[inliers]  # (M, 6, 2)
        information = np.einsum("nij,njk->ik", jw, jacobian[inliers])
        gradient = np.einsum("nij,nj->i", jw, residual[inliers])
        if iteration == iterations:
            break
        try:
            step = np.linalg.solve(information, gradient)
        except np.linalg.LinAlgError:
            break
        pose = pose @ se3_exp(step)
        if np.linalg.norm(step) < 1e-9:
            break
    dof = max(2 * int(inliers.sum()) - 6, 1)
    chi2_per_dof = float(chi2[inliers].sum() / dof) if inliers.any() else float("inf")
    covariance = fit_covariance(information, chi2_per_dof, min_residual_scale)
    offset = CommonOffset(np.zeros(6), 0.0, 0.0)
    if inliers.sum() >= 3:
        offset = common_offset_fit(
            jacobian[inliers],
            weight[inliers],
            residual[inliers],
            disparity_offset_jacobian(points[inliers], point_jacobian[inliers], intrinsics),
            information,
            max(min_residual_scale, chi2_per_dof),
        )
    return PoseFit(pose, covariance, inliers, chi2_per_dof, offset)


def disparity_offset_jacobian(
    points: np.ndarray, point_jacobian: np.ndarray, intrinsics: StereoIntrinsics
) -> np.ndarray:
    """d(predicted pixel)/d(disparity offset), (N, 2): how each keyframe point's prediction in
    the current image moves when its disparity is one pixel larger. A point triangulated from
    disparity `d = fx b / z` moves by `dP/dd = -P z / (fx b)` along its ray; `point_jacobian`
    (N, 2, 3) is d(pixel)/d(P) of each point."""
    along_ray = -points * (points[:, 2:3] / (intrinsics.fx * intrinsics.baseline))
    return np.einsum("nij,nj->ni", point_jacobian, along_ray)


def common_offset_fit(
    jacobian: np.ndarray,
    weight: np.ndarray,
    residual: np.ndarray,
    offset_jacobian: np.ndarray,
    information: np.ndarray,
    residual_scale: float,
) -> CommonOffset:
    """A weighted least-squares pose fit (J: (N, 2, 6), W: (N, 2, 2), residuals r: (N, 2),
    `information` = J^T W J) against one error common to every residual that shifts the
    predictions by `offset_jacobian` g (N, 2) per unit:

    - sensitivity `s = -(J^T W J)^-1 J^T W g`: how the fitted pose moves per unit of it;
    - the offset fitted together with the pose (the Schur complement of the 7-parameter
      normal equations): `(g^T W r + s^T J^T W r) / S`, with `S = g^T W g + s^T J^T W g`;
    - its information `S / residual_scale` (W is the prior noise's; `residual_scale` the
      residual variance relative to it).

    Nothing known (zeros) where the equations cannot be solved."""
    pull = np.einsum("nji,njk,nk->i", jacobian, weight, offset_jacobian)
    nothing = CommonOffset(np.zeros(6), 0.0, 0.0)
    try:
        sensitivity = -np.linalg.solve(information, pull)
    except np.linalg.LinAlgError:
        return nothing
    schur = float(np.einsum("ni,nij,nj->", offset_jacobian, weight, offset_jacobian))
    schur += float(sensitivity @ pull)
    gradient = np.einsum("nji,njk,nk->i", jacobian, weight, residual)
    shown = float(np.einsum("ni,nij,nj->", offset_jacobian, weight, residual))
    if not (np.all(np.isfinite(sensitivity)) and schur > 0 and residual_scale > 0):
        return nothing
    return CommonOffset(
        sensitivity, (shown + sensitivity @ gradient) / schur, schur / residual_scale
    )


def offset_second_moment(prior_sigma: float, information: float, weighted_sum: float) -> float:
    """E[offset^2] after estimates of an offset with total `information` and
    `weighted_sum` = sum(information_k * estimate_k), starting from a prior N(0, prior_sigma^2):
    the posterior mean squared plus the posterior variance. It is the prior's variance before
    any estimate, and the estimates' mean squared after many."""
    total = prior_sigma**-2 + information
    return (weighted_sum / total) ** 2 + 1.0 / total


def fit_covariance(
    information: np.ndarray, chi2_per_dof: float, min_residual_scale: float
) -> np.ndarray:
    """The covariance of a Gauss-Newton fit: the inverse of its information `J^T W J` (W from
    the prior pixel noise), scaled by the residual variance the fit shows relative to that
    prior (`chi2_per_dof`), never below `min_residual_scale`. An information matrix that
    cannot be inverted gives a covariance of 1 (rad^2, m^2) on every axis: nothing known."""
    try:
        covariance = np.linalg.inv(information) * max(min_residual_scale, chi2_per_dof)
    except np.linalg.LinAlgError:
        return np.eye(6)
    if not np.all(np.isfinite(covariance)):
        return np.eye(6)
    return 0.5 * (covariance + covariance.T)


def solve_pnp(
    features: StereoFeatures,
    pixels: np.ndarray,
    intrinsics: StereoIntrinsics,
    config: VoConfig,
    min_inlier_fraction: float | None = None,
) -> PoseFit | None:
    """The current camera in the keyframe's camera frame from tracked keyframe points, or None
    when fewer than `min_inliers` of them, or fewer than `min_inlier_fraction` of them (default:
    the config's), fit one motion: many tracks that disagree mean that those that agree may
    agree by chance (wrong tracks of the same kind agree on a wrong motion)."""
    if min_inlier_fraction is None:
        min_inlier_fraction = config.min_inlier_fraction
    if len(pixels) < max(config.min_inliers, 4):
        return None
    ok, rvec, tvec, ransac_inliers = cv2.solvePnPRansac(
        features.points.astype(np.float64),
        pixels.astype(np.float64),
        intrinsics.camera_matrix,
        None,
        iterationsCount=config.ransac_iterations,
        reprojectionError=config.ransac_threshold,
        confidence=0.999,
        flags=cv2.SOLVEPNP_P3P,
    )
    if not ok or ransac_inliers is None or len(ransac_inliers) < config.min_inliers:
        return None
    camera_from_keyframe = np.eye(4)
    camera_from_keyframe[:3, :3] = cv2.Rodrigues(rvec)[0]
    camera_from_keyframe[:3, 3] = tvec.ravel()
    start = np.zeros(len(pixels), bool)
    start[np.ravel(ransac_inliers)] = True
    fit = refine_pose(
        invert_pose(camera_from_keyframe),
        features.points,
        features.covariances,
        pixels,
        intrinsics,
        config.pixel_sigma,
        config.refine_iterations,
        start,
        config.min_residual_scale,
    )
    inliers = int(fit.inliers.sum())
    if inliers < config.min_inliers or inliers < min_inlier_fraction * len(pixels):
        log.debug("%d of %d tracked corners fit the motion: refused", inliers, len(pixels))
        return None
    return fit


def match_descriptors(
    first: np.ndarray, second: np.ndarray, count: int, ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """ORB features of two images matched by their descriptors (Lowe's ratio test): their pixels
    in the first and in the second image, (N, 2) each. The descriptors are upright: a stereo
    rig hardly rolls between two frames, and more of them match."""
    orb = cv2.ORB_create(nfeatures=count)
    described = []
    for image in (first, second):
        keypoints = orb.detect(image, None)
        for keypoint in keypoints:
            keypoint.angle = 0.0
        described.append(orb.compute(image, keypoints))
    (first_points, first_descriptors), (second_points, second_descriptors) = described
    if first_descriptors is None or second_descriptors is None or len(second_points) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(first_descriptors, second_descriptors, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    return (
        np.array([first_points[m.queryIdx].pt for m in good], float).reshape(-1, 2),
        np.array([second_points[m.trainIdx].pt for m in good], float).reshape(-1, 2),
    )


def _subset(features: StereoFeatures, mask: np.ndarray) -> StereoFeatures:
    return StereoFeatures(features.pixels[mask], features.points[mask], features.covariances[mask])


# A motion, the keyframe features that fit it, and their pixels in the current frame.
Tracked = tuple[PoseFit, StereoFeatures, np.ndarray]


class StereoOdometry:
    """Feed frames in order with `process`; it returns a `KeyframeStep` at each new keyframe.

    The first frame processed is keyframe 0 (pose 0 of the log) and returns None; `finish`
    after the last frame makes that frame a keyframe too. `lost_count` counts the steps logged
    as lost, `recovered_count` the frames whose tracking was found again by descriptors.
    """

    def __init__(
        self, intrinsics: StereoIntrinsics, config: VoConfig, keyframes: KeyframeConfig
    ) -> None:
        self.intrinsics = intrinsics
        self.config = config
        self.keyframe_rules = keyframes
        self.keyframe_index: int | None = None  # frame index of the current keyframe
        self._keyframe_features = StereoFeatures(
            np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3, 3))
        )
        self._keyframe_images: tuple[np.ndarray, np.ndarray] | None = None
        self._features = self._keyframe_features  # those still tracked
        self._tracked = np.zeros((0, 2))  # pixels of the keyframe's features in the last frame
        self._previous_image: np.ndarray | None = None
        self._previous_pose = np.eye(4)  # last frame's camera in the keyframe's camera frame
        self._frame_motion = np.eye(4)  # last frame-to-frame camera motion (constant velocity)
        self._pending: KeyframeStep | None = None  # the last frame, were it made a keyframe
        self._velocity_known = False  # whether _frame_motion was measured
        self._force_keyframe = False  # the last fit is the descriptors': start afresh
        self.lost_count = 0
        self.recovered_count = 0
        # The disparity offset's estimates so far (forgetting the old ones slowly): their
        # information and information-weighted sum.
        self._offset_information = 0.0
        self._offset_sum = 0.0

    def process(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> KeyframeStep | None:
        if self.keyframe_index is None:
            self._start_keyframe(frame_index, left, right)
            return None
        # Without a motion to predict from (the first frame, or after a loss), the prediction
        # comes from descriptors first: Lucas-Kanade from a guess metres off can lock onto
        # repeated texture, the same wrong way back and forth.
        found = None if self._velocity_known else self._recover(left)
        if found is None:
            found = self._track(left)
        if found is None and self._velocity_known:
            found = self._recover(left)
        if found is None:
            return self._lost(frame_index, left, right)
        fit, self._features, self._tracked = found
        self._previous_image = left
        self._velocity_known = True
        frames_since = frame_index - self.keyframe_index
        pose = fit.camera_pose
        tracked_fraction = fit.inliers.sum() / max(len(self._keyframe_features.pixels), 1)
        rules = self.keyframe_rules
        new_keyframe = (
            self._force_keyframe
            or np.linalg.norm(pose[:3, 3]) >= rules.min_translation
            or rotation_angle(pose[:3, :3]) >= rules.min_rotation
            or frames_since >= rules.max_frames
            or tracked_fraction < rules.min_tracked_fraction
        )
        self._frame_motion = invert_pose(self._previous_pose) @ pose
        self._previous_pose = pose
        step = self._step(frame_index, fit)
        if not new_keyframe:
            self._pending = step
            return None
        self._start_keyframe(frame_index, left, right)
        return step

    def finish(self) -> KeyframeStep | None:
        """Make the last frame processed a keyframe, if it is not one already, so that the
        poses cover the whole sequence."""
        step, self._pending = self._pending, None
        if step is not None:
            self.keyframe_index = step.frame_index
        return step

    def _step(self, frame_index: int, fit: PoseFit) -> KeyframeStep:
        c, offset = self.config, fit.disparity_offset
        keep = 1.0 - 1.0 / c.disparity_offset_memory
        self._offset_information = keep * self._offset_information + offset.information
        self._offset_sum = keep * self._offset_sum + offset.information * offset.estimate
        second_moment = offset_second_moment(
            c.disparity_offset_sigma, self._offset_information, self._offset_sum
        )
        covariance = fit.covariance + unseen_covariance(
            fit.camera_pose, offset.sensitivity, second_moment, c
        )
        motion, body_covariance = camera_to_body_motion(fit.camera_pose, covariance)
        return KeyframeStep(frame_index, motion, body_covariance, int(fit.inliers.sum()), False)

    def _track(self, left: np.ndarray) -> Tracked | None:
        """The keyframe's corners tracked from the last frame into this one, from where the
        constant-velocity motion puts them, and the motion they give."""
        assert self._previous_image is not None
        if len(self._tracked) == 0:
            return None
        predicted_pose = self._previous_pose @ self._frame_motion
        guess = self._predict(self._features, self._tracked, predicted_pose)
        return self._track_from(self._features, self._previous_image, self._tracked, guess, left)

    def _recover(self, left: np.ndarray) -> Tracked | None:
        """Tracking from the last frame failed (a sudden turn or jolt): match ORB features of
        the keyframe and this frame, triangulate the keyframe's side, and solve the motion from
        those matches. It predicts where to track the keyframe's corners again, from the
        keyframe straight to this frame. Where they cannot be tracked so far (a large change of
        scale), the descriptors' own fit is the motion, if enough of the matches agree with it,
        and this frame becomes a keyframe."""
        assert self._keyframe_images is not None
        c = self.config
        keyframe_left, keyframe_right = self._keyframe_images
        ours, theirs = match_descriptors(keyframe_left, left, c.recovery_features, c.recovery_ratio)
        disparity, good = match_stereo(keyframe_left, keyframe_right, ours, c)
        matched = stereo_features(ours[good], disparity[good], self.intrinsics, c.pixel_sigma)
        # Descriptor matches are often wrong (repeated texture): RANSAC alone picks the motion
        # that predicts the tracks, which must then pass the usual checks.
        rough = solve_pnp(matched, theirs[good], self.intrinsics, c, min_inlier_fraction=0.0)
        if rough is None:
            return None
        keyframe = self._keyframe_features
        guess = self._predict(keyframe, keyframe.pixels, rough.camera_pose)
        found = self._track_from(keyframe, keyframe_left, keyframe.pixels, guess, left)
        if found is None and rough.inliers.sum() >= c.min_inlier_fraction * len(rough.inliers):
            self._force_keyframe = True
            found = rough, _subset(matched, rough.inliers), theirs[good][rough.inliers]
        if found is not None:
            self.recovered_count += 1
            log.info("visual odometry: tracking found again by descriptors")
        return found

    def _predict(
        self, features: StereoFeatures, fallback: np.ndarray, camera_pose: np.ndarray
    ) -> np.ndarray:
        """Where the features' points project from `camera_pose`; `fallback` for points that
        would be behind or too near the camera."""
        local = (features.points - camera_pose[:3, 3]) @ camera_pose[:3, :3]
        guess = fallback.copy()
        ahead = local[:, 2] > 0.5
        guess[ahead] = project(local[ahead], self.intrinsics)
        return guess

    def _track_from(
        self,
        features: StereoFeatures,
        image: np.ndarray,
        pixels: np.ndarray,
        guess: np.ndarray,
        left: np.ndarray,
    ) -> Tracked | None:
        """Lucas-Kanade of `features`, seen at `pixels` in `image`, into `left` from `guess`;
        the motion, and the features that fit it with their pixels in `left`."""
        c = self.config
        tracked, good = track_points(
            image,
            left,
            pixels,
            c.tracking_window,
            c.tracking_levels,
            c.tracking_iterations,
            c.max_backward_error if c.temporal_backward_check else None,
            guess,
        )
        height, width = left.shape[:2]
        good &= (tracked[:, 0] >= 0) & (tracked[:, 0] < width)
        good &= (tracked[:, 1] >= 0) & (tracked[:, 1] < height)
        features, tracked = _subset(features, good), tracked[good]
        fit = solve_pnp(features, tracked, self.intrinsics, c)
        if fit is None:
            return None
        return fit, _subset(features, fit.inliers), tracked[fit.inliers]

    def _lost(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> KeyframeStep:
        """No motion that can be trusted: assume constant velocity, say so in the covariance,
        and start over from this frame."""
        self.lost_count += 1
        log.debug("visual odometry lost at frame %d: constant velocity assumed", frame_index)
        pose = self._previous_pose @ self._frame_motion
        c = self.config
        sigmas = np.array([c.lost_sigma_rotation] * 3 + [c.lost_sigma_translation] * 3)
        motion, covariance = camera_to_body_motion(pose, np.diag(sigmas**2))
        self._start_keyframe(frame_index, left, right)
        self._velocity_known = False
        return KeyframeStep(frame_index, motion, covariance, 0, True)

    def _start_keyframe(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> None:
        self.keyframe_index = frame_index
        self._pending = None
        self._force_keyframe = False
        self._keyframe_features = detect_stereo_features(left, right, self.intrinsics, self.config)
        self._keyframe_images = (left, right)
        self._features = self._keyframe_features
        self._tracked = self._features.pixels.copy()
        self._previous_image = left
        self._previous_pose = np.eye(4)
        log.debug("keyframe at frame %d: %d stereo features", frame_index, len(self._tracked))
