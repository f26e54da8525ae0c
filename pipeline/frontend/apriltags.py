"""AprilTags (tag36h11) seen by the stereo camera: a point and a 6-DoF pose measurement each.

Tags are found in the left image with libapriltag (the pupil-apriltags binding). The same tag is
then found in the right image, searched only in a band of the left tag's rows (the images are
rectified); if it is not found there, its corners are followed into the right image with
Lucas-Kanade from a disparity guessed by monocular PnP.

- 6-DoF pose: IPPE (`cv2.SOLVEPNP_IPPE_SQUARE`) on the left corners gives both candidate poses;
  each is refined by Gauss-Newton on the reprojection of the corners into the left and the right
  image, and the one that fits best is kept. Covariance: `sigma^2 (J^T J)^-1`, where the corner
  noise `sigma` is the fit's residual RMS (10 degrees of freedom), at least `corner_sigma`;
  widened to cover the other IPPE pose when that one fits about as well.
  The tag frame is AprilTag's: x right and y down the printed tag, z into it.
- Point measurement: bearing and elevation of the tag centre (the homography's centre pixel in
  the left image) and its range from the disparity at that pixel, which is fitted as a plane
  `d = a u + b v + c` through the four corners' disparities (disparity is affine in the pixel
  over a plane). Covariance: `sigma` on the centre's coordinates and on each image's column
  (corner errors are mostly shared, so averaging four does not reduce them). The point does
  not depend on the configured tag size; the pose does.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import cv2
import numpy as np
from pupil_apriltags import Detector as _BindingDetector

from pipeline.datasets.camera import BODY_FROM_CAMERA, StereoIntrinsics
from pipeline.frontend.config import AprilTagConfig
from pipeline.frontend.geometry import (
    project,
    projection_jacobian,
    quaternion_from_rotation,
    right_camera_points,
    se3_exp,
    skew,
    so3_log,
    stereo_pixel_covariance,
    stereo_point_measurement,
)
from pipeline.frontend.stereo_vo import track_points
from pipeline.log import Detection, RelativePose

log = logging.getLogger(__name__)

# libapriltag puts pixel centres at half-integer coordinates (the image's top-left corner is
# (0, 0)); OpenCV and the calibration put them at integers. Measured on warped synthetic tags:
# its corners are 0.50 +- 0.1 px right of and below OpenCV's.
LIBAPRILTAG_PIXEL_OFFSET = 0.5

# Lucas-Kanade of tag corners into the right image (the fallback): a small window, so that it
# sees the tag's own border more than what lies behind the tag.
CORNER_WINDOW = 11
CORNER_LEVELS = 3
CORNER_ITERATIONS = 30
CORNER_BACKWARD_ERROR = 0.5

# The second IPPE pose is taken as plausible when its cost exceeds the best one's by less than
# this (chi-square units): 9.21 = 2 dof at 0.99.
AMBIGUITY_CHI2 = 9.21

# Degrees of freedom of the stereo fit of a tag pose: 4 corners x 2 images x 2 coordinates - 6.
STEREO_FIT_DOF = 10


def tag_object_points(size: float) -> np.ndarray:
    """Corners of the black square in the tag frame, in the order libapriltag reports them."""
    half = size / 2.0
    return np.array(
        [[-half, half, 0.0], [half, half, 0.0], [half, -half, 0.0], [-half, -half, 0.0]]
    )


@dataclass(frozen=True)
class TagSighting:
    """A tag found in one image: corners in libapriltag's order, pixel centres at integers."""

    tag_id: int
    corners: np.ndarray  # (4, 2)
    centre: np.ndarray  # (2,)
    decision_margin: float
    hamming: int


@dataclass(frozen=True)
class TagObservation:
    """One tag seen in a stereo pair; pixels are in the left image unless named right."""

    tag_id: int
    decision_margin: float
    hamming: int
    corners: np.ndarray  # (4, 2)
    centre: np.ndarray  # (2,)
    right_corners: np.ndarray  # (4, 2)
    right_method: str  # "detected" (in the right image) or "tracked" (Lucas-Kanade)
    uvd: np.ndarray  # centre pixel and its disparity
    uvd_covariance: np.ndarray  # 3x3
    camera_from_tag: np.ndarray  # 4x4
    pose_covariance: np.ndarray  # 6x6, right perturbation of camera_from_tag

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        low, high = self.corners.min(axis=0), self.corners.max(axis=0)
        return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def centre_disparity(corners: np.ndarray, right_corners: np.ndarray, centre: np.ndarray) -> float:
    """Disparity at `centre`, from the plane `d = a u + b v + c` through the corners."""
    disparities = corners[:, 0] - right_corners[:, 0]
    design = np.column_stack([corners, np.ones(len(corners))])
    coefficients, *_ = np.linalg.lstsq(design, disparities, rcond=None)
    return float(np.array([centre[0], centre[1], 1.0]) @ coefficients)


