"""`check_intrinsics` on wide images (KITTI's 1242 x 375): a principal point on or past the
image's edge is outside it, and how far from the centre it may lie is a quarter of the image's
width across, a quarter of its height up and down; numbers that are not finite, a focal length
or baseline that is not positive, refused by name; and the log's calibration message as read."""

import dataclasses

import pytest

from pipeline.datasets.camera import MAX_PRINCIPAL_OFFSET, StereoIntrinsics, check_intrinsics
from pipeline.errors import InputError

WIDTH, HEIGHT = 1242, 375


def intrinsics(cx: float, cy: float) -> StereoIntrinsics:
    return StereoIntrinsics(WIDTH, HEIGHT, 700.0, 700.0, cx, cy, 0.54)


@pytest.mark.parametrize(("cx", "cy"), [(WIDTH, HEIGHT / 2), (WIDTH / 2, HEIGHT), (-0.5, 187.0)])
def test_a_principal_point_on_or_past_the_edge_is_outside_the_images(cx, cy):
    with pytest.raises(InputError, match=r"lies outside the 1242x375 images"):
        check_intrinsics(intrinsics(cx, cy), "calib.txt")


@pytest.mark.parametrize(
    ("dx", "dy", "accepted"),
    [
        (0.2 * WIDTH, 0.0, True),  # 248 px across: far more than a quarter of the height
        (0.3 * WIDTH, 0.0, False),
        (0.0, 0.2 * HEIGHT, True),
        (0.0, 0.3 * HEIGHT, False),
    ],
)
def test_the_principal_point_may_lie_a_quarter_of_the_image_from_its_centre(dx, dy, accepted):
    assert pytest.approx(0.25) == MAX_PRINCIPAL_OFFSET
    k = intrinsics(WIDTH / 2 + dx, HEIGHT / 2 + dy)
    if accepted:
        check_intrinsics(k, "calib.txt")
    else:
        with pytest.raises(InputError, match="far from the centre"):
            check_intrinsics(k, "calib.txt")


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("fx", float("inf"), "fx is inf"),
        ("cy", float("nan"), "cy is nan"),
        ("baseline", float("inf"), "baseline is inf"),
        ("baseline", 0.0, "must be positive"),
        ("baseline", -0.54, "must be positive"),
        ("fy", -700.0, "must be positive"),
    ],
)
def test_numbers_a_calibration_cannot_hold_are_refused_by_name(field, value, message):
    k = dataclasses.replace(intrinsics(WIDTH / 2, HEIGHT / 2), **{field: value})
    with pytest.raises(InputError, match=message):
        check_intrinsics(k, "calib.txt")


def test_the_log_s_calibration_holds_each_number_in_its_place():
    k = StereoIntrinsics(WIDTH, HEIGHT, 701.0, 699.0, 610.0, 180.0, 0.54)
    message = k.calibration_message(123)
    assert (message.stamp_ns, message.width, message.height) == (123, WIDTH, HEIGHT)
    assert (message.fx, message.fy, message.cx, message.cy) == pytest.approx(
        (701.0, 699.0, 610.0, 180.0)
    )
    assert message.baseline == pytest.approx(0.54)
