"""AprilTags: real photos against libapriltag's reference corners, and synthetic stereo views
of a tag at a known pose (range, bearing, pose, pixel convention).

The photos and their reference corners are in tests/data/apriltag/ (CC BY-SA 2.0, see the
README there).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from data_tools.bench_frontend import (
    TAG_PHOTOS,
    shared_non_tag_images,
    shared_tag_photos,
    tag_recall,
    tags_on_images,
)
from pipeline.datasets.camera import StereoIntrinsics
from pipeline.frontend import geometry as g
from pipeline.frontend.apriltags import (
    LIBAPRILTAG_PIXEL_OFFSET,
    AprilTagDetector,
    centre_disparity,
    tag_detection,
    tag_object_points,
)
from pipeline.frontend.config import load_frontend_config
from tests import real_data

DATA = Path(__file__).parent / "data" / "apriltag"
PHOTOS = sorted(DATA.glob("*.jpg"))
REFERENCE_TAG_COUNT = 47


def read_reference(path: Path) -> list[tuple[int, np.ndarray]]:
    """`id, (u v), (u v), (u v), (u v)` lines -> [(id, corners (4, 2))]."""
    rows = []
    for line in path.read_text().splitlines():
        numbers = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", line)]
        rows.append((int(numbers[0]), np.array(numbers[1:]).reshape(4, 2)))
    return rows


def detector(intrinsics: StereoIntrinsics | None = None, **changes) -> AprilTagDetector:
    config = dataclasses.replace(load_frontend_config().apriltags, **changes)
    intrinsics = intrinsics or StereoIntrinsics(799, 533, 500.0, 500.0, 400.0, 266.0, 0.5)
    return AprilTagDetector(config, intrinsics)


def match_photos(tag_detector: AprilTagDetector) -> tuple[int, int, list[float]]:
    """Reference tags found, detections with an id the reference lacks, corner errors (px)."""
    found, unknown, errors = 0, 0, []
    for photo in PHOTOS:
        image = cv2.imread(str(photo), cv2.IMREAD_GRAYSCALE)
        reference = read_reference(photo.with_suffix(".txt"))
        sightings = tag_detector.detect_image(image)
        reference_ids = {tag_id for tag_id, _ in reference}
        unknown += sum(s.tag_id not in reference_ids for s in sightings)
        for tag_id, corners in reference:
            # Back to libapriltag's pixel convention, that of the reference.
            candidates = [
                np.linalg.norm(s.corners + LIBAPRILTAG_PIXEL_OFFSET - corners, axis=1)
                for s in sightings
                if s.tag_id == tag_id
            ]
            if candidates:
                best = min(candidates, key=lambda e: e.max())
                if best.max() < 5.0:
                    found += 1
                    errors.extend(best)
    return found, unknown, errors


def test_photos_are_there():
    assert len(PHOTOS) == 3
    assert sum(len(read_reference(p.with_suffix(".txt"))) for p in PHOTOS) == 47


def test_real_photos_match_the_reference_corners():
    # The reference's own settings: the binding must reproduce libapriltag's corners (measured:
    # all 47, median error 0.0002 px, max 0.14 px; two tags need 1 and 2 bits corrected).
    found, unknown, errors = match_photos(detector(decimate=1.0, refine_edges=False))
    assert found == REFERENCE_TAG_COUNT
    assert unknown == 0
    assert np.median(errors) < 0.02
    assert max(errors) < 0.5


def test_real_photos_with_the_default_settings():
    # Full resolution and edge refinement: every tag but one of weak decision margin (measured
    # 46 of 47; decimate 2 found 34), corners moved by a few tenths of a pixel from the
    # unrefined reference (measured 0.37 px mean).
    found, unknown, errors = match_photos(detector())
    assert found >= 46
    assert unknown == 0
    assert np.mean(errors) < 1.0


# --- synthetic stereo views ------------------------------------------------------------------

STEREO = StereoIntrinsics(
    width=640, height=400, fx=450.0, fy=450.0, cx=319.5, cy=199.5, baseline=0.3
)
TAG_SIZE = 0.5
CELLS = 8  # tag36h11 is 8 cells wide; the quiet zone adds one a side
TEXELS_PER_CELL = 8


def tag_bitmap(tag_id: int) -> np.ndarray:
    """The official tag image with its quiet zone (OpenCV holds the codes turned by 180 deg)."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cells = np.rot90(cv2.aruco.generateImageMarker(dictionary, tag_id, CELLS), 2)
    cells = np.pad(cells, 1, constant_values=255)
    return np.kron(np.where(cells > 127, 230, 25), np.ones((TEXELS_PER_CELL,) * 2)).astype(np.uint8)


