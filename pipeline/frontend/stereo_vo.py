"""Sparse stereo visual odometry: keyframe to frame, PnP with RANSAC, Gauss-Newton refinement.

At a keyframe, Shi-Tomasi corners of the left image are matched into the right image with
pyramidal Lucas-Kanade (rectified images: the match must stay on its row) and triangulated.
Every following frame tracks those corners frame to frame (Lucas-Kanade, checked backwards) and
solves the pose of the current camera in the keyframe's camera frame from the keyframe's 3-D
points: P3P inside RANSAC, then Gauss-Newton on the inliers, weighting each residual by the
pixel noise plus the projected uncertainty of its triangulated point. The covariance is the
inverse of the Gauss-Newton information, scaled by the fit's chi-square per degree of freedom
(never below 1), plus a floor. A new keyframe starts when the camera has moved or turned enough,
after a number of frames, or when too few corners are still tracked; its motion from the last
keyframe (in the body frame) is one odometry step of the log.

Poses are estimated directly from keyframe to frame, so no drift builds up between keyframes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from pipeline.datasets.kitti import StereoIntrinsics
from pipeline.frontend.config import KeyframeConfig, VoConfig
from pipeline.frontend.geometry import (
    camera_to_body_motion,
    invert_pose,
    project,
    projection_jacobian,
    rotation_angle,
    se3_exp,
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


@dataclass(frozen=True)
class StereoFeatures:
    """Corners of a keyframe with their 3-D points in its camera frame."""

    pixels: np.ndarray  # (N, 2) left-image pixels
    points: np.ndarray  # (N, 3) camera frame
    covariances: np.ndarray  # (N, 3, 3)


@dataclass(frozen=True)
class PoseFit:
    camera_pose: np.ndarray  # 4x4: the current camera in the keyframe's camera frame
    covariance: np.ndarray  # 6x6 over a right perturbation of camera_pose
    inliers: np.ndarray  # bool (N,)
    chi2_per_dof: float


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


def detect_stereo_features(
    left: np.ndarray, right: np.ndarray, intrinsics: StereoIntrinsics, config: VoConfig
) -> StereoFeatures:
    """Corners of the left image that match into the right one, triangulated."""
    pixels = detect_corners(left, config.fast_threshold, config.feature_cell, config.max_features)
    disparity, good = match_stereo(left, right, pixels, config)
    uvd = np.column_stack([pixels[good], disparity[good]])
    jacobian = triangulation_jacobian(uvd, intrinsics)
    pixel_covariance = stereo_pixel_covariance(config.pixel_sigma)
    covariances = jacobian @ pixel_covariance @ np.swapaxes(jacobian, 1, 2)
    return StereoFeatures(pixels[good], triangulate(uvd, intrinsics), covariances)


def refine_pose(
    camera_pose: np.ndarray,
    points: np.ndarray,
    point_covariances: np.ndarray,
    pixels: np.ndarray,
    intrinsics: StereoIntrinsics,
    pixel_sigma: float,
    iterations: int,
) -> PoseFit:
    """Gauss-Newton on the reprojection of keyframe points into the current left image.

    The unknown is `T` = the current camera in the keyframe's camera frame, perturbed on the
    right; a point `P` is seen at `project(T^-1 P)`. Each residual is weighted by the inverse
    of `pixel_sigma^2 I + J_P Sigma_P J_P^T`; outliers (chi-square beyond 9.21 at 2 dof, times the
    residuals' robust scale if above 1) are re-selected at every iteration after the first two.
    """
    pose = camera_pose.copy()
    inliers = np.ones(len(points), bool)
    information = np.eye(6)
    for iteration in range(iterations + 1):
        rotation, translation = pose[:3, :3], pose[:3, 3]
        local = (points - translation) @ rotation  # T^-1 P for every point
        in_front = local[:, 2] > 1e-3
        safe = np.where(in_front[:, None], local, np.array([0.0, 0.0, 1.0]))
        residual = pixels - project(safe, intrinsics)
        projection = projection_jacobian(safe, intrinsics)  # (N, 2, 3)
        # d(local)/d(xi) for T Exp(xi): [skew(local), -I]; d(local)/dP = R^T.
        d_local = np.zeros((len(points), 3, 6))
        d_local[:, :, :3] = _skew_batch(safe)
        d_local[:, :, 3:] = -np.eye(3)
        jacobian = projection @ d_local  # (N, 2, 6)
        point_jacobian = projection @ rotation.T
        noise = pixel_sigma**2 * np.eye(2) + point_jacobian @ point_covariances @ np.swapaxes(
            point_jacobian, 1, 2
        )
        weight = np.linalg.inv(noise)
        chi2 = np.einsum("ni,nij,nj->n", residual, weight, residual)
        # The first steps use every point given (RANSAC's inliers: the start may be a few
        # pixels off); the gate then drops what does not fit the refined pose. The gate widens
        # with the residuals' robust scale (median), so that noise larger than pixel_sigma
        # widens the covariance instead of thinning the points.
        inliers = in_front
        if iteration >= UNGATED_ITERATIONS and in_front.any():
            scale = max(1.0, float(np.median(chi2[in_front])) / CHI2_2DOF_MEDIAN)
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
    try:
        covariance = np.linalg.inv(information) * max(1.0, chi2_per_dof)
    except np.linalg.LinAlgError:
        covariance = np.eye(6)
    return PoseFit(pose, 0.5 * (covariance + covariance.T), inliers, chi2_per_dof)


def _skew_batch(vectors: np.ndarray) -> np.ndarray:
    out = np.zeros((len(vectors), 3, 3))
    x, y, z = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    out[:, 0, 1], out[:, 0, 2] = -z, y
    out[:, 1, 0], out[:, 1, 2] = z, -x
    out[:, 2, 0], out[:, 2, 1] = -y, x
    return out


def solve_pnp(
    features: StereoFeatures,
    pixels: np.ndarray,
    intrinsics: StereoIntrinsics,
    config: VoConfig,
) -> PoseFit | None:
    """The current camera in the keyframe's camera frame from tracked keyframe points."""
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
    fit = refine_pose(
        invert_pose(camera_from_keyframe),
        features.points,
        features.covariances,
        pixels,
        intrinsics,
        config.pixel_sigma,
        config.refine_iterations,
    )
    if fit.inliers.sum() < config.min_inliers:
        return None
    return fit


class StereoOdometry:
    """Feed frames in order with `process`; it returns a `KeyframeStep` at each new keyframe.

    The first frame processed is keyframe 0 (pose 0 of the log) and returns None; `finish`
    after the last frame makes that frame a keyframe too.
    """

    def __init__(
        self, intrinsics: StereoIntrinsics, config: VoConfig, keyframes: KeyframeConfig
    ) -> None:
        self.intrinsics = intrinsics
        self.config = config
        self.keyframe_rules = keyframes
        self.keyframe_index: int | None = None  # frame index of the current keyframe
        self._features = StereoFeatures(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3, 3)))
        self._initial_count = 0
        self._tracked = np.zeros((0, 2))  # pixels of the keyframe's features in the last frame
        self._previous_image: np.ndarray | None = None
        self._previous_pose = np.eye(4)  # last frame's camera in the keyframe's camera frame
        self._frame_motion = np.eye(4)  # last frame-to-frame camera motion (constant velocity)
        self._pending: KeyframeStep | None = None  # the last frame, were it made a keyframe
        self.lost_count = 0

    def process(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> KeyframeStep | None:
        if self.keyframe_index is None:
            self._start_keyframe(frame_index, left, right)
            return None
        fit = self._track(left)
        if fit is None:
            return self._lost(frame_index, left, right)
        frames_since = frame_index - self.keyframe_index
        pose = fit.camera_pose
        tracked_fraction = fit.inliers.sum() / max(self._initial_count, 1)
        rules = self.keyframe_rules
        new_keyframe = (
            np.linalg.norm(pose[:3, 3]) >= rules.min_translation
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
        covariance = fit.covariance + np.diag(self._floor())
        motion, body_covariance = camera_to_body_motion(fit.camera_pose, covariance)
        return KeyframeStep(frame_index, motion, body_covariance, int(fit.inliers.sum()), False)

    def _floor(self) -> np.ndarray:
        c = self.config
        return np.array([c.min_sigma_rotation] * 3 + [c.min_sigma_translation] * 3) ** 2

    def _track(self, left: np.ndarray) -> PoseFit | None:
        assert self._previous_image is not None
        if len(self._tracked) == 0:
            return None
        # Predict where the points go (constant velocity) so that fast motion stays in reach.
        predicted_pose = self._previous_pose @ self._frame_motion
        local = (self._features.points - predicted_pose[:3, 3]) @ predicted_pose[:3, :3]
        guess = self._tracked.copy()
        ahead = local[:, 2] > 0.5
        guess[ahead] = project(local[ahead], self.intrinsics)
        c = self.config
        pixels, good = track_points(
            self._previous_image,
            left,
            self._tracked,
            c.tracking_window,
            c.tracking_levels,
            c.tracking_iterations,
            c.max_backward_error if c.temporal_backward_check else None,
            guess,
        )
        height, width = left.shape[:2]
        good &= (pixels[:, 0] >= 0) & (pixels[:, 0] < width)
        good &= (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
        self._keep(good, pixels)
        self._previous_image = left
        fit = solve_pnp(self._features, self._tracked, self.intrinsics, c)
        if fit is not None:
            self._keep(fit.inliers, self._tracked)
        return fit

    def _keep(self, mask: np.ndarray, pixels: np.ndarray) -> None:
        f = self._features
        self._features = StereoFeatures(f.pixels[mask], f.points[mask], f.covariances[mask])
        self._tracked = pixels[mask]

    def _lost(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> KeyframeStep:
        """No pose from tracking: assume constant velocity, say so in the covariance, and start
        over from this frame."""
        self.lost_count += 1
        log.warning("visual odometry lost at frame %d: constant velocity assumed", frame_index)
        pose = self._previous_pose @ self._frame_motion
        c = self.config
        sigmas = np.array([c.lost_sigma_rotation] * 3 + [c.lost_sigma_translation] * 3)
        motion, covariance = camera_to_body_motion(pose, np.diag(sigmas**2))
        self._start_keyframe(frame_index, left, right)
        return KeyframeStep(frame_index, motion, covariance, 0, True)

    def _start_keyframe(self, frame_index: int, left: np.ndarray, right: np.ndarray) -> None:
        self.keyframe_index = frame_index
        self._pending = None
        self._features = detect_stereo_features(left, right, self.intrinsics, self.config)
        self._initial_count = len(self._features.pixels)
        self._tracked = self._features.pixels.copy()
        self._previous_image = left
        self._previous_pose = np.eye(4)
        log.debug("keyframe at frame %d: %d stereo features", frame_index, self._initial_count)