def refine_tag_pose(
    camera_from_tag: np.ndarray,
    object_points: np.ndarray,
    corners: np.ndarray,
    right_corners: np.ndarray | None,
    intrinsics: StereoIntrinsics,
    iterations: int = 8,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Gauss-Newton on corner reprojection (left, and right if given) over a right
    perturbation of `camera_from_tag`. Returns the pose, the inverse information `(J^T J)^-1`
    (multiply by the pixel variance), and the sum of squared residuals (px^2)."""
    pose = camera_from_tag.copy()
    cost = np.inf
    information = np.eye(6)
    object_skews = skew(object_points)
    d_point = np.zeros((len(object_points), 3, 6))
    for iteration in range(iterations + 1):
        rotation = pose[:3, :3]
        points = object_points @ rotation.T + pose[:3, 3]
        # d(point)/d(xi) for T Exp(xi): [-R skew(X), R].
        d_point[:, :, :3] = -rotation @ object_skews
        d_point[:, :, 3:] = rotation
        residuals = [corners - project(points, intrinsics)]
        jacobians = [projection_jacobian(points, intrinsics) @ d_point]
        if right_corners is not None:
            right_points = right_camera_points(points, intrinsics)
            residuals.append(right_corners - project(right_points, intrinsics))
            jacobians.append(projection_jacobian(right_points, intrinsics) @ d_point)
        residual = np.concatenate(residuals).reshape(-1)
        jacobian = np.concatenate(jacobians).reshape(-1, 6)
        cost = float(residual @ residual)
        information = jacobian.T @ jacobian
        if iteration == iterations:
            break
        step = np.linalg.lstsq(jacobian, residual, rcond=None)[0]
        pose = pose @ se3_exp(step)
        if np.linalg.norm(step) < 1e-8:  # ~1e-8 rad and m: far below the noise
            break
    return pose, np.linalg.pinv(information), cost


class LibapriltagDetector(_BindingDetector):
    """pupil-apriltags' detector (1.0.4), with two of its faults mended.

    - Its `__del__` frees the tag families before the detector, whose destruction then reads
      them: a use after free that crashes the process now and then (pupil-labs/apriltags issues
      34, 46, 52; seen here in about one test run in two). Freed here in libapriltag's order.
    - It stores `decode_sharpening` through `int()`, so 0.25 became 0; set here as given.
    """

    def __init__(self, *, decode_sharpening: float, **options) -> None:
        super().__init__(decode_sharpening=decode_sharpening, **options)
        self.tag_detector_ptr.contents.decode_sharpening = float(decode_sharpening)

    def __del__(self) -> None:
        pointer, self.tag_detector_ptr = getattr(self, "tag_detector_ptr", None), None
        if pointer is None:
            return
        self.libc.apriltag_detector_destroy.restype = None
        self.libc.apriltag_detector_destroy(pointer)
        for family, handle in self.tag_families.items():
            destroy = getattr(self.libc, f"{family}_destroy")
            destroy.restype = None
            destroy(handle)
        self.tag_families = {}


def tangent_difference(pose: np.ndarray, other: np.ndarray) -> np.ndarray:
    """`xi` with `other ~= pose @ Exp(xi)`: rotation vector, then the translation difference
    in `pose`'s frame (first order in the translation)."""
    relative = np.linalg.inv(pose) @ other
    return np.concatenate([so3_log(relative[:3, :3]), relative[:3, 3]])


class AprilTagDetector:
    """Finds tags in stereo pairs and measures them (see the module's description)."""

    def __init__(self, config: AprilTagConfig, intrinsics: StereoIntrinsics) -> None:
        self.config = config
        self.intrinsics = intrinsics
        self.object_points = tag_object_points(config.size)
        self._detector = LibapriltagDetector(
            families=config.family,
            nthreads=1,
            quad_decimate=config.decimate,
            quad_sigma=config.blur,
            refine_edges=int(config.refine_edges),
            decode_sharpening=config.decode_sharpening,
        )
        self.right_detected = 0
        self.right_tracked = 0
        self.dropped = 0

    def detect_image(self, image: np.ndarray) -> list[TagSighting]:
        """The tags of one grey image that pass the decode checks, in OpenCV's pixel
        convention (pixel centres at integer coordinates)."""
        found = self._detector.detect(np.ascontiguousarray(image, dtype=np.uint8))
        return [
            TagSighting(
                tag_id=int(d.tag_id),
                corners=np.asarray(d.corners, float) - LIBAPRILTAG_PIXEL_OFFSET,
                centre=np.asarray(d.center, float) - LIBAPRILTAG_PIXEL_OFFSET,
                decision_margin=float(d.decision_margin),
                hamming=int(d.hamming),
            )
            for d in found
            if d.hamming <= self.config.max_hamming
            and d.decision_margin >= self.config.min_decision_margin
        ]

    def observe(self, left: np.ndarray, right: np.ndarray) -> list[TagObservation]:
        """Every tag of the left image that can also be measured in the right one."""
        sightings = self.detect_image(left)
        if not sightings:
            return []
        right_sightings = self._detect_in_right_band(sightings, right)
        observations = []
        for sighting in sightings:
            observation = self._measure(sighting, right_sightings, left, right)
            if observation is None:
                self.dropped += 1
            else:
                observations.append(observation)
        return observations

    def _measure(
        self,
        detection: TagSighting,
        right_sightings: list[TagSighting],
        left: np.ndarray,
        right: np.ndarray,
    ) -> TagObservation | None:
        corners, centre = detection.corners, detection.centre
        candidates = self._candidate_poses(corners)
        if not candidates:
            return None
        right_corners, method = self._find_in_right(detection, right_sightings), "detected"
        if right_corners is None:
            right_corners = self._track_into_right(corners, candidates[0], left, right)
            method = "tracked"
        if right_corners is None:
            log.debug("tag %d: not found in the right image", detection.tag_id)
            return None
        disparity = centre_disparity(corners, right_corners, centre)
        if disparity < self.config.min_disparity:
            return None
        fits = sorted(
            (
                refine_tag_pose(c, self.object_points, corners, right_corners, self.intrinsics)
                for c in candidates
            ),
            key=lambda fit: fit[2],
        )
        pose, inverse_information, cost = fits[0]
        # Corner noise: the stereo fit's residuals (16 numbers, 6 unknowns) say how well the
        # corners were found (small tags: up to ~0.6 px, measured), never below corner_sigma.
        sigma = float(np.sqrt(max(self.config.corner_sigma**2, cost / STEREO_FIT_DOF)))
        pose_covariance = sigma**2 * 0.5 * (inverse_information + inverse_information.T)
        if len(fits) > 1 and (fits[1][2] - cost) / sigma**2 < AMBIGUITY_CHI2:
            # Both IPPE poses fit about as well (small or far tags): widen the covariance to
            # cover the other one, as a Gaussian matched to the pair would.
            difference = tangent_difference(pose, fits[1][0])
            pose_covariance = pose_covariance + np.outer(difference, difference)
        if method == "detected":
            self.right_detected += 1
        else:
            self.right_tracked += 1
        return TagObservation(
            tag_id=detection.tag_id,
            decision_margin=detection.decision_margin,
            hamming=detection.hamming,
            corners=corners,
            centre=centre,
            right_corners=right_corners,
            right_method=method,
            uvd=np.array([centre[0], centre[1], disparity]),
            # The centre is about the mean of the four corners, but their errors are mostly
            # shared (blur, edge fits; measured), so it keeps a corner's variance.
            uvd_covariance=stereo_pixel_covariance(sigma),
            camera_from_tag=pose,
            pose_covariance=pose_covariance,
        )

    def _candidate_poses(self, corners: np.ndarray) -> list[np.ndarray]:
        """Both IPPE solutions (a square's pose is ambiguous from one view)."""
        count, rvecs, tvecs, _ = cv2.solvePnPGeneric(
            self.object_points,
            corners,
            self.intrinsics.camera_matrix,
            None,
            flags=cv2.SOLVEPNP_IPPE_SQUARE,
        )
        poses = []
        for rvec, tvec in zip(rvecs[:count], tvecs[:count], strict=True):
            pose = np.eye(4)
            pose[:3, :3] = cv2.Rodrigues(rvec)[0]
            pose[:3, 3] = np.ravel(tvec)
            if pose[2, 3] > 0:
                poses.append(pose)
        return poses

    def _detect_in_right_band(
        self, sightings: list[TagSighting], right: np.ndarray
    ) -> list[TagSighting]:
        """Tags of the right image, searched only where the left tags can be seen in it: their
        rows (rectified images) left of their rightmost column. One detection for all tags."""
        margin = self.config.right_search_margin
        height, width = right.shape[:2]
        corners = np.concatenate([s.corners for s in sightings])
        top = max(int(np.floor(corners[:, 1].min())) - margin, 0)
        bottom = min(int(np.ceil(corners[:, 1].max())) + margin + 1, height)
        end = min(int(np.ceil(corners[:, 0].max())) + margin + 1, width)
        if bottom - top < 8 or end < 8:
            return []
        shift = np.array([0.0, top])
        return [
            dataclasses.replace(s, corners=s.corners + shift, centre=s.centre + shift)
            for s in self.detect_image(right[top:bottom, :end])
        ]

    def _find_in_right(
        self, sighting: TagSighting, right_sightings: list[TagSighting]
    ) -> np.ndarray | None:
        """The right-image corners of the same tag: same id, same rows, positive disparity."""
        best, best_error = None, np.inf
        for found in right_sightings:
            if found.tag_id != sighting.tag_id:
                continue
            row_error = np.abs(found.corners[:, 1] - sighting.corners[:, 1]).max()
            if row_error > self.config.max_row_error:
                continue
            if np.any(sighting.corners[:, 0] - found.corners[:, 0] <= 0):
                continue
            if row_error < best_error:
                best, best_error = found.corners, row_error
        return best

    def _track_into_right(
        self, corners: np.ndarray, camera_from_tag: np.ndarray, left: np.ndarray, right: np.ndarray
    ) -> np.ndarray | None:
        """Lucas-Kanade of the corners into the right image, from the disparities that the
        monocular pose predicts."""
        points = self.object_points @ camera_from_tag[:3, :3].T + camera_from_tag[:3, 3]
        guess = project(right_camera_points(points, self.intrinsics), self.intrinsics)
        right_corners, tracked = track_points(
            left,
            right,
            corners,
            CORNER_WINDOW,
            CORNER_LEVELS,
            CORNER_ITERATIONS,
            CORNER_BACKWARD_ERROR,
            guess,
        )
        good = (
            tracked.all()
            and np.abs(right_corners[:, 1] - corners[:, 1]).max() <= self.config.max_row_error
            and np.all(corners[:, 0] - right_corners[:, 0] > 0)
        )
        return right_corners if good else None


def tag_detection(
    observation: TagObservation,
    intrinsics: StereoIntrinsics,
    num_classes: int,
    full_score_margin: float,
    truth_landmark_id: int | None = None,
) -> Detection:
    """The log's detection of a tag: in the body frame, class = tag id mod num_classes."""
    measurement, covariance = stereo_point_measurement(
        observation.uvd, observation.uvd_covariance, intrinsics
    )
    # A fixed frame change on the left leaves a right perturbation's covariance as it is.
    body_from_tag = BODY_FROM_CAMERA @ observation.camera_from_tag
    return Detection(
        class_id=observation.tag_id % num_classes,
        score=float(min(1.0, observation.decision_margin / full_score_margin)),
        bearing=float(measurement[0]),
        elevation=float(measurement[1]),
        range=float(measurement[2]),
        covariance=tuple(float(v) for v in covariance.ravel()),
        source="apriltag",
        bbox=observation.bbox,
        relative_pose=RelativePose(
            translation=tuple(float(v) for v in body_from_tag[:3, 3]),  # type: ignore[arg-type]
            rotation=tuple(quaternion_from_rotation(body_from_tag[:3, :3]).tolist()),
            covariance=tuple(float(v) for v in observation.pose_covariance.ravel()),
        ),
        truth_landmark_id=truth_landmark_id,
    )