SUPERSAMPLE = 4


def render_tag(tag_id: int, camera_from_tag: np.ndarray, right: bool) -> np.ndarray:
    """A view of the tag on a grey background (OpenCV convention: pixel centres at integers),
    rendered 4 x 4 times finer and area-averaged down, as a sensor integrates light."""
    bitmap = tag_bitmap(tag_id)
    total = TAG_SIZE * (CELLS + 2) / CELLS  # edge of the quiet zone (m)
    texels = bitmap.shape[0]
    # bitmap pixel -> tag plane (x, y, 1): texel centres at integers, edges at -0.5 and n-0.5.
    plane_from_bitmap = np.array(
        [
            [total / texels, 0.0, (0.5 * total / texels) - total / 2],
            [0.0, total / texels, (0.5 * total / texels) - total / 2],
            [0.0, 0.0, 1.0],
        ]
    )
    pose = camera_from_tag.copy()
    if right:
        pose[0, 3] -= STEREO.baseline
    image_from_plane = STEREO.camera_matrix @ np.column_stack(
        [pose[:3, 0], pose[:3, 1], pose[:3, 3]]
    )
    # Pixel p covers fine pixels s p .. s p + s - 1, whose centres average s p + (s - 1) / 2.
    s = SUPERSAMPLE
    fine_from_image = np.array([[s, 0.0, (s - 1) / 2], [0.0, s, (s - 1) / 2], [0.0, 0.0, 1.0]])
    homography = fine_from_image @ image_from_plane @ plane_from_bitmap
    size = (STEREO.width * s, STEREO.height * s)
    fine = cv2.warpPerspective(bitmap, homography, size, flags=cv2.INTER_LINEAR, borderValue=128)
    return cv2.resize(fine, (STEREO.width, STEREO.height), interpolation=cv2.INTER_AREA)


