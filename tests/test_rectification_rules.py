"""When a stereo pair must be warped (`Rectification.needed`) and when it is taken as rectified
already (`stereo_rectification`), on pinholes built by hand: distortion alone, a rotation
weighed in pixels at the focal length, and a right camera that sits to the left."""

import cv2
import numpy as np
import pytest

from pipeline.datasets.rectification import CameraModel, Rectification, stereo_rectification

FX = 500.0
K = np.array([[FX, 0.0, 320.0], [0.0, FX, 240.0], [0.0, 0.0, 1.0]])


def camera(distortion=(0.0, 0.0, 0.0, 0.0, 0.0)) -> CameraModel:
    return CameraModel(640, 480, K, np.array(distortion, dtype=float))


def as_is(left: CameraModel, right: CameraModel, R_right=None) -> Rectification:
    """The pair with its own pinholes, the right one 10 cm to the right (rotated by
    `R_right` to rectify it, none by default)."""
    R_right = np.eye(3) if R_right is None else R_right
    P_left = np.hstack([K, np.zeros((3, 1))])
    P_right = P_left.copy()
    P_right[0, 3] = -FX * 0.1
    return Rectification(left, right, np.eye(3), R_right, P_left, P_right)


@pytest.mark.parametrize(
    ("distortion", "needed"),
    [((0.0,) * 5, False), ((-0.1, 0.0, 0.0, 0.0, 0.0), True), ((0.0, 0.0, 1e-4, 0.0, 0.0), True)],
)
def test_any_distortion_makes_the_warp_needed(distortion, needed):
    assert as_is(camera(), camera(distortion)).needed == needed
    assert as_is(camera(distortion), camera()).needed == needed


@pytest.mark.parametrize(("angle", "needed"), [(1e-6, False), (1e-5, False), (1e-4, True)])
def test_a_rotation_is_weighed_by_the_pixels_it_moves(angle, needed):
    """A rotation moves pixels by about its angle times the focal length: 1e-4 rad at 500 px
    is 0.05 px, above the 0.01 px a rectified pair may be off; 1e-5 rad is 0.005 px."""
    R = cv2.Rodrigues(np.array([0.0, angle, 0.0]))[0]
    assert as_is(camera(), camera(), R_right=R).needed == needed


@pytest.mark.parametrize("offset", [-0.1, 0.1])
def test_the_right_camera_s_projection_holds_its_side(offset):
    """`right_from_left` maps the left camera's points into the right's: a right camera 10 cm
    to the right has translation -0.1 (the rectified pair as it is, P_right[0, 3] = -fx b);
    one 10 cm to the left, +0.1, is no rectified pair as it is: OpenCV's P_right[0, 3] is
    +fx b."""
    right_from_left = np.eye(4)
    right_from_left[0, 3] = offset
    rectification = stereo_rectification(camera(), camera(), right_from_left)
    assert rectification.P_right[0, 3] == pytest.approx(FX * offset, rel=1e-6)