def tag_pose(distance: float, yaw: float, offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """A tag facing the camera (its z into the tag = along the optical axis), turned by yaw."""
    pose = np.eye(4)
    pose[:3, :3] = g.so3_exp([0.0, yaw, 0.0])
    pose[:3, 3] = [offset[0], offset[1], distance]
    return pose


@pytest.mark.parametrize(
    ("distance", "yaw", "offset", "max_angle_deg"),
    [
        (4.0, 0.3, (0.5, -0.2), 3.0),
        (8.0, -0.5, (-1.0, 0.4), 3.0),
        # Far and facing the camera: orientation is weak (measured 7.6 deg off, sigma 15 deg).
        (12.0, 0.0, (0.0, 0.0), None),
    ],
)
def test_stereo_tag_measurement_at_a_known_pose(distance, yaw, offset, max_angle_deg):
    camera_from_tag = tag_pose(distance, yaw, offset)
    left = render_tag(7, camera_from_tag, right=False)
    right = render_tag(7, camera_from_tag, right=True)
    tags = detector(STEREO, size=TAG_SIZE)
    observations = tags.observe(left, right)
    assert [o.tag_id for o in observations] == [7]
    observation = observations[0]
    assert observation.right_method == "detected"

    # Corners in OpenCV's pixel convention: libapriltag's half-pixel offset is removed.
    true_corners = g.project(
        tag_object_points(TAG_SIZE) @ camera_from_tag[:3, :3].T + camera_from_tag[:3, 3], STEREO
    )
    assert np.abs(observation.corners - true_corners).max() < 0.3

    detection = tag_detection(observation, STEREO, num_classes=2, full_score_margin=100.0)
    true_body = g.BODY_FROM_CAMERA_ROTATION @ camera_from_tag[:3, 3]
    true_measurement = g.bearing_elevation_range(true_body)
    sigma = np.sqrt(np.diag(np.array(detection.covariance).reshape(3, 3)))
    assert abs(detection.range - true_measurement[2]) < max(0.01 * distance, 4 * sigma[2])
    assert abs(detection.bearing - true_measurement[0]) < 1e-3
    assert abs(detection.elevation - true_measurement[1]) < 1e-3
    assert detection.class_id == 7 % 2
    assert detection.source == "apriltag"

    # The 6-DoF pose in the body frame: the tag frame's axes and its centre.
    body_from_tag = g.BODY_FROM_CAMERA @ camera_from_tag
    pose = detection.relative_pose
    rotation_error = g.so3_log(g.rotation_from_quaternion(pose.rotation).T @ body_from_tag[:3, :3])
    if max_angle_deg is not None:
        assert np.linalg.norm(rotation_error) < np.radians(max_angle_deg)
    assert np.linalg.norm(np.array(pose.translation) - body_from_tag[:3, 3]) < 0.02 * distance
    covariance = np.array(pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(covariance, covariance.T)
    assert np.all(np.linalg.eigvalsh(covariance) > 0)
    # The orientation error is within the covariance (chi-square, 3 dof, 0.99).
    assert rotation_error @ np.linalg.solve(covariance[:3, :3], rotation_error) < 11.34


def test_tag_seen_only_in_the_left_image_is_dropped():
    camera_from_tag = tag_pose(5.0, 0.2)
    left = render_tag(3, camera_from_tag, right=False)
    blank = np.full_like(left, 128)
    tags = detector(STEREO, size=TAG_SIZE)
    assert tags.observe(left, blank) == []
    assert tags.dropped == 1


def test_far_tag_range_is_less_certain_than_near():
    tags = detector(STEREO, size=TAG_SIZE)
    sigmas = []
    for distance in (3.0, 9.0):
        pose = tag_pose(distance, 0.1)
        [observation] = tags.observe(render_tag(5, pose, False), render_tag(5, pose, True))
        covariance = tag_detection(observation, STEREO, 2, 100.0).covariance
        sigmas.append(np.sqrt(covariance[8]))
    # Range noise grows with the square of the distance.
    assert sigmas[1] / sigmas[0] == pytest.approx(9.0, rel=0.15)


def test_centre_disparity_is_exact_on_a_plane():
    corners = np.array([[100.0, 50.0], [140.0, 52.0], [138.0, 90.0], [99.0, 88.0]])
    a, b, c = 0.05, -0.02, 12.0  # d = a u + b v + c
    right = corners - np.column_stack([a * corners[:, 0] + b * corners[:, 1] + c, np.zeros(4)])
    centre = np.array([119.0, 70.0])
    assert centre_disparity(corners, right, centre) == pytest.approx(a * 119 + b * 70 + c)


def test_score_is_the_decision_margin_capped():
    pose = tag_pose(4.0, 0.0)
    [observation] = detector(STEREO, size=TAG_SIZE).observe(
        render_tag(9, pose, False), render_tag(9, pose, True)
    )
    low = tag_detection(observation, STEREO, 2, full_score_margin=1e6).score
    assert low == pytest.approx(observation.decision_margin / 1e6)
    assert tag_detection(observation, STEREO, 2, full_score_margin=1.0).score == 1.0


# --- the shared real photos (../shared/data/real/apriltag-photos) ----------------------------

needs_real_photos = real_data.needs(TAG_PHOTOS)


@pytest.mark.slow
@needs_real_photos
def test_recall_against_libapriltag_at_full_resolution_on_real_photos():
    # 94 photos of an office and a hallway: libapriltag at full resolution finds 236 tags,
    # tags of 13-29 px and oblique ones among them. Measured: all 236 at decimate 1; 94.5 % at 2.
    result = tag_recall(shared_tag_photos(), load_frontend_config())
    assert result.images >= 90 and result.reference >= 200
    assert result.recall >= 0.95
    assert result.extra <= 2


@pytest.mark.slow
@needs_real_photos
def test_no_tags_on_real_images_without_tags():
    images = shared_non_tag_images()
    assert len(images) >= 50  # KITTI street frames, the object frame, Middlebury's pair
    assert tags_on_images(images, load_frontend_config()) == 0
